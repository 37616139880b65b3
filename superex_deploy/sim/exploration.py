"""What a simulated exploration runs with: the world's sensors and noise, the explorer's configuration, and when the
episode runner (:func:`superex_deploy.evaluation.episodes.run_episode`) evaluates its metrics."""

from __future__ import annotations

from dataclasses import dataclass, field

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_int
from superex_deploy.onboard.explorer import ExplorerConfig
from superex_deploy.sim.noise.model import SimNoise
from superex_deploy.sim.world import LidarConfig

__all__ = ["ExplorationConfig"]


@dataclass(frozen=True)
class ExplorationConfig(JsonConfig):
    """Episode parameters: the world's sensors, the explorer's configuration, and when the metrics are evaluated.

    Attributes:
        lidar: the line-of-sight LiDAR (the world's).
        explorer: what the explorer is built with (:class:`~superex_deploy.onboard.explorer.ExplorerConfig`:
            motion, frontier size, prediction schedule and reuse); the world drives ``explorer.motion.step_m``
            metres per step. The default is the explorer's defaults under the simulated benchmarks' rules
            (:meth:`~superex_deploy.onboard.config.ExplorerConfig.for_simulation`: finished at the first step
            without a goal, a locked goal kept until reached); a configuration given here is used as it is.
        iou_every: evaluate the prediction's map IoU every this many steps, and at the last step (0: never).
        iou_dense_until: above this coverage (with carving) the IoU is evaluated only every ``10 * iou_every``
            steps: the benchmark's IoU metrics read the low-coverage part of the curve (up to 30 %), and each
            evaluation runs the predictor.
        noise: the world's noise (:class:`~superex_deploy.sim.noise.model.SimNoise`: localisation error, LiDAR
            noise; its SPAD budget is the sensing's, :meth:`SimNoise.sensing
            <superex_deploy.sim.noise.model.SimNoise.sensing>`).
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    explorer: ExplorerConfig = field(default_factory=lambda: ExplorerConfig().for_simulation())
    iou_every: int = 25
    iou_dense_until: float = 1.0
    noise: SimNoise = SimNoise()

    def __post_init__(self) -> None:
        for name, kind in (("lidar", LidarConfig), ("explorer", ExplorerConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}")
        if not isinstance(self.noise, SimNoise):
            raise ValueError(f"noise must be a SimNoise, got {type(self.noise).__name__}")
        object.__setattr__(self, "iou_every", check_int("iou_every", self.iou_every, 0))

    def to_json(self) -> dict:
        """The configuration as JSON values (:meth:`~superex_deploy.configs.JsonConfig.to_json`); ``noise`` only
        where noise is on (a noise-free configuration reads as it did before it existed; :meth:`from_json` reads a
        left-out entry as no noise)."""
        config = super().to_json()
        if not self.noise.on:
            del config["noise"]
        return config
