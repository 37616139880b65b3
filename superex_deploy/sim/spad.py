"""SPAD LiDAR simulator (the simulator's side; the sensor model and histogram types are in
:mod:`superex_deploy.spad_types`): time-of-flight histograms with the direct and the three-bounce (NLOS) returns.

The model is the seed paper's, in 2D and confocal (laser and detector at the robot cell centre):

* Primary ray ``i`` (``SpadConfig.n_rays`` over 360 degrees) hits wall cell ``h1`` at distance ``d1`` (metres,
  to the point where the ray enters the cell).
* The outward normal ``n1`` at ``h1`` comes from Sobel gradients of the ground-truth grid. One-cell-thick walls
  (5-25 % of KTH wall cells) have no Sobel response, so there the normal is the minor principal axis of the
  wall cells in a 5x5 window, and for an isolated cell the face the primary ray entered. The normal at ``h1``
  faces the robot.
* ``n_secondary`` rays leave ``h1`` uniformly over [-90, 90] degrees about ``n1`` (midpoint sampling, so none
  is exactly grazing) until they hit a wall ``h2`` at distance ``d2``.
* Bins: ``b = floor(path / bin_path_m)`` with path ``2 d1`` (direct) and ``2 d1 + 2 d2`` (three-bounce).
* Counts: eq. (1) ``N1 = alpha E rho / pi * lambda / (h c)`` and eq. (2)
  ``N2 = E rho^3 cos(theta1) cos(theta2) s^2 alpha / (pi^3 d1 d2^2) * lambda / (h c)`` per secondary ray
  (``theta1``: incidence of the primary at ``h1``; ``theta2``: of the secondary at ``h2``; ``s``: the grid
  resolution in metres, the size of the reflecting patch).

Two discretisation choices, both at the grid's 0.1 m scale:

* **Per-cell fans.** All primaries hitting the same cell share one secondary fan (traced once per grid), from
  the point ``X1`` where the normal through the cell centre leaves the cell. Rays reaching the same 0.1 m patch
  see the same hidden scene up to a few centimetres, and this makes the scan affordable.
* **Staircase walls.** A fan started right at ``X1`` would graze the staircase of its own rasterised wall and
  return at ``d2 ~ 0.1 m`` for every oblique wall. Tracing therefore starts at ``X1 + FAN_OFFSET_CELLS * n1``
  (``d2`` is still measured from ``X1``), and Lambertian cosines are clamped at zero: a secondary ray arriving
  at the back of a thick wall's surface (``d . n2 > 0``) returns nothing. If the offset start lies in a wall,
  the return is recorded at ``d2 = FAN_OFFSET_CELLS`` cells (an early, conservative return).

Distances ``d1, d2`` are floored at half a cell so eq. (2) stays finite for a robot touching a wall.

Cost. :func:`prepare_scene` computes, once per grid, the wall normals and a 4x4-block occupancy map (cached on
the grid; 10-95 ms on the KTH eval floors). Every scan then traces the primaries and one
fan per distinct hit cell with a two-level DDA that crosses wall-free 4x4 blocks in one step and returns the
exact DDA's hits, groups the rays by hit cell and writes the histograms. A fan depends on its wall cell and
the normal it leaves along, not on the robot's pose, so each grid keeps the fans traced so far
(:class:`FanCache`): along an exploration episode a scan traces only the fans of wall cells it is the first to
see. The histograms are written sparse (:class:`SparseHistograms`: at most ``1 + n_secondary`` of the
``n_bins`` bins of a noise-free ray are non-zero), and densified only when asked for. The primaries, the new
fans and the histograms are each split over numba's threads; the split never changes a scan.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from functools import cached_property
from typing import Optional, Union

import numba
import numpy as np
from scipy import ndimage

from superex_deploy.geometry import dda_start, dda_step, group_by_cell, cell_centre, ray_angles
from superex_deploy.maps import OccupancyGrid
from superex_deploy.spad_types import SpadConfig, SpadScan, SparseHistograms

__all__ = ["SpadTruth", "SpadScene", "FanCache", "prepare_scene", "simulate_scan", "nlos_ground_truth"]
FAN_OFFSET_CELLS = 0.75
MIN_DISTANCE_CELLS = 0.5
_FLOAT32_MAX = float(np.finfo(np.float32).max)
# Rays cross wall-free blocks of BLOCK_CELLS x BLOCK_CELLS cells in one step; SpadScene.cell_kind codes:
BLOCK_SHIFT = 2
BLOCK_CELLS = 1 << BLOCK_SHIFT
CELL_FREE = 0
CELL_WALL = 1
CELL_OPEN_BLOCK = 2
# numpy's Poisson sampler refuses means above ~1e19; beyond this the normal approximation is exact to 1e-3.
_POISSON_NORMAL_ABOVE = 1e7



@dataclass(frozen=True, eq=False)
class SpadTruth:
    """Simulation-only ground truth (labels and tests; never read by the NLOS processing).

    Stored per fan (one per distinct primary-hit cell) as rows of the grid's fan cache (:class:`FanCache`; rows
    are written once and never changed, so a truth stays valid however the cache grows later); the per-fan and
    per-path arrays are gathered on first access.

    Attributes:
        h1_rc: int32 ``[n_rays, 2]`` first wall cell of each primary ray, -1 where none within range.
        d1_m: float64 ``[n_rays]`` distance to ``h1`` (metres; NaN where no hit).
        normal1: float64 ``[n_rays, 2]`` unit outward normal ``(dy, dx)`` at ``h1`` facing the robot (0 if none).
        cos1: float64 ``[n_rays]`` incidence cosine of the primary at ``h1`` (0 if none).
        ray_fan: int64 ``[n_rays]`` fan index of each primary ray, -1 where it hit nothing.
        fan_rows: int64 ``[n_fans]`` row of each fan in ``fan_store``.
        fan_store: the cache's arrays ``(d2_m, cos2, h2_rc)`` as they were when the scan was taken.
        three_bounce_scale: eq. (2) without its geometric factor (see :meth:`SpadConfig.three_bounce_scale`).
    """

    h1_rc: np.ndarray
    d1_m: np.ndarray
    normal1: np.ndarray
    cos1: np.ndarray
    ray_fan: np.ndarray
    fan_rows: np.ndarray
    fan_store: tuple[np.ndarray, np.ndarray, np.ndarray]
    three_bounce_scale: float

    @cached_property
    def fan_h2_rc(self) -> np.ndarray:
        """int32 ``[n_fans, n_secondary, 2]`` secondary hit cells (-1: no hit within range)."""
        return self.fan_store[2][self.fan_rows]

    @cached_property
    def fan_d2_m(self) -> np.ndarray:
        """float64 ``[n_fans, n_secondary]`` distance from the fan origin ``X1`` to ``h2`` (NaN: no hit)."""
        return self.fan_store[0][self.fan_rows]

    @cached_property
    def fan_cos2(self) -> np.ndarray:
        """float64 ``[n_fans, n_secondary]`` clamped incidence cosine at ``h2`` (0: back-facing)."""
        return self.fan_store[1][self.fan_rows]

    @cached_property
    def _paths(self) -> tuple[np.ndarray, np.ndarray]:
        rays = np.flatnonzero(self.ray_fan >= 0)
        hit = self.fan_h2_rc[self.ray_fan[rays], :, 0] >= 0
        ray_index, slot = np.nonzero(hit)
        return rays[ray_index], slot

    @property
    def h2_ray(self) -> np.ndarray:
        """int32 ``[M]``: the primary ray of every secondary hit, over all primary rays."""
        return self._paths[0].astype(np.int32)

    @property
    def h2_rc(self) -> np.ndarray:
        """int32 ``[M, 2]``: every secondary hit cell (aligned with :attr:`h2_ray`)."""
        rays, slot = self._paths
        return self.fan_h2_rc[self.ray_fan[rays], slot].astype(np.int32)

    @property
    def d2_m(self) -> np.ndarray:
        """float64 ``[M]``: ``d2`` of every secondary hit (metres)."""
        rays, slot = self._paths
        return self.fan_d2_m[self.ray_fan[rays], slot]

    @property
    def h2_counts(self) -> np.ndarray:
        """float64 ``[M]``: expected photons of every three-bounce path (eq. 2; 0 when back-facing)."""
        rays, slot = self._paths
        fan = self.ray_fan[rays]
        return (self.three_bounce_scale * self.cos1[rays] * self.fan_cos2[fan, slot]
                / (self.d1_m[rays] * self.fan_d2_m[fan, slot] ** 2))



@numba.njit(cache=True)
def _thin_wall_normals(occupied, weak, normals):
    """Minor principal axis of the wall cells in the 5x5 window around each ``weak`` wall cell (unit, arbitrary
    sign); left at zero where the window's wall cells are isotropic (an isolated cell or a blob)."""
    n_rows, n_cols = occupied.shape
    for r in range(n_rows):
        for c in range(n_cols):
            if not weak[r, c]:
                continue
            n = 0
            sy = 0.0
            sx = 0.0
            syy = 0.0
            sxx = 0.0
            sxy = 0.0
            for rr in range(max(0, r - 2), min(n_rows, r + 3)):
                for cc in range(max(0, c - 2), min(n_cols, c + 3)):
                    if occupied[rr, cc]:
                        dy = rr - r
                        dx = cc - c
                        n += 1
                        sy += dy
                        sx += dx
                        syy += dy * dy
                        sxx += dx * dx
                        sxy += dy * dx
            my = sy / n
            mx = sx / n
            cyy = syy / n - my * my
            cxx = sxx / n - mx * mx
            cxy = sxy / n - my * mx
            # Eigen-decomposition of [[cyy, cxy], [cxy, cxx]]; the minor axis is the wall's normal.
            half_trace = 0.5 * (cyy + cxx)
            spread = np.sqrt(0.25 * (cyy - cxx) ** 2 + cxy * cxy)
            if spread < 1e-9 or half_trace < 1e-9:
                continue
            minor = half_trace - spread
            # (A - minor I) v = 0 -> v = (cxy, minor - cyy) or (minor - cxx, cxy), whichever is larger.
            vy1, vx1 = minor - cxx, cxy
            vy2, vx2 = cxy, minor - cyy
            if vy1 * vy1 + vx1 * vx1 >= vy2 * vy2 + vx2 * vx2:
                vy, vx = vy1, vx1
            else:
                vy, vx = vy2, vx2
            norm = np.sqrt(vy * vy + vx * vx)
            normals[r, c, 0] = vy / norm
            normals[r, c, 1] = vx / norm


