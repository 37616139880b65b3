"""The robot's observed map, built from line-of-sight scans and, separately, from NLOS carving."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from superex_deploy.explore.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.geometry import cell_centre, mark_rays, ray_angles

__all__ = ["LidarConfig", "Mapper"]


@dataclass(frozen=True)
class LidarConfig:
    """Line-of-sight LiDAR of the robot (MapEx ``lidar_sim_configs``: 2500 rays, 20 m)."""

    n_rays: int = 2500
    range_m: float = 20.0

    def __post_init__(self) -> None:
        if self.n_rays < 1 or not self.range_m > 0:
            raise ValueError(f"LidarConfig needs n_rays >= 1 and range_m > 0, got {self.n_rays}, {self.range_m}")


class Mapper:
    """Observed map over a ground-truth grid of shape ``[H, W]``.

    Line-of-sight scans mark the cells each ray crosses as free and its first wall as occupied. Carved cells
    from the NLOS processing are kept in a separate mask: they count as free in :attr:`observed` (never over an
    observed wall) and coverage is reported with and without them.
    """

    def __init__(self, shape: tuple[int, int], lidar: LidarConfig = LidarConfig()):
        self.lidar = lidar
        self.seen_free = np.zeros(shape, bool)
        self.seen_wall = np.zeros(shape, bool)
        self.carved = np.zeros(shape, bool)
        self._angles = ray_angles(lidar.n_rays)

    @property
    def shape(self) -> tuple[int, int]:
        return self.seen_free.shape  # type: ignore[return-value]

    def integrate_scan(self, ground_truth: np.ndarray, pose_rc: tuple[int, int], resolution_m: float) -> None:
        """Cast the LiDAR from the centre of ``pose_rc`` through ``ground_truth`` (bool ``[H, W]`` walls)."""
        if ground_truth.shape != self.shape:
            raise ValueError(f"ground truth has shape {ground_truth.shape}, the map has {self.shape}")
        mark_rays(ground_truth, cell_centre(pose_rc), self._angles, self.lidar.range_m / resolution_m,
                  self.seen_free, self.seen_wall)

    def merge_carved(self, carved: np.ndarray) -> None:
        """Add cells proven free by NLOS space carving (bool ``[H, W]``)."""
        carved = np.asarray(carved)
        if carved.dtype != np.bool_ or carved.shape != self.shape:
            raise ValueError(f"carved must be a bool array of shape {self.shape}")
        self.carved |= carved

    def observed(self, include_carved: bool = True) -> np.ndarray:
        """int8 ``[H, W]``: OCCUPIED where a wall was seen, FREE where seen (or carved) free, UNKNOWN elsewhere."""
        known_free = self.seen_free | self.carved if include_carved else self.seen_free
        observed = np.full(self.shape, UNKNOWN, np.int8)
        observed[known_free] = FREE
        observed[self.seen_wall] = OCCUPIED
        return observed

    def coverage(self, valid: np.ndarray, include_carved: bool = True) -> float:
        """Fraction of the valid area that is known (free or wall)."""
        known = self.seen_free | self.seen_wall
        if include_carved:
            known = known | self.carved
        total = np.count_nonzero(valid)
        return np.count_nonzero(known & valid) / total if total else 1.0
