"""Secondary fans of the SPAD simulator: the per-grid cache of the fans already traced (:class:`FanCache`), the
look-up of a scan's fans in it, and the tracing of the missing ones (each fan's returning paths sorted by length).

A fan leaves the point ``X1`` of its wall cell along the cell's normal facing the robot; it is traced from
``X1 + FAN_OFFSET_CELLS * n1`` (see "staircase walls" in :mod:`superex_deploy.sim.spad`).
"""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.sim.spad.tracer import facing_normal, trace_first_hit_blocks

__all__ = ["FAN_OFFSET_CELLS", "FAN_VARIANTS", "MAX_CACHED_FAN_BYTES", "FanCache"]

FAN_OFFSET_CELLS = 0.75
"""Fans are traced from this many cells beyond ``X1`` along the normal (``d2`` is still measured from ``X1``),
clear of the staircase of their own rasterised wall."""
FAN_VARIANTS = 4
"""Fans cached per wall cell: a cell with a normal leaves along it or its reverse (variants 0, 1); a cell
without one along the face the light entered (variants 0-3: +rows, -rows, +cols, -cols)."""
MAX_CACHED_FAN_BYTES = 64 << 20
"""A grid's fan cache starts afresh when it would outgrow this (about 6,500 fans at the default 256 secondary rays,
26,000 at 64)."""


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


@numba.njit(cache=True)
def fan_cache_rows(normals, two_sided, wall_index, row_of_key, fan_cells, fan_entry_axis, robot_y, robot_x,
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
        ny, nx, _ = facing_normal(normals, two_sided, r1, c1, fan_entry_axis[u], cy - robot_y, cx - robot_x,
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
        r2, c2, t, axis = trace_first_hit_blocks(cell_kind, wall_blocks, oy, ox, dy, dx, max_t)
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
        n2y, n2x, _ = facing_normal(normals, two_sided, r2, c2, axis, dy, dx, -dy, -dx)
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
    the insertion sort that follows then only orders paths within a bucket, which is faster than one insertion
    sort of them all (docs/benchmarks/spad.md). Scratch arrays: ``n`` floats each and ``n + 1`` ints.
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
def trace_fans(cell_kind, wall_blocks, normals, two_sided, fan_cells, fan_normal, todo, rows, n_secondary,
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
