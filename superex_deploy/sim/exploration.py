"""What a simulated exploration runs with: the world's sensors and noise, the explorer's configuration, and when the
episode runner (:func:`superex_deploy.evaluation.episodes.run_episode`) evaluates its metrics."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.explorer import ExplorerConfig
from superex_deploy.sim.noise.lidar import LidarNoise
from superex_deploy.sim.noise.pose import PoseNoise
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
        pose_noise: the world's localisation error (:class:`~superex_deploy.sim.noise.pose.PoseNoise`), or None.
        lidar_noise: the world's LiDAR noise (:class:`~superex_deploy.sim.noise.lidar.LidarNoise`), or None.
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    explorer: ExplorerConfig = field(default_factory=lambda: ExplorerConfig().for_simulation())
    iou_every: int = 25
    iou_dense_until: float = 1.0
    pose_noise: Optional[PoseNoise] = None
    lidar_noise: Optional[LidarNoise] = None

    def __post_init__(self) -> None:
        for name, kind in (("lidar", LidarConfig), ("explorer", ExplorerConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}")
        for name, kind in (("pose_noise", PoseNoise), ("lidar_noise", LidarNoise)):
            if getattr(self, name) is not None and not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__} or None, got {type(getattr(self, name)).__name__}")
        if isinstance(self.iou_every, bool) or int(self.iou_every) != self.iou_every or self.iou_every < 0:
            raise ValueError(f"iou_every must be an integer >= 0, got {self.iou_every!r}")

    def to_json(self) -> dict:
        """The configuration as JSON values (:meth:`~superex_deploy.configs.JsonConfig.to_json`); the noise entries
        only where noise is on (a noise-free configuration reads as it did before they existed; :meth:`from_json`
        reads a left-out entry as None)."""
        config = super().to_json()
        for name in ("pose_noise", "lidar_noise"):
            if config[name] is None:
                del config[name]
        return config
