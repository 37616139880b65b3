"""The NLOS gain of a viewpoint: the unknown cells the SPAD's carving would prove free from there, estimated on the
map and the prediction.

Today's gain counts what the robot would see in line of sight. The SPAD also carves: each wall point the robot
sees relays a fan of light into the half-plane in front of it, and its first late photon proves free a disc sector
as far as the nearest surface that fan meets (:mod:`superex_deploy.onboard.nlos.carving`). A goal beside a long
relay wall with open space around its corner can carve much that line of sight would not see. The estimate here
runs that geometry on the planning map instead of a measured scan:

1. **Relay walls.** The walls are the observed walls and the unknown cells the prediction holds at or above
   ``wall_threshold``. From a viewpoint, ``n_rays`` rays over a full turn stop at the first wall cell within
   ``range_m``; each distinct cell hit is a relay point.
2. **Trusted as the onboard carving trusts** (the same rules, read off the map): the wall cells of the window around
   the relay point (5 x 5 cells at 0.1 m, wide enough for ``interior_m``) that show the viewpoint a face (a 4-neighbour off the wall and nearer the viewpoint: what
   its LiDAR would hit) lie on one line (minor / major variance ratio at most ``max_minor_ratio``, the line's
   normal is the relay point's, turned to the viewpoint's side), they run on at least ``interior_cells`` on both
   sides of it (no wall end or corner), and the viewpoint sees it within ``max_incidence_deg`` of that normal.
3. **Its carve radius**: the distance from the relay point to the first wall cell met by ``fan_rays`` rays over the
   half-plane in front of it (the first late photon: the nearest surface its fan reaches), capped at ``cap_m``
   (the fan density's :func:`~superex_deploy.onboard.nlos.shared.carve_radius_cap_m`) and less ``margin_m`` (the
   carving's apex and bin margins). Computed once per relay point and side per call.
4. **Its carved sector**: cells within that radius, at least ``strip_m`` in front of the wall line and within
   ``sector_deg`` of the normal seen from 0.75 cells in front of the relay point (the carving's own sector test).

A viewpoint's NLOS gain is the number of UNKNOWN cells in the union of its relay points' sectors; a path's, the
union over its viewpoints (:func:`union_nlos_gains`). It is an estimate: the prediction's walls stand in for the
hidden ones, and the simulator's truth is never read (the ceiling that does: ``scripts/ceiling_carve_gain.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.geometry import dda_start, dda_step, minor_axis_2x2, window_covariance
from superex_deploy.onboard.checks import check_int, check_real
from superex_deploy.onboard.planning.visibility import check_cells, check_map
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, check_observed

__all__ = ["NlosGainConfig", "planning_walls", "viewpoint_carved", "union_nlos_gains"]

MAX_NLOS_RAYS = 4096
"""The most rays a relay-wall cast or a fan takes."""


@dataclass(frozen=True)
class NlosGainConfig(JsonConfig):
    """The carving geometry the NLOS gain runs on the planning map (metres and degrees; defaults: the onboard
    carving's :class:`~superex_deploy.onboard.nlos.NlosConfig` and the shipped 256-ray fan at 0.1 m).

    Attributes:
        n_rays: rays over a full turn from each viewpoint that find its relay walls.
        range_m: the LiDAR's range (a relay point farther away is not hit).
        wall_threshold: an unknown cell is a wall when its predicted wall probability reaches this.
        fan_rays: rays over the half-plane in front of a relay point that find its carve radius.
        cap_m: the largest carve radius (the fan density's cap, 8.1 m at 256 secondary rays and 0.1 m cells).
        margin_m: the carve radius is reduced by this (the carving's apex margin, a cell's half diagonal, a bin).
        strip_m: cells closer than this to the wall line are not counted (the carving's wall strip).
        sector_deg: half-angle of the carved sector about the normal (90 - the carving's sector margin).
        max_incidence_deg: relay points seen more obliquely than this are not carved from.
        max_minor_ratio: the wall cells around a relay point must lie on a line this straight.
        interior_m: ... and run on at least this far on both sides of it.

    Raises:
        ValueError: a field out of its range, named.
    """

    n_rays: int = 72
    range_m: float = 20.0
    wall_threshold: float = 0.5
    fan_rays: int = 24
    cap_m: float = 8.1
    margin_m: float = 0.3
    strip_m: float = 0.15
    sector_deg: float = 70.0
    max_incidence_deg: float = 70.0
    max_minor_ratio: float = 0.1
    interior_m: float = 0.2

    def __post_init__(self) -> None:
        values = {"n_rays": check_int("n_rays", self.n_rays, 3, MAX_NLOS_RAYS),
                  "fan_rays": check_int("fan_rays", self.fan_rays, 2, MAX_NLOS_RAYS),
                  "wall_threshold": check_real("wall_threshold", self.wall_threshold, 0.0, 1.0, low_open=True),
                  "sector_deg": check_real("sector_deg", self.sector_deg, 0.0, 90.0, low_open=True),
                  "max_incidence_deg": check_real("max_incidence_deg", self.max_incidence_deg, 0.0, 90.0,
                                                  low_open=True),
                  "max_minor_ratio": check_real("max_minor_ratio", self.max_minor_ratio, 0.0, 1.0, low_open=True)}
        for name in ("range_m", "cap_m"):
            values[name] = check_real(name, getattr(self, name), 0.0, low_open=True)
        for name in ("margin_m", "strip_m", "interior_m"):
            values[name] = check_real(name, getattr(self, name), 0.0)
        for name, value in values.items():
            object.__setattr__(self, name, value)


def planning_walls(observed: np.ndarray, mean: np.ndarray, wall_threshold: float) -> np.ndarray:
    """bool ``[H, W]``: the relay walls of the estimate, observed OCCUPIED cells and UNKNOWN cells whose predicted
    wall probability (float ``[H, W]`` ``mean``) reaches ``wall_threshold`` (known free cells never are)."""
    observed = check_observed(observed)
    if not (isinstance(mean, np.ndarray) and mean.dtype in (np.float32, np.float64) and mean.shape == observed.shape):
        found = f"{mean.dtype} {mean.shape}" if isinstance(mean, np.ndarray) else type(mean).__name__
        raise ValueError(f"mean must be a float32 or float64 {observed.shape} array (the map's shape), got {found}")
    return (observed == OCCUPIED) | ((observed == UNKNOWN) & (mean >= wall_threshold))


@numba.njit(cache=True, inline="always")
def _faces(walls, rr, cc, y0, x0):
    """Whether wall cell (rr, cc) shows a face to the point (y0, x0): a 4-neighbour that is no wall and whose centre
    lies closer to the point than the cell's (the cells a LiDAR there would hit, as the carving's scan hits)."""
    n_rows, n_cols = walls.shape
    here = (rr + 0.5 - y0) ** 2 + (cc + 0.5 - x0) ** 2
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        r2 = rr + dr
        c2 = cc + dc
        if 0 <= r2 < n_rows and 0 <= c2 < n_cols and not walls[r2, c2]:
            if (r2 + 0.5 - y0) ** 2 + (c2 + 0.5 - x0) ** 2 < here:
                return True
    return False


@numba.njit(cache=True)
def _relay_normal(walls, r, c, y0, x0, interior, max_minor_ratio):
    """Unit normal ``(ny, nx)`` (arbitrary sign) of the wall through cell (r, c), from the wall cells of its window
    (``half`` = max(2, ceil(interior)) cells each way: 5 x 5 at 0.1 m) that face the viewpoint (y0, x0)
    (:func:`_faces`: the surface it sees, as the carving fits its scan's hits), or ``(0, 0)`` where they do not
    lie on one straight line running at least ``interior`` cells past the cell on both sides (a corner, a wall end,
    a blob; ``interior`` with a 1e-9 tolerance, the window reaching just that far)."""
    n_rows, n_cols = walls.shape
    half = max(2, int(np.ceil(interior - 1e-9)))
    # The window's face cells, on a window-sized mask.
    faces = np.zeros((2 * half + 1, 2 * half + 1), np.bool_)
    for rr in range(max(0, r - half), min(n_rows, r + half + 1)):
        for cc in range(max(0, c - half), min(n_cols, c + half + 1)):
            faces[rr - r + half, cc - c + half] = walls[rr, cc] and _faces(walls, rr, cc, y0, x0)
    n, cyy, cxx, cxy = window_covariance(faces, half, half, half)
    if n < 3:
        return 0.0, 0.0
    half_trace, spread, vy, vx, norm = minor_axis_2x2(cyy, cxx, cxy)
    major = half_trace + spread
    if norm == 0.0 or major < 1e-9 or (half_trace - spread) > max_minor_ratio * major:
        return 0.0, 0.0
    ny = vy / norm
    nx = vx / norm
    # The wall must run on past the cell on both sides along its line (tangent (-nx, ny)).
    lo = 0.0
    hi = 0.0
    for i in range(2 * half + 1):
        for j in range(2 * half + 1):
            if faces[i, j]:
                along = -(i - half) * nx + (j - half) * ny
                lo = min(lo, along)
                hi = max(hi, along)
    if -lo < interior - 1e-9 or hi < interior - 1e-9:
        return 0.0, 0.0
    return ny, nx


@numba.njit(cache=True)
def _first_wall(walls, y0, x0, dy, dx, max_t, skip_r, skip_c):
    """Ray parameter (cells) at which the ray from (y0, x0) along unit (dy, dx) enters its first wall cell other
    than (skip_r, skip_c), or the grid border; ``max_t`` if neither comes first. Returns ``(t, r, c, hit)``."""
    n_rows, n_cols = walls.shape
    r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(y0, x0, dy, dx)
    while True:
        r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c)
        if t >= max_t:
            return max_t, r, c, False
        if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
            return t, r, c, False
        if walls[r, c] and not (r == skip_r and c == skip_c):
            return t, r, c, True


@numba.njit(cache=True)
def _carve_radius(walls, r, c, ny, nx, fan_rays, cap):
    """Distance (cells) from the centre of relay cell (r, c) to the first wall cell its fan meets: ``fan_rays``
    directions over the open half-plane about the normal (ny, nx), from 0.75 cells in front of the centre (where
    the carving's sector starts), capped at ``cap``."""
    ay = r + 0.5
    ax = c + 0.5
    oy = ay + 0.75 * ny
    ox = ax + 0.75 * nx
    radius = cap
    facing = np.arctan2(ny, nx)
    for k in range(fan_rays):
        theta = facing - 0.5 * np.pi + np.pi * (k + 0.5) / fan_rays
        dy = np.sin(theta)
        dx = np.cos(theta)
        t, _, _, hit = _first_wall(walls, oy, ox, dy, dx, cap + 1.0, r, c)
        if not hit:
            continue
        hy = oy + t * dy - ay
        hx = ox + t * dx - ax
        radius = min(radius, np.sqrt(hy * hy + hx * hx))
    return radius


@numba.njit(cache=True)
def _paint_sector(r, c, ny, nx, radius, strip, cos_sector, observed, mark, stamp, out, n_out):
    """Append to ``out`` (from ``n_out``) the flat index of every UNKNOWN cell of relay cell (r, c)'s sector
    (within ``radius`` of its centre, ``strip`` in front of its wall line, ``cos_sector`` of the normal seen from
    0.75 cells in front) not yet stamped ``stamp`` in ``mark``; stamps every cell of the sector. Returns the new
    ``(out, n_out)`` (``out`` doubled when full)."""
    n_rows, n_cols = observed.shape
    ay = r + 0.5
    ax = c + 0.5
    oy = ay + 0.75 * ny
    ox = ax + 0.75 * nx
    for rr in range(max(0, int(np.floor(ay - radius))), min(n_rows, int(np.ceil(ay + radius)) + 1)):
        vy = rr + 0.5 - ay
        for cc in range(max(0, int(np.floor(ax - radius))), min(n_cols, int(np.ceil(ax + radius)) + 1)):
            if mark[rr, cc] == stamp:
                continue
            vx = cc + 0.5 - ax
            if vy * vy + vx * vx >= radius * radius or vy * ny + vx * nx < strip:
                continue
            wy = rr + 0.5 - oy
            wx = cc + 0.5 - ox
            norm = np.sqrt(wy * wy + wx * wx)
            if norm == 0.0 or (wy * ny + wx * nx) < cos_sector * norm:
                continue
            mark[rr, cc] = stamp
            if observed[rr, cc] == -1:
                if n_out == out.shape[0]:
                    grown = np.empty(2 * out.shape[0], np.int64)
                    grown[:n_out] = out[:n_out]
                    out = grown
                out[n_out] = rr * n_cols + cc
                n_out += 1
    return out, n_out


@numba.njit(cache=True)
def _carved_of_viewpoints(walls, observed, view_rows, view_cols, n_rays, max_t, fan_rays, cap, margin, strip,
                          cos_sector, cos_incidence, max_minor_ratio, interior):
    """Flat indices of the UNKNOWN cells each viewpoint's relay points carve (see the module docstring): int64
    ``[M]`` and offsets int64 ``[V + 1]`` (viewpoint ``v``'s cells, each once, are ``[offsets[v], offsets[v + 1])``).
    A viewpoint inside a wall carves nothing."""
    n_rows, n_cols = walls.shape
    n_views = view_rows.shape[0]
    mark = np.zeros((n_rows, n_cols), np.int32)
    # Per cell and side (of the canonical sign below), the last carve radius computed and the normal it was
    # computed for (the face cells, hence the fit, may differ between viewpoints); -1: none yet.
    radius_of = np.full((n_rows, n_cols, 2), -1.0)
    normal_of = np.zeros((n_rows, n_cols, 2, 2))
    out = np.empty(1024, np.int64)
    n_out = 0
    offsets = np.zeros(n_views + 1, np.int64)
    for v in range(n_views):
        y0 = view_rows[v] + 0.5
        x0 = view_cols[v] + 0.5
        stamp = v + 1
        if not walls[view_rows[v], view_cols[v]]:
            last_r = -1
            last_c = -1
            for k in range(n_rays):
                angle = 2.0 * np.pi * k / n_rays
                t, r, c, hit = _first_wall(walls, y0, x0, np.sin(angle), np.cos(angle), max_t, -1, -1)
                if not hit or (r == last_r and c == last_c):
                    continue
                last_r = r
                last_c = c
                ny, nx = _relay_normal(walls, r, c, y0, x0, interior, max_minor_ratio)
                if ny == 0.0 and nx == 0.0:
                    continue
                if ny < 0.0 or (ny == 0.0 and nx < 0.0):  # the canonical sign of the cell's axis
                    ny = -ny
                    nx = -nx
                to_y = y0 - (r + 0.5)
                to_x = x0 - (c + 0.5)
                dist = np.sqrt(to_y * to_y + to_x * to_x)
                facing = (to_y * ny + to_x * nx) / dist
                side = 0
                if facing < 0.0:  # the viewpoint is on the -normal side
                    ny = -ny
                    nx = -nx
                    facing = -facing
                    side = 1
                if facing < cos_incidence:
                    continue
                radius = radius_of[r, c, side]
                if radius < 0.0 or normal_of[r, c, side, 0] != ny or normal_of[r, c, side, 1] != nx:
                    radius = _carve_radius(walls, r, c, ny, nx, fan_rays, cap)
                    radius_of[r, c, side] = radius
                    normal_of[r, c, side, 0] = ny
                    normal_of[r, c, side, 1] = nx
                if radius - margin <= strip:
                    continue
                out, n_out = _paint_sector(r, c, ny, nx, radius - margin, strip, cos_sector, observed, mark, stamp,
                                           out, n_out)
        offsets[v + 1] = n_out
    return out[:n_out], offsets


@numba.njit(cache=True)
def _union_counts(carved, offsets, group_views, group_offsets, n_cells):
    """int64 ``[N]``: per group (its viewpoints ``group_views[group_offsets[i]:group_offsets[i + 1]]``), the number
    of distinct cells in the union of its viewpoints' carved cells."""
    n_groups = group_offsets.shape[0] - 1
    mark = np.zeros(n_cells, np.int32)
    counts = np.zeros(n_groups, np.int64)
    for i in range(n_groups):
        stamp = i + 1
        count = 0
        for j in range(group_offsets[i], group_offsets[i + 1]):
            v = group_views[j]
            for k in range(offsets[v], offsets[v + 1]):
                cell = carved[k]
                if mark[cell] != stamp:
                    mark[cell] = stamp
                    count += 1
        counts[i] = count
    return counts


def _kernel_args(cfg: NlosGainConfig, resolution_m: float) -> tuple:
    """The kernels' geometry in cells (and cosines) for a grid of ``resolution_m`` metres."""
    s = check_real("resolution_m", resolution_m, 0.0, low_open=True)
    return (int(cfg.n_rays), cfg.range_m / s, int(cfg.fan_rays), cfg.cap_m / s, cfg.margin_m / s, cfg.strip_m / s,
            float(np.cos(np.radians(cfg.sector_deg))), float(np.cos(np.radians(cfg.max_incidence_deg))),
            float(cfg.max_minor_ratio), cfg.interior_m / s)


def viewpoint_carved(walls: np.ndarray, observed: np.ndarray, cells_rc, cfg: NlosGainConfig,
                     resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The UNKNOWN cells the SPAD's carving is estimated to prove free from each viewpoint (module docstring).

    Args:
        walls: bool ``[H, W]`` relay walls (:func:`planning_walls`).
        observed: int8 ``[H, W]`` map (UNKNOWN / FREE / OCCUPIED); only its UNKNOWN cells are returned.
        cells_rc: ``[V, 2]`` viewpoint cells (row, col).
        cfg: the carving geometry.
        resolution_m: metres per cell.

    Returns:
        ``(flat int64 [M], offsets int64 [V + 1])``: viewpoint ``v``'s cells (flat row-major indices, each once) are
        ``flat[offsets[v]:offsets[v + 1]]``.

    Raises:
        ValueError: maps of other dtypes or shapes, a cell off the map, a resolution that is not positive.
    """
    observed = check_observed(observed)
    walls = check_map("walls", walls, np.bool_, observed.shape)
    cells = check_cells(cells_rc, observed.shape)
    return _carved_of_viewpoints(walls, observed, np.ascontiguousarray(cells[:, 0]),
                                 np.ascontiguousarray(cells[:, 1]), *_kernel_args(cfg, resolution_m))


def union_nlos_gains(observed: np.ndarray, mean: np.ndarray, cells_rc, offsets, cfg: NlosGainConfig,
                     resolution_m: float) -> np.ndarray:
    """int64 ``[N]``: for each group of viewpoints (group ``i``: ``cells_rc[offsets[i]:offsets[i + 1]]``, e.g. a
    frontier's path viewpoints), the UNKNOWN cells of ``observed`` in the union of what the SPAD's carving is
    estimated to prove free from them, on the relay walls of ``observed`` and the prediction ``mean``
    (:func:`planning_walls`). Each distinct viewpoint cell is estimated once.

    Raises:
        ValueError: as :func:`viewpoint_carved`; offsets that are not non-decreasing from 0 to ``len(cells_rc)``.
    """
    observed = check_observed(observed)
    cells = check_cells(cells_rc, observed.shape)
    offsets = np.asarray(offsets, np.int64)
    if (offsets.ndim != 1 or offsets.size < 1 or offsets[0] != 0 or offsets[-1] != len(cells)
            or np.any(np.diff(offsets) < 0)):
        raise ValueError(f"offsets must run non-decreasing from 0 to {len(cells)}, got {offsets.tolist()[:8]}...")
    walls = planning_walls(observed, mean, cfg.wall_threshold)
    distinct, group_views = np.unique(cells, axis=0, return_inverse=True)
    carved, view_offsets = viewpoint_carved(walls, observed, distinct, cfg, resolution_m)
    return _union_counts(carved, view_offsets, np.ascontiguousarray(group_views.reshape(-1).astype(np.int64)),
                         offsets, observed.size)
