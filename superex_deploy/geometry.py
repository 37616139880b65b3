"""Grid geometry shared by the LiDAR simulators and the mapper: exact 2D ray casting (Amanatides-Woo DDA).

Conventions used throughout SuperEx
-----------------------------------
* Grids are ``[row, col]`` arrays, row 0 at the top of the image.
* Continuous positions are ``(y, x)`` in **cell units**: cell ``(r, c)`` covers ``y in [r, r+1)``,
  ``x in [c, c+1)``; its centre is ``(r + 0.5, c + 0.5)``. Multiply by ``OccupancyGrid.resolution_m`` to
  get metres.
* An angle ``theta`` (radians) is the direction ``(dy, dx) = (sin theta, cos theta)``: ``0`` points along
  ``+col`` (east on the image), ``pi/2`` along ``+row`` (down on the image).
* Ray distances returned here are in cells along the ray.

The kernels are private ``_name`` functions compiled with ``numba.njit(cache=True)``; the public wrappers
check dtypes, shapes and bounds and raise ``ValueError``. Two kernels are shared with other modules' kernels (the
SPAD simulator, the NLOS processing, the planners' visibility) and so are public, unchecked, callable only from
compiled code or with already-checked arguments: :func:`dda_start`, :func:`dda_step`, :func:`group_by_cell`,
:func:`minor_axis_2x2` and :func:`window_covariance`. Slow references live
in ``tests/naive.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["RayHits", "ray_angles", "cast_rays", "mark_rays", "mark_ranges", "line_of_sight", "cell_centre",
           "dda_start", "dda_step", "group_by_cell", "minor_axis_2x2", "window_covariance",
           "check_measured_rays",
           "RETURN_TOLERANCE_CELLS"]

RETURN_TOLERANCE_CELLS = 1e-6
"""A measured return marks the cell that holds the point this far (cells) beyond the measured range: a return on a
cell boundary is the face of the cell behind it (the wall), and a range rounded to float32 (``sensor_msgs/LaserScan``)
just short of that face still marks the wall (see :func:`mark_ranges`)."""


@dataclass(frozen=True)
class RayHits:
    """First hits of a fan of rays.

    Attributes:
        hit_rc: int32 ``[N, 2]`` (row, col) of the first occupied cell along each ray, ``-1`` where the ray
            reached its range or left the grid without hitting anything.
        distance_cells: float64 ``[N]`` distance along the ray (cells) to the point where it enters the hit
            cell; for rays without a hit, the distance travelled before stopping (range or grid border).
        entry_axis: int8 ``[N]``: ``0`` if the hit cell was entered through a row boundary (its face normal is
            along the rows), ``1`` through a column boundary, ``-1`` for no hit or a ray starting inside an
            occupied cell.
    """

    hit_rc: np.ndarray
    distance_cells: np.ndarray
    entry_axis: np.ndarray

    @property
    def hit_mask(self) -> np.ndarray:
        """bool ``[N]``: rays that hit an occupied cell."""
        return self.hit_rc[:, 0] >= 0


def ray_angles(n_rays: int, offset_rad: float = 0.0) -> np.ndarray:
    """Evenly spaced ray angles over a full turn.

    Args:
        n_rays: number of rays (> 0).
        offset_rad: angle of the first ray.

    Returns:
        float64 ``[n_rays]`` angles ``offset + 2*pi*k/n_rays`` (radians).
    """
    if int(n_rays) <= 0:
        raise ValueError(f"n_rays must be positive, got {n_rays}")
    return offset_rad + 2.0 * np.pi * np.arange(int(n_rays), dtype=np.float64) / int(n_rays)


def cell_centre(rc) -> tuple[float, float]:
    """Continuous ``(y, x)`` position (cells) of the centre of cell ``rc = (row, col)``."""
    return float(rc[0]) + 0.5, float(rc[1]) + 0.5


@numba.njit(cache=True, inline="always")
def dda_start(y0, x0, dy, dx):
    """Amanatides-Woo set-up for a ray from (y0, x0) along (dy, dx): per axis the step (-1, 0, 1), the ray
    parameter of the first cell boundary and the parameter between boundaries."""
    r = int(np.floor(y0))
    c = int(np.floor(x0))
    if dy > 0.0:
        step_r, t_next_r, t_delta_r = 1, (r + 1.0 - y0) / dy, 1.0 / dy
    elif dy < 0.0:
        step_r, t_next_r, t_delta_r = -1, (y0 - r) / (-dy), -1.0 / dy
    else:
        step_r, t_next_r, t_delta_r = 0, np.inf, np.inf
    if dx > 0.0:
        step_c, t_next_c, t_delta_c = 1, (c + 1.0 - x0) / dx, 1.0 / dx
    elif dx < 0.0:
        step_c, t_next_c, t_delta_c = -1, (x0 - c) / (-dx), -1.0 / dx
    else:
        step_c, t_next_c, t_delta_c = 0, np.inf, np.inf
    return r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c


@numba.njit(cache=True, inline="always")
def dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c):
    """One Amanatides-Woo step into the next cell. Returns ``(r, c, t_next_r, t_next_c, t_entry, axis)``: the new
    cell, the updated boundary parameters, where the ray entered the cell and through which boundary (0: a row
    boundary, 1: a column boundary). Exact ties (a cell corner) step along columns first, so a ray cannot slip
    between two cells that touch only at a corner."""
    if t_next_c <= t_next_r:
        return r, c + step_c, t_next_r, t_next_c + t_delta_c, t_next_c, 1
    return r + step_r, c, t_next_r + t_delta_r, t_next_c, t_next_r, 0


@numba.njit(cache=True)
def window_covariance(mask, r, c, half):
    """Count and covariance of the cells of bool ``mask`` within ``half`` cells of cell (r, c) (the square window,
    clipped at the border), as offsets ``(dy, dx)`` from it: ``(n, cyy, cxx, cxy)``, the covariance zero for
    ``n == 0``. What a wall's line is fitted to (:func:`minor_axis_2x2` of it gives the normal)."""
    n_rows, n_cols = mask.shape
    n = 0
    sy = 0.0
    sx = 0.0
    syy = 0.0
    sxx = 0.0
    sxy = 0.0
    for rr in range(max(0, r - half), min(n_rows, r + half + 1)):
        for cc in range(max(0, c - half), min(n_cols, c + half + 1)):
            if mask[rr, cc]:
                dy = float(rr - r)
                dx = float(cc - c)
                n += 1
                sy += dy
                sx += dx
                syy += dy * dy
                sxx += dx * dx
                sxy += dy * dx
    if n == 0:
        return 0, 0.0, 0.0, 0.0
    my = sy / n
    mx = sx / n
    return n, syy / n - my * my, sxx / n - mx * mx, sxy / n - my * mx


