"""The log-odds update of one line-of-sight scan, and its parameters (:class:`OccupancyConfig`): the inverse sensor
model that :class:`~superex_deploy.onboard.mapping.mapper.Mapper` applies (why each rule: the mapper's module
docstring). :func:`integrate_log_odds` walks every ray with the exact DDA of :mod:`superex_deploy.geometry` and gives
each touched cell one hit or one miss; :func:`clear_limits` bounds how far a ray clears under a pose's uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.geometry import RETURN_TOLERANCE_CELLS, check_measured_rays, dda_start, dda_step

__all__ = ["OccupancyConfig", "integrate_log_odds", "clear_limits"]


@dataclass(frozen=True)
class OccupancyConfig(JsonConfig):
    """Log-odds occupancy parameters (natural log-odds ``ln(p / (1 - p))``; OctoMap's defaults in brackets).

    Attributes:
        hit: added at a return's cell (2.5, p = 0.92) [0.85]. A hit from the free clamp reaches the occupied
            threshold: a wall wins over a free history.
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
        range_sigma_m: the LiDAR's range noise (standard deviation, metres; its calibration, or the simulated
            sensor's ``--lidar-noise`` sigma). 0: the ranges are taken as exact (the noise-free protocol).
        range_hit_sigmas: with ``range_sigma_m > 0`` each return's hit is placed this many sigmas beyond the
            measured range, and the misses stop before that cell (see the module docstring).
        usable_range_m: the usable range (metres; GMapping's ``maxUrange``, slam_toolbox's ``max_laser_range``,
            costmap_2d's ``raytrace_range``): a return beyond it, and a reading that says "no return" (``+inf``,
            ``range_max`` and above, as REP 117 and the drivers code it), clears free space only up to it (and up
            to ``range_max``), stopping at the first cell the map holds occupied: such a ray never lowers a wall.
            A SICK LMS codes no echo as 81.83 m with ``range_max`` 80 m: taken as 80 m of free space, every one
            cleared the building's walls behind a glass door. The default, 20 m, is slam_toolbox's and the
            simulated LiDAR's range (the benchmarks are unchanged); indoors 2D LiDARs (Hokuyo UST-20, SICK TiM,
            RPLIDAR) measure walls reliably to 10-25 m.
        pose_clearing_sigmas: with a pose covariance, a ray clears only as far as every ray within this many
            lateral sigmas of the pose error around it reaches (see the module docstring); 0: as far as it reaches.
        footprint_clearing: each step, the cells under the robot's body become free (:meth:`Mapper.clear_footprint`).
        footprint_margin_sigmas: the footprint disc is the robot radius less this many position sigmas of the
            pose covariance (an exact pose: the whole radius).
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
    range_sigma_m: float = 0.0
    range_hit_sigmas: float = 2.0
    usable_range_m: float = 20.0
    pose_clearing_sigmas: float = 1.0
    footprint_clearing: bool = True
    footprint_margin_sigmas: float = 2.0

    def __post_init__(self) -> None:
        for name in ("range_sigma_m", "range_hit_sigmas", "footprint_margin_sigmas", "pose_clearing_sigmas"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)) \
                    or not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"OccupancyConfig.{name} must be a finite number >= 0, got {value!r}")
        usable = self.usable_range_m
        if isinstance(usable, (bool, np.bool_)) or not isinstance(usable, (int, float, np.number)) \
                or not (np.isfinite(usable) and usable > 0.0):
            raise ValueError(f"OccupancyConfig.usable_range_m must be a positive finite number of metres, got "
                             f"{usable!r}")
        if not isinstance(self.footprint_clearing, (bool, np.bool_)):
            raise ValueError(f"OccupancyConfig.footprint_clearing must be a bool, got {self.footprint_clearing!r}")
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
def _integrate_log_odds(y0, x0, angles, ranges, max_t, tolerance, hit_shift, log_odds, touched, hit, miss, lowest,
                        highest, weak_t, weak_stop, clear_t):
    """One scan's log-odds update: walk every ray as :func:`superex_deploy.geometry._mark_ranges` does, its return
    moved ``hit_shift`` cells farther (walked past ``max_t`` if need be), counting in ``touched`` (int32
    ``[H, W, 2]``, zero on entry and on return) the rays that crossed each cell (``[..., 0]``) and that returned in
    it (``[..., 1]``), then give each touched cell one update: ``hit`` where at least as many rays returned in it
    as crossed it, else ``miss``; clamped to ``[lowest, highest]``. ``ranges[i] < 0``: no return, walked only up
    to ``weak_t`` and stopped before the first cell whose log-odds (before this scan) is ``weak_stop`` or more.
    Ray ``i`` crosses only the cells it leaves by ``clear_t[i]`` (a return's hit is placed all the same)."""
    n_rows, n_cols = log_odds.shape
    top, left, bottom, right = n_rows, n_cols, -1, -1
    for i in range(angles.shape[0]):
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
            y0, x0, np.sin(angles[i]), np.cos(angles[i]))
        weak = ranges[i] < 0.0
        hit_at = ranges[i] + hit_shift + tolerance if not weak else -1.0
        # Without a shift the walk stops at max_t exactly as geometry.mark_ranges does (the noise-free map).
        stop_t = max(max_t, hit_at) if hit_shift > 0.0 else max_t
        if weak:
            stop_t = min(max_t, weak_t)
        while True:
            if weak and log_odds[r, c] >= weak_stop:
                break
            top, bottom = min(top, r), max(bottom, r)
            left, right = min(left, c), max(right, c)
            t_exit = min(t_next_c, t_next_r)
            if hit_at >= 0.0 and t_exit > hit_at:
                touched[r, c, 1] += 1
                break
            if t_exit <= clear_t[i]:
                touched[r, c, 0] += 1
            elif weak:
                break
            r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                      t_delta_c)
            if t > stop_t or r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                break
    for r in range(top, bottom + 1):
        for c in range(left, right + 1):
            crossed, returned = touched[r, c, 0], touched[r, c, 1]
            if crossed == 0 and returned == 0:
                continue
            value = log_odds[r, c] + (hit if returned > 0 and returned >= crossed else miss)
            log_odds[r, c] = min(max(value, lowest), highest)
            touched[r, c, 0] = 0
            touched[r, c, 1] = 0


