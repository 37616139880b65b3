"""The robot's own map: a probabilistic occupancy grid in log-odds, built from measured line-of-sight scans (or
taken from a SLAM map) and, in a layer of its own, from NLOS space carving.

Line of sight (as costmap_2d's voxel layer and OctoMap keep it): each scan is walked ray by ray with the exact DDA
of :mod:`superex_deploy.geometry` (the cells a ray leaves before its return were crossed, the cell of the return
was hit: :func:`~superex_deploy.geometry.mark_ranges`); then every cell the scan touched gets **one** update, a
hit if any ray returned in it (a hit wins over the misses of the same scan), else a miss:
``l += hit`` or ``l += miss`` (negative), clamped to ``[lowest, highest]``. A cell is **occupied** at
``l >= occupied_threshold``, **free** at ``l <= free_threshold``, unknown in between. Clamping bounds what any
history weighs, so no cell is decided for good by one reading: a wall hit once is cleared by a few scans that see
through it, and a cell seen free becomes a wall with one hit.

The defaults (:class:`OccupancyConfig`) reproduce the binary map this replaced on noise-free data: one miss makes
an unknown cell free, one hit makes any cell occupied (a wall wins over a free history, as ``seen_wall`` did), and
a wall hit once stays occupied through 5 scans that cross it (through 8 once confirmed). Measured on noise-free
episodes, no cell is ever both hit and crossed, so the thresholded map is exactly the old one.

**SLAM map.** :meth:`Mapper.set_line_of_sight` replaces the line-of-sight layer by a published map
(``nav_msgs/OccupancyGrid`` percentages, thresholded as costmap_2d does: occupied at or above
``slam_occupied_percent``, free at or below ``slam_free_percent``).

**Carving** enters as evidence, in a layer of its own so coverage can be reported with and without it: each
carving pushes a cell's carving log-odds down by ``carve_step``, to at most ``carve_lowest`` in all. A carved cell
counts as free when the line-of-sight log-odds plus the carving log-odds reach the free threshold, and never where
the line of sight holds a wall (``l >= occupied_threshold``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from superex_deploy.geometry import RETURN_TOLERANCE_CELLS, check_measured_rays, dda_start, dda_step
from superex_deploy.messages import LaserScan, MapFrame, Pose2D, grid_angles
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

__all__ = ["OccupancyConfig", "Mapper", "integrate_log_odds"]


@dataclass(frozen=True)
class OccupancyConfig:
    """Log-odds occupancy parameters (natural log-odds ``ln(p / (1 - p))``; OctoMap's defaults in brackets).

    Attributes:
        hit: added at a return's cell (2.5, p = 0.92) [0.85]. A hit from the free clamp reaches the occupied
            threshold: a wall wins over a free history, as in the binary map this replaced.
        miss: added to a cell a ray crossed (-0.4, p = 0.40) [-0.4].
        lowest, highest: clamps (-2.0 and 3.5: p = 0.12 and 0.97) [the same].
        occupied_threshold: occupied at or above (0.25, p = 0.56). Every reachable value is a multiple of 0.1:
            the thresholds sit halfway between two, away from rounding.
        free_threshold: free at or below (-0.25, p = 0.44): one miss makes an unknown cell free.
        carve_step: added to a cell's carving log-odds by each carving (-0.4: one carving makes an unknown
            cell free).
        carve_lowest: the carving log-odds' clamp (-1.0): carving moves a cell towards free by at most this
            much in all, and never frees a cell the line of sight holds occupied.
        slam_occupied_percent: a SLAM map's cell is occupied at or above this (costmap_2d: 65).
        slam_free_percent: ... and free at or below this (costmap_2d's ``free_thresh`` 0.25: 25).
    """

    hit: float = 2.5
    miss: float = -0.4
    lowest: float = -2.0
    highest: float = 3.5
    occupied_threshold: float = 0.25
    free_threshold: float = -0.25
    carve_step: float = -0.4
    carve_lowest: float = -1.0
    slam_occupied_percent: int = 65
    slam_free_percent: int = 25

    def __post_init__(self) -> None:
        values = [getattr(self, name) for name in ("hit", "miss", "lowest", "highest", "occupied_threshold",
                                                   "free_threshold", "carve_step", "carve_lowest")]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in values):
            raise ValueError(f"OccupancyConfig: the log-odds values must be finite numbers, got {values}")
        if not (self.miss < 0.0 < self.hit):
            raise ValueError(f"OccupancyConfig: need miss < 0 < hit, got miss={self.miss}, hit={self.hit}")
        if not (self.lowest < self.free_threshold < 0.0 < self.occupied_threshold < self.highest):
            raise ValueError(f"OccupancyConfig: need lowest < free_threshold < 0 < occupied_threshold < highest, "
                             f"got {self.lowest}, {self.free_threshold}, {self.occupied_threshold}, {self.highest}")
        if not (self.carve_lowest <= self.carve_step < 0.0):
            raise ValueError(f"OccupancyConfig: need carve_lowest <= carve_step < 0, got {self.carve_lowest}, "
                             f"{self.carve_step}")
        for name in ("slam_occupied_percent", "slam_free_percent"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= 100:
                raise ValueError(f"OccupancyConfig.{name} must be an integer in [0, 100], got {value!r}")
        if not self.slam_free_percent < self.slam_occupied_percent:
            raise ValueError(f"OccupancyConfig: need slam_free_percent < slam_occupied_percent, got "
                             f"{self.slam_free_percent} and {self.slam_occupied_percent}")


@numba.njit(cache=True)
def _integrate_log_odds(y0, x0, angles, ranges, max_t, tolerance, log_odds, touched, hit, miss, lowest, highest):
    """One scan's log-odds update: walk every ray as :func:`superex_deploy.geometry._mark_ranges` does, noting in
    ``touched`` (int8, zero on entry and on return) 1 for a crossed cell and 2 for a return's cell, then give each
    touched cell one update (``hit`` where any ray returned, else ``miss``), clamped to ``[lowest, highest]``.
    ``ranges[i] < 0``: no return."""
    n_rows, n_cols = log_odds.shape
    top, left, bottom, right = n_rows, n_cols, -1, -1
    for i in range(angles.shape[0]):
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
            y0, x0, np.sin(angles[i]), np.cos(angles[i]))
        hit_at = ranges[i] + tolerance if ranges[i] >= 0.0 else -1.0
        while True:
            top, bottom = min(top, r), max(bottom, r)
            left, right = min(left, c), max(right, c)
            t_exit = min(t_next_c, t_next_r)
            if hit_at >= 0.0 and t_exit > hit_at:
                touched[r, c] = 2
                break
            if touched[r, c] == 0:
                touched[r, c] = 1
            r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                      t_delta_c)
            if t > max_t or r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                break
    for r in range(top, bottom + 1):
        for c in range(left, right + 1):
            kind = touched[r, c]
            if kind == 0:
                continue
            value = log_odds[r, c] + (hit if kind == 2 else miss)
            log_odds[r, c] = min(max(value, lowest), highest)
            touched[r, c] = 0


def integrate_log_odds(log_odds: np.ndarray, origin_yx, angles, ranges_cells, max_range_cells: float,
                       cfg: OccupancyConfig = OccupancyConfig(), touched: np.ndarray = None) -> None:
    """Update a log-odds grid with one measured scan (see the module docstring), in grid units.

    Args:
        log_odds: float32 ``[H, W]`` C-contiguous, updated in place.
        origin_yx: sensor position ``(y, x)`` in cells, inside the grid.
        angles: float ``[N]`` ray angles (radians, grid convention: ``(dy, dx) = (sin, cos)``).
        ranges_cells: float ``[N]`` measured ranges (cells, >= 0), ``inf`` for no return.
        max_range_cells: the sensor's maximum range (cells, > 0).
        cfg: the update and its clamps.
        touched: optional int8 ``[H, W]`` all-zero scratch grid (kept all zero); None: one is made.

    Raises:
        ValueError: a grid that is not float32 ``[H, W]`` C-contiguous and writeable, a bad scratch grid, an origin
            outside the grid, non-finite angles, NaN or negative ranges, lengths that differ.
    """
    if not isinstance(log_odds, np.ndarray) or log_odds.dtype != np.float32 or log_odds.ndim != 2 \
            or min(log_odds.shape) < 1 or not log_odds.flags.c_contiguous or not log_odds.flags.writeable:
        raise ValueError("log_odds must be a non-empty, C-contiguous, writeable float32 [H, W] array")
    if touched is None:
        touched = np.zeros(log_odds.shape, np.int8)
    elif not isinstance(touched, np.ndarray) or touched.dtype != np.int8 or touched.shape != log_odds.shape \
            or not touched.flags.c_contiguous or not touched.flags.writeable:
        raise ValueError(f"touched must be a C-contiguous, writeable int8 array of shape {log_odds.shape}")
    y0, x0, angles, ranges, max_t = check_measured_rays(log_odds.shape, origin_yx, angles, ranges_cells,
                                                        max_range_cells)
    _integrate_log_odds(y0, x0, angles, ranges, max_t, RETURN_TOLERANCE_CELLS, log_odds, touched, float(cfg.hit),
                        float(cfg.miss), float(cfg.lowest), float(cfg.highest))


class Mapper:
    """Observed map over a grid of shape ``[H, W]`` (``[row, col]``), in log-odds (see the module docstring).

    Args:
        shape: ``(rows, cols)``.
        cfg: the log-odds parameters.

    Attributes:
        cfg: as given.
        log_odds: float32 ``[H, W]`` line-of-sight log-odds (0: nothing measured).
        carve_log_odds: float32 ``[H, W]`` carving log-odds, in ``[cfg.carve_lowest, 0]``.

    The masks below are derived from the two layers at each read (bool ``[H, W]``, fresh arrays).
    """

    def __init__(self, shape: tuple[int, int], cfg: OccupancyConfig = OccupancyConfig()):
        shape = tuple(int(n) for n in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be a positive (rows, cols) pair, got {shape}")
        if not isinstance(cfg, OccupancyConfig):
            raise ValueError(f"cfg must be an OccupancyConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self.log_odds = np.zeros(shape, np.float32)
        self.carve_log_odds = np.zeros(shape, np.float32)
        self._touched = np.zeros(shape, np.int8)  # the scan kernel's scratch, all zero between scans

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.log_odds.shape  # type: ignore[return-value]

    @property
    def seen_wall(self) -> np.ndarray:
        """Cells the line of sight holds occupied (``log_odds >= occupied_threshold``)."""
        return self.log_odds >= self.cfg.occupied_threshold

    @property
    def seen_free(self) -> np.ndarray:
        """Cells the line of sight holds free with confidence (``log_odds <= free_threshold``)."""
        return self.log_odds <= self.cfg.free_threshold

    @property
    def carved(self) -> np.ndarray:
        """Cells NLOS carving pushed towards free (may overlap the two above)."""
        return self.carve_log_odds < 0.0

    @property
    def carved_free(self) -> np.ndarray:
        """Cells free by carving: carved, not held occupied, and line-of-sight plus carving log-odds at or below
        the free threshold."""
        carved = self.carve_log_odds < 0.0
        return carved & ~self.seen_wall & (self.log_odds + self.carve_log_odds <= self.cfg.free_threshold)

    def integrate_scan(self, frame: MapFrame, pose: Pose2D, scan: LaserScan) -> None:
        """Update the map with a measured scan taken at ``pose``.

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
        """Update the map with a measured scan, in grid units: see :func:`integrate_log_odds`.

        Args:
            origin_yx: sensor position ``(y, x)`` in cells, inside the map.
            angles: float64 ``[N]`` ray angles (radians, grid convention: ``(dy, dx) = (sin, cos)``).
            ranges_cells: float64 ``[N]`` measured ranges (cells), ``inf`` for no return.
            max_range_cells: the sensor's maximum range (cells).
        """
        integrate_log_odds(self.log_odds, origin_yx, angles, ranges_cells, max_range_cells, self.cfg, self._touched)

    def set_line_of_sight(self, occupancy_percent: np.ndarray) -> None:
        """Replace the line-of-sight layer by a SLAM map on this grid (the carving layer is kept).

        Args:
            occupancy_percent: int8 ``[H, W]``: -1 unknown, 0..100 occupancy in percent
                (:meth:`superex_deploy.messages.OccupancyGridMessage.in_frame`). Cells at or above
                ``slam_occupied_percent`` become ``highest``, known cells at or below ``slam_free_percent``
                ``lowest``, the others 0 (unknown).
        """
        grid = np.asarray(occupancy_percent)
        if grid.dtype != np.int8 or grid.shape != self.shape:
            raise ValueError(f"occupancy_percent must be int8 of shape {self.shape}, got {grid.dtype} {grid.shape}")
        cfg = self.cfg
        self.log_odds[...] = 0.0
        self.log_odds[(grid >= 0) & (grid <= cfg.slam_free_percent)] = cfg.lowest
        self.log_odds[grid >= cfg.slam_occupied_percent] = cfg.highest

    def merge_carved(self, carved: np.ndarray) -> None:
        """Add the cells one NLOS carving proved free: their carving log-odds move by ``carve_step``, clamped at
        ``carve_lowest``.

        Args:
            carved: bool ``[H, W]``.
        """
        carved = np.asarray(carved)
        if carved.dtype != np.bool_ or carved.shape != self.shape:
            raise ValueError(f"carved must be a bool array of shape {self.shape}, got {carved.dtype} "
                             f"{carved.shape}")
        if carved.any():
            values = self.carve_log_odds[carved].astype(np.float64) + self.cfg.carve_step
            self.carve_log_odds[carved] = np.maximum(values, self.cfg.carve_lowest)

    def known(self, include_carved: bool = True) -> np.ndarray:
        """bool ``[H, W]``: cells held free or occupied (plus cells free by carving if ``include_carved``)."""
        known = self.seen_free | self.seen_wall
        return known | self.carved_free if include_carved else known

    def drivable(self, include_carved: bool = False) -> np.ndarray:
        """bool ``[H, W]``: cells a path may cross: held free with confidence by the line of sight (plus cells free
        by carving if ``include_carved``)."""
        return self.seen_free | self.carved_free if include_carved else self.seen_free

    def observed(self, include_carved: bool = True) -> np.ndarray:
        """int8 ``[H, W]``: OCCUPIED where the line of sight holds a wall, FREE where it holds free (or, with
        ``include_carved``, where carving makes it free), else UNKNOWN."""
        free = self.drivable(include_carved)
        observed = np.full(self.shape, UNKNOWN, np.int8)
        observed[free] = FREE
        observed[self.seen_wall] = OCCUPIED
        return observed