@numba.njit(cache=True, inline="always")
def minor_axis_2x2(cyy, cxx, cxy):
    """Eigen-decomposition of the symmetric 2x2 matrix ``[[cyy, cxy], [cxy, cxx]]`` (a point set's covariance in
    ``(y, x)`` order), for fitting a line to wall points: the minor axis is the line's normal.

    Returns ``(half_trace, spread, vy, vx, norm)``: the eigenvalues are ``half_trace +- spread``; ``(vy, vx) / norm``
    is the unit eigenvector of the smaller one (undefined where ``norm == 0``: an isotropic or empty spread). The
    unnormalised vector is ``(minor - cxx, cxy)`` or ``(cxy, minor - cyy)``, whichever is longer, since
    ``(A - minor I) v = 0`` is solved by either row's perpendicular and the longer one is the better conditioned.
    """
    half_trace = 0.5 * (cyy + cxx)
    spread = np.sqrt(0.25 * (cyy - cxx) ** 2 + cxy * cxy)
    minor = half_trace - spread
    vy1, vx1 = minor - cxx, cxy
    vy2, vx2 = cxy, minor - cyy
    if vy1 * vy1 + vx1 * vx1 >= vy2 * vy2 + vx2 * vx2:
        vy, vx = vy1, vx1
    else:
        vy, vx = vy2, vx2
    return half_trace, spread, vy, vx, np.sqrt(vy * vy + vx * vx)


@numba.njit(cache=True)
def _trace_first_hit(occupied, y0, x0, dy, dx, max_t):
    """Walk one ray through the grid; return (row, col, t_entry, entry_axis) of the first occupied cell.

    Stops with row = col = -1 when the ray exceeds ``max_t`` cells or leaves the grid (t = where it stopped).
    Exact ties (the ray passes through a cell corner) step along columns first, so a ray cannot slip between
    two walls that touch only at a corner.
    """
    n_rows, n_cols = occupied.shape
    r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(y0, x0, dy, dx)
    if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
        return -1, -1, 0.0, -1
    if occupied[r, c]:
        return r, c, 0.0, -1
    while True:
        r, c, t_next_r, t_next_c, t, axis = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c)
        if t > max_t:
            return -1, -1, max_t, -1
        if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
            return -1, -1, t, -1
        if occupied[r, c]:
            return r, c, t, axis