_MAX_HALF_WINDOW = np.pi / 6.0
"""The angular half-window of :func:`_clear_limits` at most (radians): near the robot a position sigma spans wide
angles, and 30 degrees either side is already more than a ray's neighbourhood."""


@numba.njit(cache=True)
def _clear_limits(angles, reach, sigma_xy, sigma_yaw, sigmas, limits):
    """Per ray ``i`` (``angles`` sorted, radians in ``[0, 2 pi)``): the largest ``t <= reach[i]`` that every ray
    within the angular half-window ``atan(u(t) / t)`` of it reaches, ``u(t) = sigmas sqrt(sigma_xy^2 + (t
    sigma_yaw)^2)`` (cells) the lateral uncertainty at ``t``; the window widens as ``t`` shrinks, so ``t`` is
    lowered to the nearest reach in it until it holds (at most 8 times). Written to ``limits``."""
    n = angles.shape[0]
    two_pi = 2.0 * np.pi
    for i in range(n):
        t = reach[i]
        for _ in range(8):
            u = sigmas * np.sqrt(sigma_xy * sigma_xy + t * t * sigma_yaw * sigma_yaw)
            half = min(np.arctan2(u, max(t, 1e-9)), _MAX_HALF_WINDOW)
            nearest = reach[i]
            for step in (1, -1):
                j = i
                for _k in range(n - 1):
                    j = (j + step) % n
                    gap = (angles[j] - angles[i]) % two_pi
                    if min(gap, two_pi - gap) > half:
                        break
                    nearest = min(nearest, reach[j])
            if nearest >= t:
                break
            t = nearest
        limits[i] = t


def clear_limits(angles: np.ndarray, reach: np.ndarray, sigma_xy_cells: float, sigma_yaw_rad: float,
                 sigmas: float) -> np.ndarray:
    """float64 ``[N]``: how far each ray of a scan may clear under a pose error of ``sigma_xy_cells`` /
    ``sigma_yaw_rad`` (see the module docstring and :func:`_clear_limits`), from the rays' grid angles and the
    distances ``reach`` (cells) they walk to (their shifted returns, or their clearing range); ``reach`` itself
    when ``sigmas`` or both sigmas are 0."""
    angles, reach = np.asarray(angles, np.float64), np.asarray(reach, np.float64)
    if sigmas == 0.0 or (sigma_xy_cells == 0.0 and sigma_yaw_rad == 0.0) or reach.size == 0:
        return reach.copy()
    wrapped = np.mod(angles, 2.0 * np.pi)
    order = np.argsort(wrapped, kind="stable")
    limits = np.empty(reach.size, np.float64)
    _clear_limits(np.ascontiguousarray(wrapped[order]), np.ascontiguousarray(reach[order]), float(sigma_xy_cells),
                  float(sigma_yaw_rad), float(sigmas), limits)
    out = np.empty_like(limits)
    out[order] = limits
    return out


