"""The robot's own map, built from measured line-of-sight scans and, separately, from NLOS space carving.

A scan is integrated along each ray by the exact DDA of :mod:`superex_deploy.geometry`: every cell the ray leaves
before its return is seen free, the cell of the return is seen occupied (:func:`~superex_deploy.geometry.mark_ranges`).
Free cells proven by the NLOS processing ("carved") are kept in their own mask so that coverage can be reported with
and without them; they count as FREE in :meth:`Mapper.observed` but never override a wall seen in line of sight.
"""

from __future__ import annotations

import numpy as np

from superex_deploy.geometry import mark_ranges
from superex_deploy.messages import LaserScan, MapFrame, Pose2D, grid_angles
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

__all__ = ["Mapper"]


class Mapper:
    """Observed map over a grid of shape ``[H, W]`` (``[row, col]``).

    Attributes:
        seen_free: bool ``[H, W]`` cells crossed by a line-of-sight ray.
        seen_wall: bool ``[H, W]`` cells holding a line-of-sight return.
        carved: bool ``[H, W]`` cells proven free by NLOS carving (may overlap the two above).
    """

    def __init__(self, shape: tuple[int, int]):
        shape = tuple(int(n) for n in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be a positive (rows, cols) pair, got {shape}")
        self.seen_free = np.zeros(shape, bool)
        self.seen_wall = np.zeros(shape, bool)
        self.carved = np.zeros(shape, bool)

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.seen_free.shape  # type: ignore[return-value]

    def integrate_scan(self, frame: MapFrame, pose: Pose2D, scan: LaserScan) -> None:
        """Mark what a measured scan taken at ``pose`` saw.

        A range in ``[range_min, range_max]`` is a return; ``+inf`` or a range above ``range_max`` is no return
        (free up to ``range_max``); NaN, ``-inf`` and ranges below ``range_min`` are invalid readings (REP 117: too
        close, or a dropout) and the ray is skipped, so a scan without a valid reading leaves the map as it was.
        Angles are turned from the robot's frame (counter-clockwise from its heading) into grid angles.

        Raises:
            ValueError: a frame of another shape, a pose outside the map.
        """
        if tuple(frame.shape) != self.shape:
            raise ValueError(f"the map frame has shape {frame.shape}, the map {self.shape}")
        origin, _ = frame.locate(pose.x, pose.y)
        resolution = frame.resolution_m
        ranges = scan.ranges.astype(np.float64)
        valid = ~np.isnan(ranges) & (ranges >= scan.range_min)
        returned = valid & (ranges <= scan.range_max)
        angles = grid_angles(pose.yaw, scan.angles())
        self.integrate_ranges(origin, angles[valid], np.where(returned, ranges / resolution, np.inf)[valid],
                              scan.range_max / resolution)

    def integrate_ranges(self, origin_yx, angles, ranges_cells, max_range_cells: float) -> None:
        """Mark what a measured scan saw, in grid units: see :func:`superex_deploy.geometry.mark_ranges`.

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