@numba.njit(cache=True)
def _cast_rays(occupied, y0, x0, angles, max_t, hit_rc, distance, entry_axis):
    for i in range(angles.shape[0]):
        r, c, t, axis = _trace_first_hit(occupied, y0, x0, np.sin(angles[i]), np.cos(angles[i]), max_t)
        hit_rc[i, 0] = r
        hit_rc[i, 1] = c
        distance[i] = t
        entry_axis[i] = axis


@numba.njit(cache=True)
def _mark_rays(occupied, y0, x0, angles, max_t, free_out, hit_out):
    """Mark every cell a ray crosses before its first hit in ``free_out`` and the hit cell in ``hit_out``."""
    n_rows, n_cols = occupied.shape
    for i in range(angles.shape[0]):
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
            y0, x0, np.sin(angles[i]), np.cos(angles[i]))
        if occupied[r, c]:
            hit_out[r, c] = True
            continue
        free_out[r, c] = True
        while True:
            r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                      t_delta_c)
            if t > max_t or r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                break
            if occupied[r, c]:
                hit_out[r, c] = True
                break
            free_out[r, c] = True


def _check_grid_and_origin(occupied: np.ndarray, origin_yx) -> tuple[np.ndarray, float, float]:
    occupied = np.asarray(occupied)
    if occupied.dtype != np.bool_:
        raise ValueError(f"occupied must be a bool array, got dtype {occupied.dtype}")
    if occupied.ndim != 2 or occupied.shape[0] == 0 or occupied.shape[1] == 0:
        raise ValueError(f"occupied must be a non-empty 2-D [rows, cols] array, got shape {occupied.shape}")
    y0, x0 = _check_origin(occupied.shape, origin_yx)
    return np.ascontiguousarray(occupied), y0, x0


def _check_origin(shape, origin_yx) -> tuple[float, float]:
    y0, x0 = (float(v) for v in origin_yx)
    if not (np.isfinite(y0) and np.isfinite(x0)):
        raise ValueError(f"ray origin must be finite, got {(y0, x0)}")
    if not (0.0 <= y0 < shape[0] and 0.0 <= x0 < shape[1]):
        raise ValueError(f"ray origin (y, x) = {(y0, x0)} lies outside the grid of shape {tuple(shape)}")
    return y0, x0


def _check_angles_and_range(angles, max_range_cells) -> tuple[np.ndarray, float]:
    angles = np.ascontiguousarray(np.asarray(angles, dtype=np.float64))
    if angles.ndim != 1:
        raise ValueError(f"angles must be 1-D, got shape {angles.shape}")
    if not np.all(np.isfinite(angles)):
        raise ValueError("angles must be finite")
    max_range_cells = float(max_range_cells)
    if not (max_range_cells > 0.0 and np.isfinite(max_range_cells)):
        raise ValueError(f"max_range_cells must be positive and finite, got {max_range_cells}")
    return angles, max_range_cells


def cast_rays(occupied: np.ndarray, origin_yx, angles, max_range_cells: float) -> RayHits:
    """First occupied cell along each ray.

    Args:
        occupied: bool ``[H, W]`` occupancy grid.
        origin_yx: ray origin ``(y, x)`` in cells (e.g. :func:`cell_centre` of the robot cell); must lie inside
            the grid.
        angles: float ``[N]`` ray angles (radians, see module conventions).
        max_range_cells: maximum range along the ray (cells).

    Returns:
        :class:`RayHits` for the ``N`` rays. A ray starting in an occupied cell hits it at distance 0.
    """
    occupied, y0, x0 = _check_grid_and_origin(occupied, origin_yx)
    angles, max_t = _check_angles_and_range(angles, max_range_cells)
    n = angles.shape[0]
    hit_rc = np.empty((n, 2), dtype=np.int32)
    distance = np.empty(n, dtype=np.float64)
    entry_axis = np.empty(n, dtype=np.int8)
    _cast_rays(occupied, y0, x0, angles, max_t, hit_rc, distance, entry_axis)
    return RayHits(hit_rc=hit_rc, distance_cells=distance, entry_axis=entry_axis)


