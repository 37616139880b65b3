"""The robot's observed map, built from line-of-sight scans and, separately, from NLOS space carving.

Line-of-sight scans use the exact DDA ray caster of :mod:`superex_deploy.geometry`: every cell a ray crosses
before its first wall is seen free, the wall cell it hits is seen occupied. Free cells proven by the NLOS
processing ("carved") are kept in their own mask so that coverage can be reported with and without them; they
count as FREE in :meth:`Mapper.observed` but never override a wall seen in line of sight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from superex_deploy.explore import metrics
from superex_deploy.explore.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.geometry import cell_centre, mark_ranges, mark_rays, ray_angles

__all__ = ["LidarConfig", "Mapper"]


@dataclass(frozen=True)
class LidarConfig:
    """The robot's line-of-sight 2-D LiDAR (MapEx ``lidar_sim_configs``: 2500 rays over a full turn, 20 m).

    Attributes:
        n_rays: rays per scan, evenly spaced over 360 degrees starting along ``+col``.
        range_m: maximum range (metres); cells entered beyond it stay unknown.
    """

    n_rays: int = 2500
    range_m: float = 20.0

    def __post_init__(self) -> None:
        if int(self.n_rays) < 1 or not (float(self.range_m) > 0.0 and np.isfinite(self.range_m)):
            raise ValueError(f"LidarConfig needs n_rays >= 1 and a positive finite range_m, got n_rays="
                             f"{self.n_rays}, range_m={self.range_m}")


class Mapper:
    """Observed map over a ground-truth grid of shape ``[H, W]`` (``[row, col]``).

    Attributes:
        seen_free: bool ``[H, W]`` cells crossed by a line-of-sight ray.
        seen_wall: bool ``[H, W]`` wall cells hit by a line-of-sight ray.
        carved: bool ``[H, W]`` cells proven free by NLOS carving (may overlap the two above).
    """

    def __init__(self, shape: tuple[int, int], lidar: LidarConfig = LidarConfig()):
        shape = tuple(int(n) for n in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be a positive (rows, cols) pair, got {shape}")
        self.lidar = lidar
        self.seen_free = np.zeros(shape, bool)
        self.seen_wall = np.zeros(shape, bool)
        self.carved = np.zeros(shape, bool)
        self._angles = ray_angles(lidar.n_rays)

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.seen_free.shape  # type: ignore[return-value]

    def integrate_scan(self, ground_truth: np.ndarray, pose_rc, resolution_m: float) -> None:
        """Scan from the centre of the robot cell through the ground truth and mark what the rays see.

        Args:
            ground_truth: bool ``[H, W]`` walls the rays travel through.
            pose_rc: robot cell (row, col), inside the grid.
            resolution_m: metres per cell (> 0), to convert the range to cells.

        Raises:
            ValueError: shape mismatch, a pose off the grid, a non-positive resolution.
        """
        ground_truth = np.asarray(ground_truth)
        if ground_truth.shape != self.shape:
            raise ValueError(f"ground truth has shape {ground_truth.shape}, the map has {self.shape}")
        if not (float(resolution_m) > 0.0 and np.isfinite(resolution_m)):
            raise ValueError(f"resolution_m must be positive and finite, got {resolution_m}")
        r, c = int(pose_rc[0]), int(pose_rc[1])
        if not (0 <= r < self.shape[0] and 0 <= c < self.shape[1]):
            raise ValueError(f"pose (row, col) = {(r, c)} lies outside the map of shape {self.shape}")
        mark_rays(ground_truth, cell_centre((r, c)), self._angles, self.lidar.range_m / float(resolution_m),
                  self.seen_free, self.seen_wall)

    def integrate_ranges(self, origin_yx, angles, ranges_cells, max_range_cells: float) -> None:
        """Mark what a measured scan saw (no ground truth): see :func:`superex_deploy.geometry.mark_ranges`.

        Args:
            origin_yx: sensor position ``(y, x)`` in cells, inside the map.
            angles: float64 ``[N]`` ray angles (radians, grid convention: ``(dy, dx) = (sin, cos)``).
            ranges_cells: float64 ``[N]`` measured ranges (cells), ``inf`` for no return.
            max_range_cells: the sensor's maximum range (cells).
        """
        mark_ranges(origin_yx, angles, ranges_cells, max_range_cells, self.seen_free, self.seen_wall)

    def merge_carved(self, carved: np.ndarray) -> None:
        """Add cells proven free by NLOS space carving.

        Args:
            carved: bool ``[H, W]``; True cells are added to :attr:`carved` (never removed).
        """
        carved = np.asarray(carved)
        if carved.dtype != np.bool_ or carved.shape != self.shape:
            raise ValueError(f"carved must be a bool array of shape {self.shape}, got {carved.dtype} "
                             f"{carved.shape}")
        self.carved |= carved

    def known(self, include_carved: bool = True) -> np.ndarray:
        """bool ``[H, W]``: cells seen free or occupied (plus carved cells if ``include_carved``)."""
        known = self.seen_free | self.seen_wall
        return known | self.carved if include_carved else known

    def observed(self, include_carved: bool = True) -> np.ndarray:
        """int8 ``[H, W]``: OCCUPIED where a wall was seen, FREE where seen (or carved) free, else UNKNOWN."""
        free = self.seen_free | self.carved if include_carved else self.seen_free
        observed = np.full(self.shape, UNKNOWN, np.int8)
        observed[free] = FREE
        observed[self.seen_wall] = OCCUPIED
        return observed

    def coverage(self, valid: np.ndarray, include_carved: bool = True) -> float:
        """Known fraction of the valid area (bool ``[H, W]``), see :func:`metrics.coverage`."""
        return metrics.coverage(self.known(include_carved), np.asarray(valid, bool))
