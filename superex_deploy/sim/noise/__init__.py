"""The simulator's models of a real robot's imperfections (all off by default): the localisation error
(:mod:`.pose`: the belief the robot is given, as white jitter plus a bounded drift) and the LiDAR's range noise,
dropouts and spurious returns (:mod:`.lidar`). The SPAD's photon noise lives with the SPAD simulator
(:mod:`superex_deploy.sim.spad.noise`)."""