def mark_rays(occupied: np.ndarray, origin_yx, angles, max_range_cells: float,
              free_out: np.ndarray, hit_out: np.ndarray) -> None:
    """Line-of-sight update: mark the cells each ray crosses as seen-free and its first hit as seen-occupied.

    Args:
        occupied: bool ``[H, W]`` ground-truth occupancy the rays travel through.
        origin_yx: ray origin ``(y, x)`` in cells, inside the grid.
        angles: float ``[N]`` ray angles (radians).
        max_range_cells: maximum range (cells); cells entered beyond it are not marked.
        free_out: bool ``[H, W]``, updated in place (set to True, never cleared).
        hit_out: bool ``[H, W]``, updated in place (set to True, never cleared).
    """
    occupied, y0, x0 = _check_grid_and_origin(occupied, origin_yx)
    angles, max_t = _check_angles_and_range(angles, max_range_cells)
    for name, out in (("free_out", free_out), ("hit_out", hit_out)):
        if not isinstance(out, np.ndarray) or out.dtype != np.bool_ or out.shape != occupied.shape:
            raise ValueError(f"{name} must be a bool array of shape {occupied.shape}")
        if not out.flags.c_contiguous or not out.flags.writeable:
            raise ValueError(f"{name} must be C-contiguous and writeable (it is updated in place)")
    _mark_rays(occupied, y0, x0, angles, max_t, free_out, hit_out)


@numba.njit(cache=True)
def _mark_ranges(y0, x0, angles, ranges, max_t, tolerance, free_out, hit_out):
    """Mark the cells each ray crosses before its measured return as free and the return's cell as hit.

    ``ranges[i] < 0``: no return, cells entered up to ``max_t`` are free."""
    n_rows, n_cols = free_out.shape
    for i in range(angles.shape[0]):
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
            y0, x0, np.sin(angles[i]), np.cos(angles[i]))
        hit_at = ranges[i] + tolerance if ranges[i] >= 0.0 else -1.0
        while True:
            t_exit = min(t_next_c, t_next_r)
            if hit_at >= 0.0 and t_exit > hit_at:
                hit_out[r, c] = True
                break
            free_out[r, c] = True
            r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                      t_delta_c)
            if t > max_t or r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                break


def mark_ranges(origin_yx, angles, ranges_cells, max_range_cells: float, free_out: np.ndarray,
                hit_out: np.ndarray) -> None:
    """Line-of-sight update from *measured* ranges: what :func:`mark_rays` does, without the ground truth.

    Along each ray, walked by the same DDA as :func:`mark_rays`, every cell the ray leaves before its return is
    marked free, and the cell holding the point ``range + RETURN_TOLERANCE_CELLS`` is marked hit. A ray without a
    return marks every cell it enters up to ``max_range_cells`` free. Given the distances :func:`cast_rays`
    returns, the result equals :func:`mark_rays` on the grid the rays were cast in, except where a ray crosses
    its hit cell for less than the tolerance plus the range's rounding (a corner clipped by micrometres).

    Args:
        origin_yx: sensor position ``(y, x)`` in cells, inside the grid.
        angles: float ``[N]`` ray angles (radians, grid convention).
        ranges_cells: float ``[N]`` measured range of each ray (cells, >= 0), ``inf`` for no return.
        max_range_cells: the sensor's maximum range (cells, > 0).
        free_out, hit_out: bool ``[H, W]`` C-contiguous, updated in place (set, never cleared).

    Raises:
        ValueError: an origin outside the grid, non-finite angles, NaN or negative ranges, lengths that differ,
            bad output arrays.
    """
    for name, out in (("free_out", free_out), ("hit_out", hit_out)):
        if not isinstance(out, np.ndarray) or out.dtype != np.bool_ or out.ndim != 2 or min(out.shape) < 1:
            raise ValueError(f"{name} must be a non-empty bool [H, W] array")
        if not out.flags.c_contiguous or not out.flags.writeable:
            raise ValueError(f"{name} must be C-contiguous and writeable (it is updated in place)")
    if hit_out.shape != free_out.shape:
        raise ValueError(f"free_out has shape {free_out.shape} but hit_out has {hit_out.shape}")
    y0, x0, angles, ranges, max_t = check_measured_rays(free_out.shape, origin_yx, angles, ranges_cells,
                                                        max_range_cells)
    _mark_ranges(y0, x0, angles, ranges, max_t, RETURN_TOLERANCE_CELLS, free_out, hit_out)


