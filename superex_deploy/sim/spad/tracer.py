"""First-hit ray tracing for the SPAD simulator: a two-level DDA that crosses wall-free blocks of cells in one step,
the primary rays cast from the robot, and the wall normal a ray sees.

The cell codes of :attr:`SpadScene.cell_kind <superex_deploy.sim.spad.scene.SpadScene>` and the block size are
defined here, by the tracer that reads them; :mod:`superex_deploy.sim.spad.scene` builds the maps in that encoding.
"""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.geometry import dda_start, dda_step

__all__ = ["BLOCK_SHIFT", "BLOCK_CELLS", "CELL_FREE", "CELL_WALL", "CELL_OPEN_BLOCK"]

# Rays cross wall-free blocks of BLOCK_CELLS x BLOCK_CELLS cells in one step; SpadScene.cell_kind codes:
BLOCK_SHIFT = 2
BLOCK_CELLS = 1 << BLOCK_SHIFT
CELL_FREE = 0
CELL_WALL = 1
CELL_OPEN_BLOCK = 2


@numba.njit(cache=True, inline="always")
def trace_first_hit_blocks(cell_kind, wall_blocks, y0, x0, dy, dx, max_t):
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
def cast_primaries(cell_kind, wall_blocks, y0, x0, angles, max_t, hit_rc, distance, entry_axis, direction, n_parts):
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
            r, c, t, axis = trace_first_hit_blocks(cell_kind, wall_blocks, y0, x0, dy, dx, max_t)
            hit_rc[i, 0] = r
            hit_rc[i, 1] = c
            distance[i] = t
            entry_axis[i] = axis


@numba.njit(cache=True)
def facing_normal(normals, two_sided, r, c, entry_axis, dy, dx, towards_y, towards_x):
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