FAN_VARIANTS = 4
"""Fans cached per wall cell: a cell with a normal leaves along it or its reverse (variants 0, 1); a cell
without one along the face the light entered (variants 0-3: +rows, -rows, +cols, -cols)."""
MAX_CACHED_FAN_BYTES = 64 << 20
"""A grid's fan cache starts afresh when it would outgrow this (about 26,000 fans at 64 secondary rays)."""


class FanCache:
    """Secondary fans already traced in one grid, for one ``(n_secondary, range)``, reused across scans.

    A fan depends on its wall cell and the normal it leaves along, never on where the robot stands (the robot
    only picks which of a cell's :data:`FAN_VARIANTS` it sees), so a robot exploring a building traces each
    fan once instead of once per scan. Rows are written once and never changed: a scan's
    :class:`SpadTruth` keeps the arrays it was taken with, and growing or restarting the cache allocates new
    ones. Not thread-safe (one cache per grid object; worker processes have their own). ``traced``, ``reused``
    and ``restarts`` count fans traced, fans found cached, and restarts.

    Per row (fan): ``d2_m`` float64 ``[K]`` (NaN: no hit), ``cos2`` float64 ``[K]``, ``h2_rc`` int32 ``[K, 2]``
    in secondary-ray order, and the returning paths (hit, front-facing, non-vanishing gain) sorted by length:
    ``path_m`` float64 ``[K]`` (``2 d2``, metres), ``gain`` float64 ``[K]`` (``cos2 / d2^2``), ``n_paths``.
    """

    def __init__(self, n_wall_cells: int, n_secondary: int, max_bytes: int = MAX_CACHED_FAN_BYTES):
        self.n_secondary = int(n_secondary)
        # Row + 1 of each cached key, 0 for none: a zeroed array costs nothing until the keys are written.
        self.row_of_key = np.zeros(max(int(n_wall_cells), 1) * FAN_VARIANTS, np.int64)
        bytes_per_fan = self.n_secondary * 5 * 8 + 8
        self.max_fans = max(1, int(max_bytes) // bytes_per_fan)
        self.size = 0
        self.traced = 0
        self.reused = 0
        self.restarts = 0
        self._allocate(0, min(1024, self.max_fans))

    def _allocate(self, keep: int, capacity: int) -> None:
        k = self.n_secondary
        arrays = (np.empty((capacity, k)), np.empty((capacity, k)), np.empty((capacity, k, 2), np.int32),
                  np.empty((capacity, k)), np.empty((capacity, k)), np.empty(capacity, np.int64))
        if keep:
            for new, old in zip(arrays, self.arrays):
                new[:keep] = old[:keep]
        self.d2_m, self.cos2, self.h2_rc, self.path_m, self.gain, self.n_paths = arrays

    @property
    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.d2_m, self.cos2, self.h2_rc, self.path_m, self.gain, self.n_paths

    @property
    def capacity(self) -> int:
        return self.n_paths.shape[0]

    def reserve(self, n_new: int, n_if_cleared: int) -> tuple[np.ndarray, bool]:
        """Rows for ``n_new`` fans: ``(rows int64, cleared)``. When they do not fit within the cache's size it
        starts afresh (``cleared``; the rows looked up before are gone) and returns ``n_if_cleared`` rows, for
        every fan of the scan."""
        cleared = self.size > 0 and self.size + n_new > self.max_fans
        if cleared:
            self.row_of_key.fill(0)
            self.size = 0
            self.restarts += 1
            n_new = n_if_cleared
            self._allocate(0, max(min(1024, self.max_fans), n_new))
        elif self.size + n_new > self.capacity:
            self._allocate(self.size, max(2 * self.capacity, self.size + n_new))
        rows = np.arange(self.size, self.size + n_new, dtype=np.int64)
        self.size += n_new
        return rows, cleared


@dataclass(frozen=True, eq=False)
class SpadScene:
    """Per-grid precomputation shared by every scan in that grid (ground-truth geometry only).

    Attributes:
        grid: the ground-truth occupancy grid.
        normals: float64 ``[H, W, 2]`` unit normal ``(dy, dx)`` at wall cells; Sobel-based (pointing out of the
            wall, physical sign) where ``two_sided`` is False, principal-axis based (sign unknown) where True,
            zero where undefined (isolated cells: the entry face is used instead).
        two_sided: bool ``[H, W]`` wall cells whose normal sign is not physical (thin walls).
        wall_blocks: bool ``[ceil(H / 4), ceil(W / 4)]``: True where the 4x4 block of cells holds a wall.
        cell_kind: uint8 ``[H, W]``: ``CELL_WALL`` at walls, ``CELL_OPEN_BLOCK`` at free cells of wall-free
            blocks, ``CELL_FREE`` at the other free cells. Rays cross wall-free blocks four cells at a time (see
            :func:`_trace_first_hit_blocks`); one byte per cell tells a cell step both outcomes at once.
        wall_index: int32 ``[H, W]``: running index of each wall cell (row-major), -1 at free cells; keys the
            fan caches.
        n_wall_cells: number of wall cells.
        fan_caches: ``(n_secondary, range in cells) -> FanCache``, filled by the scans.
    """

    grid: OccupancyGrid
    normals: np.ndarray
    two_sided: np.ndarray
    wall_blocks: np.ndarray
    cell_kind: np.ndarray
    wall_index: np.ndarray
    n_wall_cells: int
    fan_caches: dict = field(default_factory=dict, repr=False)

    def fan_cache(self, n_secondary: int, max_t: float) -> FanCache:
        """The fan cache for ``n_secondary`` rays of range ``max_t`` cells (created empty on first use)."""
        key = (int(n_secondary), float(max_t))
        cache = self.fan_caches.get(key)
        if cache is None:
            cache = self.fan_caches[key] = FanCache(self.n_wall_cells, n_secondary, MAX_CACHED_FAN_BYTES)
        return cache

    def clear_fan_caches(self) -> None:
        """Forget every cached fan: the next scan traces all of its fans (a cold scan)."""
        self.fan_caches.clear()


_SCENES: "weakref.WeakKeyDictionary[OccupancyGrid, SpadScene]" = weakref.WeakKeyDictionary()


def _wall_blocks(occupied: np.ndarray) -> np.ndarray:
    """bool ``[ceil(H / B), ceil(W / B)]`` (``B = BLOCK_CELLS``): which blocks of ``B x B`` cells hold a wall."""
    n_rows = -(-occupied.shape[0] // BLOCK_CELLS)
    n_cols = -(-occupied.shape[1] // BLOCK_CELLS)
    padded = np.zeros((n_rows * BLOCK_CELLS, n_cols * BLOCK_CELLS), bool)
    padded[:occupied.shape[0], :occupied.shape[1]] = occupied
    return padded.reshape(n_rows, BLOCK_CELLS, n_cols, BLOCK_CELLS).any(axis=(1, 3))


def _cell_kind(occupied: np.ndarray, wall_blocks: np.ndarray) -> np.ndarray:
    """uint8 ``[H, W]``, see :attr:`SpadScene.cell_kind`."""
    in_open_block = ~np.repeat(np.repeat(wall_blocks, BLOCK_CELLS, 0), BLOCK_CELLS, 1)
    kind = np.where(in_open_block[:occupied.shape[0], :occupied.shape[1]], CELL_OPEN_BLOCK, CELL_FREE)
    kind[occupied] = CELL_WALL
    return kind.astype(np.uint8)


def prepare_scene(grid: OccupancyGrid) -> SpadScene:
    """Wall normals and wall blocks of a grid, computed once and cached for the grid's lifetime (a weak
    reference to the grid keys the cache: scans of one grid share them and its fan caches, and they go when the
    grid goes)."""
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    scene = _SCENES.get(grid)
    if scene is None:
        walls = grid.occupied.astype(np.float64)
        grad_y = ndimage.sobel(walls, axis=0, mode="nearest")
        grad_x = ndimage.sobel(walls, axis=1, mode="nearest")
        magnitude = np.hypot(grad_y, grad_x)
        strong = grid.occupied & (magnitude >= 1.0)
        normals = np.zeros(grid.shape + (2,), np.float64)
        # Occupancy rises into the wall, so the outward (free-side) normal is minus the gradient.
        normals[strong, 0] = -grad_y[strong] / magnitude[strong]
        normals[strong, 1] = -grad_x[strong] / magnitude[strong]
        weak = grid.occupied & ~strong
        _thin_wall_normals(grid.occupied, weak, normals)
        wall_blocks = _wall_blocks(grid.occupied)
        wall_index = np.where(grid.occupied, np.cumsum(grid.occupied.ravel()).reshape(grid.shape) - 1, -1)
        scene = SpadScene(grid=grid, normals=normals, two_sided=weak, wall_blocks=wall_blocks,
                          cell_kind=_cell_kind(grid.occupied, wall_blocks), wall_index=wall_index.astype(np.int32),
                          n_wall_cells=int(np.count_nonzero(grid.occupied)))
        _SCENES[grid] = scene
    return scene


@numba.njit(cache=True, inline="always")
def _trace_first_hit_blocks(cell_kind, wall_blocks, y0, x0, dy, dx, max_t):
    """``geometry._trace_first_hit`` on two levels: exact DDA steps through the cells of blocks that hold a
    wall, DDA steps of whole ``BLOCK_CELLS x BLOCK_CELLS`` blocks through wall-free blocks. The hit cell, its
    entry distance and its entry axis are the exact DDA's up to float rounding (each level's boundary parameters
    are carried over from the other's, so they accumulate a few ulps differently).

    Returns (row, col, t_entry, entry_axis) like ``_trace_first_hit``; on a miss the row and column are -1 and
    ``t`` is only approximately where the ray stopped.
    """
    n_rows, n_cols = cell_kind.shape
    r = int(np.floor(y0))
    c = int(np.floor(x0))
    if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
        return -1, -1, 0.0, -1
    kind = cell_kind[r, c]
    if kind == CELL_WALL:
        return r, c, 0.0, -1
    mask = BLOCK_CELLS - 1
    r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(y0, x0, dy, dx)
    t = 0.0
    while True:
        if kind == CELL_FREE:
            # Cell level, until the ray hits a wall or steps into a wall-free block.
            while True:
                r, c, t_next_r, t_next_c, t, axis = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                             t_delta_c)
                if t > max_t:
                    return -1, -1, max_t, -1
                if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                    return -1, -1, t, -1
                kind = cell_kind[r, c]
                if kind == CELL_WALL:
                    return r, c, t, axis
                if kind == CELL_OPEN_BLOCK:
                    break
        # Block level, until the ray steps into a block with a wall. A block's far boundary lies as many cell
        # widths beyond the current cell's next boundary as there are cells left in the block.
        if step_r > 0:
            bt_next_r = t_next_r + (mask - (r & mask)) * t_delta_r
        elif step_r < 0:
            bt_next_r = t_next_r + (r & mask) * t_delta_r
        else:
            bt_next_r = np.inf
        if step_c > 0:
            bt_next_c = t_next_c + (mask - (c & mask)) * t_delta_c
        elif step_c < 0:
            bt_next_c = t_next_c + (c & mask) * t_delta_c
        else:
            bt_next_c = np.inf
        br = r >> BLOCK_SHIFT
        bc = c >> BLOCK_SHIFT
        while True:
            if bt_next_c <= bt_next_r:
                t = bt_next_c
                bc += step_c
                bt_next_c += BLOCK_CELLS * t_delta_c
                axis = 1
            else:
                t = bt_next_r
                br += step_r
                bt_next_r += BLOCK_CELLS * t_delta_r
                axis = 0
            if t > max_t:
                return -1, -1, max_t, -1
            if br < 0 or br >= wall_blocks.shape[0] or bc < 0 or bc >= wall_blocks.shape[1]:
                return -1, -1, t, -1
            if wall_blocks[br, bc]:
                break
        # The cell through which the ray entered the walled block (the other coordinate is clamped into the
        # block: the entry point lies on the block's edge, where rounding may put it one cell outside), and its
        # next boundaries: one cell width past the entry face, and the block's far boundary less the cells left.
        if axis == 1:
            c = bc * BLOCK_CELLS + (0 if step_c > 0 else mask)
            r = min(max(int(np.floor(y0 + t * dy)), br * BLOCK_CELLS), br * BLOCK_CELLS + mask)
            t_next_c = t + t_delta_c
            if step_r > 0:
                t_next_r = bt_next_r - (mask - (r & mask)) * t_delta_r
            elif step_r < 0:
                t_next_r = bt_next_r - (r & mask) * t_delta_r
        else:
            r = br * BLOCK_CELLS + (0 if step_r > 0 else mask)
            c = min(max(int(np.floor(x0 + t * dx)), bc * BLOCK_CELLS), bc * BLOCK_CELLS + mask)
            t_next_r = t + t_delta_r
            if step_c > 0:
                t_next_c = bt_next_c - (mask - (c & mask)) * t_delta_c
            elif step_c < 0:
                t_next_c = bt_next_c - (c & mask) * t_delta_c
        if r >= n_rows or c >= n_cols:
            return -1, -1, t, -1
        kind = cell_kind[r, c]
        if kind == CELL_WALL:
            return r, c, t, axis


@numba.njit(cache=True, parallel=True)
def _cast_primaries(cell_kind, wall_blocks, y0, x0, angles, max_t, hit_rc, distance, entry_axis, direction, n_parts):
    """``geometry._cast_rays`` with the two-level tracer (same outputs, up to float rounding); ``direction[i]``
    receives the unit vector ``(dy, dx)`` of ray ``i``. The rays are cut into ``n_parts`` runs of neighbouring
    angles traced in parallel (each ray is independent: the split does not change the result)."""
    n_rays = angles.shape[0]
    chunk = (n_rays + n_parts - 1) // n_parts
    for part in numba.prange(n_parts):
        for i in range(part * chunk, min(n_rays, (part + 1) * chunk)):
            dy = np.sin(angles[i])
            dx = np.cos(angles[i])
            direction[i, 0] = dy
            direction[i, 1] = dx
            r, c, t, axis = _trace_first_hit_blocks(cell_kind, wall_blocks, y0, x0, dy, dx, max_t)
            hit_rc[i, 0] = r
            hit_rc[i, 1] = c
            distance[i] = t
            entry_axis[i] = axis


@numba.njit(cache=True)
def _facing_normal(normals, two_sided, r, c, entry_axis, dy, dx, towards_y, towards_x):
    """Unit normal at wall cell (r, c) for light arriving along (dy, dx). Thin-wall and undefined normals get
    the sign pointing towards (towards_y, towards_x) (the side the light comes from); Sobel normals keep their
    physical sign. Returns (ny, nx, physical)."""
    ny = normals[r, c, 0]
    nx = normals[r, c, 1]
    if ny == 0.0 and nx == 0.0:
        if entry_axis == 0:
            ny = -1.0 if dy > 0.0 else 1.0
        elif entry_axis == 1:
            nx = -1.0 if dx > 0.0 else 1.0
        else:
            ny = -dy
            nx = -dx
        return ny, nx, False
    if two_sided[r, c]:
        if ny * towards_y + nx * towards_x < 0.0:
            ny = -ny
            nx = -nx
        return ny, nx, False
    return ny, nx, True


@numba.njit(cache=True)
def _fan_rows(normals, two_sided, wall_index, row_of_key, fan_cells, fan_entry_axis, robot_y, robot_x,
              fan_normal, fan_key, fan_row):
    """Per fan: ``fan_normal`` the unit normal at its cell facing the robot, ``fan_key`` its cache key
    (``wall_index * FAN_VARIANTS + variant``; -1 for a normal that is no face and no stored normal, which only a
    ray starting inside a wall produces) and ``fan_row`` its cached row (-1: not cached; ``row_of_key`` holds
    row + 1, 0 for none). Returns the number of fans not cached."""
    missing = 0
    for u in range(fan_cells.shape[0]):
        r1 = fan_cells[u, 0]
        c1 = fan_cells[u, 1]
        cy = r1 + 0.5
        cx = c1 + 0.5
        ny, nx, _ = _facing_normal(normals, two_sided, r1, c1, fan_entry_axis[u], cy - robot_y, cx - robot_x,
                                   robot_y - cy, robot_x - cx)
        if ny * (robot_y - cy) + nx * (robot_x - cx) < 0.0:
            ny = -ny
            nx = -nx
        fan_normal[u, 0] = ny
        fan_normal[u, 1] = nx
        sy = normals[r1, c1, 0]
        sx = normals[r1, c1, 1]
        if sy != 0.0 or sx != 0.0:
            variant = 0 if (ny == sy and nx == sx) else 1
        elif fan_entry_axis[u] < 0:
            variant = -1
        elif nx == 0.0:
            variant = 0 if ny > 0.0 else 1
        else:
            variant = 2 if nx > 0.0 else 3
        key = -1 if variant < 0 else np.int64(wall_index[r1, c1]) * FAN_VARIANTS + variant
        fan_key[u] = key
        fan_row[u] = -1 if key < 0 else row_of_key[key] - 1
        if fan_row[u] < 0:
            missing += 1
    return missing


@numba.njit(cache=True)
def _trace_fan(cell_kind, wall_blocks, normals, two_sided, r1, c1, ny, nx, cos_phi, sin_phi, max_t,
               resolution_m, min_distance_m, d2_m, cos2, h2_rc, path_m, gain, scratch_path, scratch_gain,
               bucket_start):
    """Trace one fan leaving wall cell ``(r1, c1)`` along the unit normal ``(ny, nx)``; fills the row views
    ``d2_m``, ``cos2``, ``h2_rc`` (secondary-ray order) and ``path_m``, ``gain`` (returning paths, shortest
    first; see :class:`FanCache`), using the scratch arrays for the sort (see :func:`_sort_paths`).
    Returns the number of returning paths."""
    n_secondary = cos_phi.shape[0]
    cy = r1 + 0.5
    cx = c1 + 0.5
    # X1: where the normal through the cell centre leaves the cell.
    half = 0.5 / max(abs(ny), abs(nx))
    x1_y = cy + half * ny
    x1_x = cx + half * nx
    oy = x1_y + FAN_OFFSET_CELLS * ny
    ox = x1_x + FAN_OFFSET_CELLS * nx
    inside = 0.0 <= oy < cell_kind.shape[0] and 0.0 <= ox < cell_kind.shape[1]
    for k in range(n_secondary):
        d2_m[k] = np.nan
        cos2[k] = 0.0
        h2_rc[k, 0] = -1
        h2_rc[k, 1] = -1
        if not inside:
            continue
        dy = ny * cos_phi[k] - nx * sin_phi[k]
        dx = ny * sin_phi[k] + nx * cos_phi[k]
        r2, c2, t, axis = _trace_first_hit_blocks(cell_kind, wall_blocks, oy, ox, dy, dx, max_t)
        if r2 < 0:
            continue
        hy = oy + t * dy
        hx = ox + t * dx
        d2_m[k] = max(np.sqrt((hy - x1_y) ** 2 + (hx - x1_x) ** 2) * resolution_m, min_distance_m)
        h2_rc[k, 0] = r2
        h2_rc[k, 1] = c2
        if t == 0.0:
            # The offset start lies inside a wall: an early return straight back, full cosine.
            cos2[k] = 1.0
            continue
        n2y, n2x, _ = _facing_normal(normals, two_sided, r2, c2, axis, dy, dx, -dy, -dx)
        cos2[k] = max(0.0, -(dy * n2y + dx * n2x))
    n = 0
    for k in range(n_secondary):
        if d2_m[k] == d2_m[k] and cos2[k] > 0.0:
            g = cos2[k] / (d2_m[k] * d2_m[k])
            # A vanishing gain is skipped: times an overflowing pulse scale it would make inf * 0 = NaN.
            if g > 0.0:
                path_m[n] = 2.0 * d2_m[k]
                gain[n] = g
                n += 1
    _sort_paths(path_m, gain, n, scratch_path, scratch_gain, bucket_start)
    return n


@numba.njit(cache=True)
def _sort_paths(path_m, gain, n, scratch_path, scratch_gain, bucket_start):
    """Sort ``path_m[:n]`` ascending, carrying ``gain[:n]`` along; stable (equal lengths keep their order).

    A fan's path lengths jitter along its angle (the staircase of a rasterised wall), so about every other one
    is shorter than the one before and insertion sort alone moves ``n^2 / 4`` entries, mispredicting a branch at
    most of them. A counting pass first deals the paths into ``n`` equal buckets spanning their lengths (stable);
    the insertion sort that follows then only orders paths within a bucket: 1.8x faster at ``n = 64``. Scratch
    arrays: ``n`` floats each and ``n + 1`` ints.
    """
    if n < 2:
        return
    lo = path_m[0]
    hi = lo
    for k in range(1, n):
        lo = min(lo, path_m[k])
        hi = max(hi, path_m[k])
    if hi > lo:
        scale = (n - 1) / (hi - lo)
        for b in range(n + 1):
            bucket_start[b] = 0
        for k in range(n):
            bucket_start[int((path_m[k] - lo) * scale) + 1] += 1
        for b in range(1, n + 1):
            bucket_start[b] += bucket_start[b - 1]
        for k in range(n):
            b = int((path_m[k] - lo) * scale)
            j = bucket_start[b]
            bucket_start[b] = j + 1
            scratch_path[j] = path_m[k]
            scratch_gain[j] = gain[k]
        for k in range(n):
            path_m[k] = scratch_path[k]
            gain[k] = scratch_gain[k]
    for j in range(1, n):
        p = path_m[j]
        g = gain[j]
        i = j - 1
        while i >= 0 and path_m[i] > p:
            path_m[i + 1] = path_m[i]
            gain[i + 1] = gain[i]
            i -= 1
        path_m[i + 1] = p
        gain[i + 1] = g


@numba.njit(cache=True, parallel=True)
def _trace_fans(cell_kind, wall_blocks, normals, two_sided, fan_cells, fan_normal, todo, rows, n_secondary,
                max_t, resolution_m, min_distance_m, d2_m, cos2, h2_rc, path_m, gain, n_paths, n_parts):
    """Trace the fans ``todo`` (indices into ``fan_cells`` / ``fan_normal``) into cache rows ``rows``; the
    fans are dealt round-robin into ``n_parts`` parts traced in parallel (each fan is independent, so the
    result does not depend on the split)."""
    phi = -0.5 * np.pi + (np.arange(n_secondary) + 0.5) * (np.pi / n_secondary)
    cos_phi = np.cos(phi)
    sin_phi = np.sin(phi)
    for part in numba.prange(n_parts):
        scratch = np.empty((2, n_secondary))
        bucket_start = np.empty(n_secondary + 1, np.int64)
        for j in range(part, todo.shape[0], n_parts):
            u = todo[j]
            row = rows[j]
            n_paths[row] = _trace_fan(cell_kind, wall_blocks, normals, two_sided, fan_cells[u, 0],
                                      fan_cells[u, 1], fan_normal[u, 0], fan_normal[u, 1], cos_phi, sin_phi,
                                      max_t, resolution_m, min_distance_m, d2_m[row], cos2[row], h2_rc[row],
                                      path_m[row], gain[row], scratch[0], scratch[1], bucket_start)


@numba.njit(cache=True, parallel=True)
def _fill_sparse(direction, hit_fan, d1_cells, fan_normal, fan_row, path_m, gain, n_paths, resolution_m,
                 bin_path_m, n_bins, direct_counts, three_bounce_scale, min_distance_m, d1_out, cos1_out,
                 normal1_out, n_parts):
    """Eq. (1) and eq. (2) as sparse histograms: returns ``(row_start, bins, counts)`` (see
    :class:`SparseHistograms`).

    Counts are summed per bin in float64 and saturate at float32's largest finite value. A ray's returning
    paths come sorted by length from the fan cache, so its bins come out in order and equal bins are adjacent;
    they are merged without branching on the data (such a branch mispredicts about every other path). Per
    ray it also writes ``d1_out[i]`` (metres, at least ``min_distance_m``; NaN for no hit), the incidence cosine
    ``cos1_out[i]`` and ``normal1_out[i]`` (0 for no hit).

    The rays are cut into ``n_parts`` runs of consecutive rays filled in parallel, each into its own stretch of
    the output (room for all its rays' paths; merged bins leave it part-filled), and the stretches are then
    closed up. Rays are independent: the split does not change the result."""
    n_rays = direction.shape[0]
    chunk = (n_rays + n_parts - 1) // n_parts
    part_room = np.zeros(n_parts + 1, np.int64)
    for i in range(n_rays):
        if hit_fan[i] >= 0:
            part_room[i // chunk + 1] += 1 + n_paths[fan_row[hit_fan[i]]]
    for part in range(n_parts):
        part_room[part + 1] += part_room[part]
    bins = np.empty(part_room[n_parts], np.int32)
    counts = np.empty(part_room[n_parts], np.float32)
    row_start = np.empty(n_rays + 1, np.int64)
    part_end = np.empty(n_parts, np.int64)
    largest = np.finfo(np.float32).max
    bins_per_m = 1.0 / bin_path_m
    for part in numba.prange(n_parts):
        n = part_room[part]
        for i in range(part * chunk, min(n_rays, (part + 1) * chunk)):
            row_start[i] = n
            u = hit_fan[i]
            cos1_out[i] = 0.0
            if u < 0:
                d1_out[i] = np.nan
                normal1_out[i, 0] = 0.0
                normal1_out[i, 1] = 0.0
                continue
            d1 = max(d1_cells[i] * resolution_m, min_distance_m)
            d1_out[i] = d1
            normal1_out[i, 0] = fan_normal[u, 0]
            normal1_out[i, 1] = fan_normal[u, 1]
            cos1 = max(0.0, -(direction[i, 0] * fan_normal[u, 0] + direction[i, 1] * fan_normal[u, 1]))
            cos1_out[i] = cos1
            b1 = int(2.0 * d1 / bin_path_m)
            if b1 >= n_bins:
                continue  # every late bin lies further still
            # The open entry (bin, total) stays in registers; it is stored at slot n on every path and n moves
            # on when the bin changes, so equal bins merge without a branch on the data.
            current = b1
            total = direct_counts
            if cos1 > 0.0:
                scale = three_bounce_scale * cos1 / d1
                path1_bins = 2.0 * d1 * bins_per_m
                row = fan_row[u]
                for j in range(n_paths[row]):
                    b = max(int(path1_bins + path_m[row, j] * bins_per_m), b1)
                    if b >= n_bins:
                        break  # the paths are sorted: the rest lie beyond the last bin too
                    bins[n] = current
                    counts[n] = min(total, largest)
                    new = b != current
                    n += new
                    total = (0.0 if new else total) + scale * gain[row, j]
                    current = b
            bins[n] = current
            counts[n] = min(total, largest)
            n += 1
        part_end[part] = n
    # Close up: each part's entries move down to follow the previous part's (copied out first: the two
    # stretches may overlap).
    n = part_end[0]
    for part in range(1, n_parts):
        shift = part_room[part] - n
        size = part_end[part] - part_room[part]
        if shift:
            bins[n:n + size] = bins[part_room[part]:part_end[part]].copy()
            counts[n:n + size] = counts[part_room[part]:part_end[part]].copy()
            for i in range(part * chunk, min(n_rays, (part + 1) * chunk)):
                row_start[i] -= shift
        n += size
    row_start[n_rays] = n
    return row_start, bins[:n], counts[:n]


def _thread_parts() -> int:
    """How many parts the parallel kernels split a scan's work into: numba's thread count (the results do not
    depend on it)."""
    return numba.get_num_threads()


def _check_rng(cfg: SpadConfig, rng) -> Optional[np.random.Generator]:
    if not cfg.noise.enabled:
        return None
    if rng is None:
        raise ValueError("noise is enabled: pass rng=numpy.random.default_rng(seed) so scans are reproducible")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def _add_noise(histograms: np.ndarray, cfg: SpadConfig, rng: np.random.Generator) -> np.ndarray:
    jitter_bins = cfg.noise.jitter_s / cfg.bin_width_s
    if jitter_bins > 0.0:
        histograms = ndimage.gaussian_filter1d(histograms, jitter_bins, axis=1, mode="constant", truncate=4.0)
    mean = np.maximum(histograms, 0.0) + cfg.noise.background_per_bin
    small = mean <= _POISSON_NORMAL_ABOVE
    noisy = np.empty_like(mean)
    noisy[small] = rng.poisson(mean[small])
    large = mean[~small]
    noisy[~small] = np.maximum(np.rint(rng.normal(large, np.sqrt(large))), 0.0)
    return noisy


def simulate_scan(grid: OccupancyGrid, pose_rc, cfg: SpadConfig = SpadConfig(),
                  rng: Optional[np.random.Generator] = None) -> SpadScan:
    """Simulate one SPAD scan from the centre of cell ``pose_rc``.

    Secondary fans are reused from the grid's :class:`FanCache` where an earlier scan traced them (the result is
    the same either way); new ones are traced on numba's threads.

    Args:
        grid: ground-truth occupancy grid.
        pose_rc: robot cell ``(row, col)``: inside the grid, not a wall.
        cfg: sensor configuration.
        rng: random generator, required when ``cfg.noise.enabled`` (ignored otherwise).

    Returns:
        The :class:`SpadScan`: sparse counts without noise, dense with it; counts are float32 and clamped to
        float32's finite range.

    Raises:
        ValueError: bad grid, pose outside the map or in a wall, noise without a generator.
    """
    if not isinstance(cfg, SpadConfig):
        raise ValueError(f"cfg must be a SpadConfig, got {type(cfg).__name__}")
    scene = prepare_scene(grid)
    pose_rc = grid.check_pose(pose_rc)
    rng = _check_rng(cfg, rng)
    origin = cell_centre(pose_rc)
    resolution = grid.resolution_m
    max_t = cfg.range_m / resolution
    angles = ray_angles(cfg.n_rays)
    hit_rc = np.empty((cfg.n_rays, 2), np.int32)
    distance = np.empty(cfg.n_rays)
    entry_axis = np.empty(cfg.n_rays, np.int8)
    direction = np.empty((cfg.n_rays, 2))
    n_parts = _thread_parts()
    _cast_primaries(scene.cell_kind, scene.wall_blocks, origin[0], origin[1], angles, max_t, hit_rc, distance,
                    entry_axis, direction, n_parts)
    hit_fan, fan_cells, first_ray = group_by_cell(hit_rc, grid.shape[1])
    fan_entry_axis = entry_axis[first_ray]  # the lowest-index ray that hit the cell

    n_fans = fan_cells.shape[0]
    cache = scene.fan_cache(cfg.n_secondary, max_t)
    fan_normal = np.empty((n_fans, 2))
    fan_key = np.empty(n_fans, np.int64)
    fan_row = np.empty(n_fans, np.int64)
    n_missing = _fan_rows(scene.normals, scene.two_sided, scene.wall_index, cache.row_of_key, fan_cells,
                          fan_entry_axis, origin[0], origin[1], fan_normal, fan_key, fan_row)
    min_distance_m = MIN_DISTANCE_CELLS * resolution
    if n_missing:
        rows, cleared = cache.reserve(n_missing, n_fans)
        if cleared:  # the cache started afresh: every fan of this scan is traced
            fan_row[:] = -1
        todo = np.flatnonzero(fan_row < 0)
        fan_row[todo] = rows
        keyed = fan_key[todo] >= 0
        cache.row_of_key[fan_key[todo][keyed]] = rows[keyed] + 1
        _trace_fans(scene.cell_kind, scene.wall_blocks, scene.normals, scene.two_sided, fan_cells, fan_normal,
                    todo, rows, cfg.n_secondary, max_t, resolution, min_distance_m, cache.d2_m, cache.cos2,
                    cache.h2_rc, cache.path_m, cache.gain, cache.n_paths, n_parts)
        cache.traced += len(todo)
    cache.reused += n_fans - n_missing

    d1_m = np.empty(cfg.n_rays)
    cos1 = np.empty(cfg.n_rays)
    normal1 = np.empty((cfg.n_rays, 2))
    three_bounce_scale = cfg.three_bounce_scale(resolution)
    row_start, bins, counts = _fill_sparse(direction, hit_fan, distance, fan_normal, fan_row, cache.path_m,
                                           cache.gain, cache.n_paths, resolution, cfg.bin_path_m, cfg.n_bins,
                                           cfg.direct_counts, three_bounce_scale, min_distance_m, d1_m, cos1,
                                           normal1, n_parts)
    stored: Union[SparseHistograms, np.ndarray] = SparseHistograms(row_start, bins, counts, cfg.n_bins)
    if rng is not None:
        noisy = np.minimum(_add_noise(stored.to_dense().astype(np.float64), cfg, rng), _FLOAT32_MAX)
        stored = noisy.astype(np.float32)

    truth = SpadTruth(h1_rc=hit_rc, d1_m=d1_m, normal1=normal1, cos1=cos1, ray_fan=hit_fan, fan_rows=fan_row,
                      fan_store=(cache.d2_m, cache.cos2, cache.h2_rc), three_bounce_scale=three_bounce_scale)
    return SpadScan(angles=angles, origin_yx=origin, pose_rc=pose_rc, bin_path_m=cfg.bin_path_m,
                    resolution_m=resolution, grid_shape=grid.shape, config=cfg, truth=truth, stored=stored)


def nlos_ground_truth(scan: SpadScan) -> np.ndarray:
    """Label image aligned with the BP map: bool ``[H, W]``, True at every cell a three-bounce path with
    non-zero photons reflected from (the ``h2`` cells). Reads the simulator's ground truth.

    Raises:
        ValueError: a scan without ground truth (a measured one).
    """
    if not isinstance(scan, SpadScan):
        raise ValueError(f"scan must be a SpadScan, got {type(scan).__name__}")
    if scan.truth is None:
        raise ValueError("nlos_ground_truth needs a simulated scan: this scan carries no ground truth")
    truth = np.zeros(scan.grid_shape, bool)
    cells = scan.truth.h2_rc[scan.truth.h2_counts > 0]
    truth[cells[:, 0], cells[:, 1]] = True
    return truth
