"""The simulator's noise as one object: :class:`SimNoise` holds the localisation error, the LiDAR's noise and the
SPAD's photon budget, and is what every layer passes (the command line parses it once, :class:`ScenarioTask
<superex_deploy.evaluation.tasks.ScenarioTask>` carries it, :class:`~superex_deploy.sim.exploration.ExplorationConfig`
and :class:`~superex_deploy.sim.world.WorldConfig` hold it, :meth:`SimNoise.sensing` applies its SPAD part).

:data:`NOISE_PRESETS` names the noise models the benchmarks use; the SPAD photon budgets are the named instances
of :data:`superex_deploy.spad_types.SPAD_PRESETS`, which :attr:`SimNoise.spad` names.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

from superex_deploy.configs import JsonConfig
from superex_deploy.sim.noise.lidar import DEFAULT_DROPOUT_PROB, DEFAULT_SPURIOUS_PROB, LidarNoise
from superex_deploy.sim.noise.pose import PoseNoise

__all__ = ["SimNoise", "NOISE_PRESETS"]


@dataclass(frozen=True)
class SimNoise(JsonConfig):
    """The simulator's noise (all off by default: the paper's noise-free protocol).

    Attributes:
        pose: the localisation error (:class:`~superex_deploy.sim.noise.pose.PoseNoise`), or None (the observations
            carry the true pose, and the robot moves from cell centre to cell centre).
        lidar: the LiDAR's noise (:class:`~superex_deploy.sim.noise.lidar.LidarNoise`), or None (exact ranges).
        spad: the SPAD sensor's photon budget, a name of :data:`superex_deploy.spad_types.SPAD_PRESETS` (``off``:
            the sensor model as it is, the paper's noise-free one).

    Raises:
        ValueError: a field of another type, an unknown photon budget.
    """

    pose: Optional[PoseNoise] = None
    lidar: Optional[LidarNoise] = None
    spad: str = "off"

    def __post_init__(self) -> None:
        from superex_deploy.onboard.checks import check_choice
        from superex_deploy.spad_types import SPAD_PRESETS

        for name, kind in (("pose", PoseNoise), ("lidar", LidarNoise)):
            if getattr(self, name) is not None and not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__} or None, got {type(getattr(self, name)).__name__}")
        check_choice("spad", self.spad, tuple(SPAD_PRESETS))

    @classmethod
    def from_sigmas(cls, pose: Optional[tuple[float, float]] = None,
                    lidar: Optional[tuple[float, float, float]] = None, spad: str = "off", seed: int = 0) -> "SimNoise":
        """The noise of the command line's numbers: ``pose = (sigma_m, sigma_deg)`` (:meth:`PoseNoise.from_sigmas
        <superex_deploy.sim.noise.pose.PoseNoise.from_sigmas>`), ``lidar = (sigma_m, dropout, spurious)``, ``spad``
        a photon budget's name; None leaves that noise off; both seeded with ``seed``."""
        return cls(pose=None if pose is None else PoseNoise.from_sigmas(*pose, seed=seed),
                   lidar=None if lidar is None else LidarNoise(sigma_m=lidar[0], dropout_prob=lidar[1],
                                                               spurious_prob=lidar[2], seed=seed),
                   spad=spad)

    def seeded(self, seed: int) -> "SimNoise":
        """This noise with its random generators seeded with ``seed`` (an episode's)."""
        return replace(self, pose=None if self.pose is None else replace(self.pose, seed=seed),
                       lidar=None if self.lidar is None else replace(self.lidar, seed=seed))

    @property
    def on(self) -> bool:
        """Whether any noise is on."""
        return self.pose is not None or self.lidar is not None or self.spad != "off"

    def settings(self) -> dict:
        """The noise that is on, in the form runs record it (``metrics.json``, a benchmark's ``settings.json``, a
        recording's metadata): ``pose_noise: [sigma_m, sigma_deg]``, ``lidar_noise: [sigma_m, dropout,
        spurious]``, ``spad_noise: NAME``; empty without noise (a noise-free run's settings read as before)."""
        settings: dict = {}
        if self.pose is not None:
            settings["pose_noise"] = [self.pose.sigma_xy_m, self.pose.sigma_yaw_deg]
        if self.lidar is not None:
            settings["lidar_noise"] = [self.lidar.sigma_m, self.lidar.dropout_prob, self.lidar.spurious_prob]
        if self.spad != "off":
            settings["spad_noise"] = self.spad
        return settings

    def episode_config(self, cfg):
        """The :class:`~superex_deploy.sim.exploration.ExplorationConfig` ``cfg`` with this noise (``cfg`` itself
        without pose and LiDAR noise). With LiDAR noise the explorer's map is told the sensor's range sigma
        (``OccupancyConfig.range_sigma_m``: the robot's calibration is the simulated sensor's sigma), as a robot's
        configuration would be."""
        if self.pose is None and self.lidar is None:
            return cfg
        if self.lidar is not None:
            explorer = cfg.explorer
            cfg = replace(cfg, explorer=replace(explorer, occupancy=replace(explorer.occupancy,
                                                                            range_sigma_m=float(self.lidar.sigma_m))))
        return replace(cfg, noise=self)

    def sensing(self, sensing):
        """The episode's :class:`~superex_deploy.sim.sensing.SpadSensing` (or None) with the sensor model of the
        photon budget :attr:`spad` (:func:`superex_deploy.spad_types.spad_preset`), on both the simulator's and the
        onboard processing's side; unchanged for ``off``."""
        from superex_deploy.spad_types import spad_preset

        if sensing is None or self.spad == "off":
            return sensing
        return replace(sensing, spad=spad_preset(self.spad, sensing.spad))


NOISE_PRESETS: dict[str, SimNoise] = {
    "off": SimNoise(),
    "robot": SimNoise(pose=PoseNoise.from_sigmas(0.05, 1.0),
                      lidar=LidarNoise(sigma_m=0.02, dropout_prob=DEFAULT_DROPOUT_PROB,
                                       spurious_prob=DEFAULT_SPURIOUS_PROB),
                      spad="realistic"),
}
"""Named noise models: ``off`` (the paper's protocol) and ``robot`` (a good indoor robot: 5 cm / 1 degree of
localisation jitter with its bounded drift, 2 cm LiDAR range noise with the default dropouts and spurious returns,
the SPAD's ``realistic`` indoor photon budget). Seed one for an episode with :meth:`SimNoise.seeded`."""
