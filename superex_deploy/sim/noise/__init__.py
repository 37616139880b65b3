"""The simulator's models of a real robot's imperfections (all off by default), as one object,
:class:`~superex_deploy.sim.noise.model.SimNoise` (:mod:`.model`, with the named models of
:data:`~superex_deploy.sim.noise.model.NOISE_PRESETS`): the localisation error (:mod:`.pose`: the belief the robot is
given, as white jitter plus a bounded drift), the LiDAR's range noise, dropouts and spurious returns (:mod:`.lidar`)
and the SPAD's photon budget (a name of :data:`superex_deploy.spad_types.SPAD_PRESETS`; the photon noise itself lives
with the SPAD simulator, :mod:`superex_deploy.sim.spad.noise`)."""