def check_measured_rays(shape, origin_yx, angles, ranges_cells, max_range_cells: float
                        ) -> tuple[float, float, np.ndarray, np.ndarray, float]:
    """Check the arguments of a measured scan for a grid of ``shape`` (what :func:`mark_ranges` and the mapper's
    log-odds update take) and return them as the kernels want them: ``(y0, x0, angles, ranges, max_t)``, angles
    and ranges C-contiguous float64, a range of ``inf`` (no return) as ``-1``.

    Raises:
        ValueError: an origin outside the grid or not finite, non-finite angles, a non-positive or infinite range
            limit, ranges of another length, NaN or negative ranges.
    """
    y0, x0 = _check_origin(shape, origin_yx)
    angles, max_t = _check_angles_and_range(angles, max_range_cells)
    ranges = np.asarray(ranges_cells, dtype=np.float64)
    if ranges.shape != angles.shape:
        raise ValueError(f"ranges_cells has shape {ranges.shape}, the angles {angles.shape}")
    if np.any(np.isnan(ranges)) or np.any(ranges < 0.0):
        raise ValueError("ranges_cells must be >= 0 (inf for no return), got NaN or a negative range")
    return y0, x0, angles, np.ascontiguousarray(np.where(np.isfinite(ranges), ranges, -1.0)), max_t


def line_of_sight(blocked: np.ndarray, a_rc, b_rc) -> bool:
    """Whether the segment between the centres of two cells crosses no blocked cell, both ends included.

    The segment is walked by the same DDA as :func:`cast_rays` (an exact corner crossing steps along columns
    first, so a line cannot slip between two blocked cells that touch only at a corner).

    Args:
        blocked: bool ``[H, W]`` cells that stop the line (for line of sight on an observed map: every cell
            that is not known free).
        a_rc, b_rc: the two cells (row, col), inside the grid.

    Returns:
        True when neither cell nor any cell the segment enters between them is blocked.

    Raises:
        ValueError: ``blocked`` not a non-empty bool 2-D array, or a cell outside it.
    """
    blocked, y0, x0 = _check_grid_and_origin(blocked, cell_centre(a_rc))
    y1, x1 = cell_centre(b_rc)
    if not (0.0 <= y1 < blocked.shape[0] and 0.0 <= x1 < blocked.shape[1]):
        raise ValueError(f"cell {tuple(int(v) for v in b_rc)} lies outside the grid of shape {blocked.shape}")
    length = float(np.hypot(y1 - y0, x1 - x0))
    if length == 0.0:
        return not bool(blocked[int(y0), int(x0)])
    row, _, _, _ = _trace_first_hit(blocked, y0, x0, (y1 - y0) / length, (x1 - x0) / length, length)
    return row < 0


@numba.njit(cache=True)
def group_by_cell(hit_rc, n_cols):
    """Group rays by the cell they hit, the groups ordered by linear cell index ``row * n_cols + col``.

    Args:
        hit_rc: int ``[n_rays, 2]`` hit cell of each ray, row -1 for none.
        n_cols: columns of the grid.

    Returns:
        ``ray_group`` int64 ``[n_rays]`` (the group of each ray, -1 for no hit), ``cells`` int64 ``[n_groups, 2]``
        and ``first_ray`` int64 ``[n_groups]``, the lowest-index ray of each group. Rays hitting one cell are
        mostly consecutive, so runs of them are merged first and only the runs sorted.
    """
    n_rays = hit_rc.shape[0]
    run_key = np.empty(n_rays, np.int64)
    run_start = np.empty(n_rays, np.int64)
    n_runs = 0
    previous = -1
    for i in range(n_rays):
        key = hit_rc[i, 0] * np.int64(n_cols) + hit_rc[i, 1] if hit_rc[i, 0] >= 0 else -1
        if key >= 0 and key != previous:
            run_key[n_runs] = key
            run_start[n_runs] = i
            n_runs += 1
        previous = key
    # Stable: among runs of one cell, the earliest ray's run comes first.
    order = np.argsort(run_key[:n_runs], kind="mergesort")
    run_group = np.empty(n_runs, np.int64)
    cells = np.empty((n_runs, 2), np.int64)
    first_ray = np.empty(n_runs, np.int64)
    n_groups = 0
    previous = -1
    for j in range(n_runs):
        run = order[j]
        if run_key[run] != previous:
            first = run_start[run]
            cells[n_groups, 0] = hit_rc[first, 0]
            cells[n_groups, 1] = hit_rc[first, 1]
            first_ray[n_groups] = first
            n_groups += 1
            previous = run_key[run]
        run_group[run] = n_groups - 1
    ray_group = np.full(n_rays, -1, np.int64)
    run = -1
    previous = -1
    for i in range(n_rays):
        key = hit_rc[i, 0] * np.int64(n_cols) + hit_rc[i, 1] if hit_rc[i, 0] >= 0 else -1
        if key >= 0:
            if key != previous:
                run += 1
            ray_group[i] = run_group[run]
        previous = key
    return ray_group, cells[:n_groups], first_ray[:n_groups]