def integrate_log_odds(log_odds: np.ndarray, origin_yx, angles, ranges_cells, max_range_cells: float,
                       cfg: OccupancyConfig = OccupancyConfig(), touched: np.ndarray = None,
                       hit_shift_cells: float = 0.0, usable_range_cells: float = np.inf,
                       pose_sigmas: Optional[tuple[float, float]] = None) -> None:
    """Update a log-odds grid with one measured scan (see the module docstring), in grid units.

    Args:
        log_odds: float32 ``[H, W]`` C-contiguous, updated in place.
        origin_yx: sensor position ``(y, x)`` in cells, inside the grid.
        angles: float ``[N]`` ray angles (radians, grid convention: ``(dy, dx) = (sin, cos)``).
        ranges_cells: float ``[N]`` measured ranges (cells, >= 0), ``inf`` for no return.
        max_range_cells: the sensor's maximum range (cells, > 0).
        cfg: the update and its clamps.
        touched: optional int32 ``[H, W, 2]`` all-zero scratch (kept all zero); None: one is made.
        hit_shift_cells: how much farther than measured each return is placed (cells, >= 0; the calibrated
            sensor model's ``range_hit_sigmas * range_sigma_m``, see :class:`OccupancyConfig`): the misses stop
            before the shifted return's cell. 0: the measured range as it is.
        usable_range_cells: a ray without a return (``inf``) clears only up to this (cells, > 0; and up to
            ``max_range_cells``) and stops before the first cell at or above ``cfg.occupied_threshold``: such a ray
            never lowers a wall (:class:`OccupancyConfig` ``usable_range_m``).
        pose_sigmas: ``(sigma_xy cells, sigma_yaw radians)`` of the pose the scan is placed at, or None (exact):
            each ray clears only as far as :func:`clear_limits` allows (``cfg.pose_clearing_sigmas``).

    Raises:
        ValueError: a grid that is not float32 ``[H, W]`` C-contiguous and writeable, a bad scratch grid, an origin
            outside the grid, non-finite angles, NaN or negative ranges, lengths that differ, a negative or
            non-finite shift.
    """
    if not isinstance(log_odds, np.ndarray) or log_odds.dtype != np.float32 or log_odds.ndim != 2 \
            or min(log_odds.shape) < 1 or not log_odds.flags.c_contiguous or not log_odds.flags.writeable:
        raise ValueError("log_odds must be a non-empty, C-contiguous, writeable float32 [H, W] array")
    if touched is None:
        touched = np.zeros(log_odds.shape + (2,), np.int32)
    elif not isinstance(touched, np.ndarray) or touched.dtype != np.int32 or touched.shape != log_odds.shape + (2,) \
            or not touched.flags.c_contiguous or not touched.flags.writeable:
        raise ValueError(f"touched must be a C-contiguous, writeable int32 array of shape {log_odds.shape + (2,)}")
    if isinstance(hit_shift_cells, (bool, np.bool_)) or not isinstance(hit_shift_cells, (int, float, np.number)) \
            or not (np.isfinite(hit_shift_cells) and hit_shift_cells >= 0.0):
        raise ValueError(f"hit_shift_cells must be a finite number >= 0, got {hit_shift_cells!r}")
    if isinstance(usable_range_cells, (bool, np.bool_)) or not isinstance(usable_range_cells, (int, float, np.number)) \
            or not usable_range_cells > 0.0:
        raise ValueError(f"usable_range_cells must be a number > 0, got {usable_range_cells!r}")
    y0, x0, angles, ranges, max_t = check_measured_rays(log_odds.shape, origin_yx, angles, ranges_cells,
                                                        max_range_cells)
    weak_t = float(usable_range_cells)
    if pose_sigmas is None:
        clear_t = np.full(ranges.shape, np.inf)
    else:
        sigma_xy, sigma_yaw = (float(v) for v in pose_sigmas)
        if not (np.isfinite(sigma_xy) and np.isfinite(sigma_yaw) and sigma_xy >= 0.0 and sigma_yaw >= 0.0):
            raise ValueError(f"pose_sigmas must be two finite numbers >= 0, got {pose_sigmas!r}")
        reach = np.where(ranges >= 0.0, ranges + float(hit_shift_cells) + RETURN_TOLERANCE_CELLS, min(max_t, weak_t))
        limits = clear_limits(angles, reach, sigma_xy, sigma_yaw, float(cfg.pose_clearing_sigmas))
        clear_t = np.where(limits < reach, limits, np.inf)  # unlimited rays walk exactly as without pose_sigmas
    _integrate_log_odds(y0, x0, angles, ranges, max_t, RETURN_TOLERANCE_CELLS, float(hit_shift_cells), log_odds,
                        touched, float(cfg.hit), float(cfg.miss), float(cfg.lowest), float(cfg.highest),
                        weak_t, float(cfg.occupied_threshold), clear_t)
