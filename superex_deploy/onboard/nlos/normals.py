"""NLOS processing, stage 2: wall normals from the scan's own wall hits (the minor principal axis of the hits
around each wall cell), which of them are trusted for carving, and the normals turned to face the robot with each
wall cell's fan origin (apex). Why a normal must pass each test: point 3 of :mod:`.carving`'s soundness argument.
"""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.geometry import minor_axis_2x2
from superex_deploy.parallel import kernel_parts
from superex_deploy.onboard.nlos.shared import NlosConfig
from superex_deploy.spad_types import SpadScan


@numba.njit(cache=True, parallel=True)
def hit_normals(points, radius, max_minor_ratio, max_residual, max_gap, interior, normals, reliable, n_parts):
    """Minor principal axis of the points within ``radius`` of each point (itself included); ``reliable`` where
    there are at least 3 such points, the minor variance is below ``max_minor_ratio`` of the major one, every
    point lies within ``max_residual`` of the fitted line, no two neighbours along it are more than ``max_gap``
    apart, and the point lies at least ``interior[u]`` cells inside the extent of its neighbours along the wall
    (float64 ``[U]``: one distance per point; ``inf``: the point only supports the others' fits, its own normal
    is not fitted and stays as given).

    ``points`` must be sorted by row (``points[:, 0]`` ascending, as row-major cell indices give them): each point
    then looks for neighbours only in the band of rows within ``radius``. The points are cut into ``n_parts``
    runs done in parallel; each point's result depends on nothing else, so neither does it on the split."""
    n = points.shape[0]
    chunk = (n + n_parts - 1) // n_parts
    for part in numba.prange(n_parts):
        _hit_normals_of(points, radius, max_minor_ratio, max_residual, max_gap, interior, normals, reliable,
                        part * chunk, min(n, (part + 1) * chunk))


@numba.njit(cache=True)
def _hit_normals_of(points, radius, max_minor_ratio, max_residual, max_gap, interior, normals, reliable, first,
                    stop):
    """:func:`hit_normals` of the points ``first .. stop - 1``."""
    n = points.shape[0]
    along_buffer = np.empty(n)
    near = np.empty(n, np.int64)
    band_lo = 0
    band_hi = 0
    for u in range(first, stop):
        if interior[u] == np.inf:  # can never be trusted: not fitted (a support point, see map_supported_normals)
            continue
        # The band of rows [y - radius - 1, y + radius + 1] holds every neighbour (a cell of slack for rounding);
        # both ends only move forward as u goes down the rows.
        while points[band_lo, 0] < points[u, 0] - radius - 1.0:
            band_lo += 1
        while band_hi < n and points[band_hi, 0] <= points[u, 0] + radius + 1.0:
            band_hi += 1
        # The neighbours, listed once (in index order) for the three passes below.
        count = 0
        sy = 0.0
        sx = 0.0
        for v in range(band_lo, band_hi):
            dy = points[v, 0] - points[u, 0]
            dx = points[v, 1] - points[u, 1]
            if dy * dy + dx * dx <= radius * radius:
                near[count] = v
                count += 1
                sy += points[v, 0]
                sx += points[v, 1]
        if count < 3:
            continue
        my = sy / count
        mx = sx / count
        cyy = 0.0
        cxx = 0.0
        cxy = 0.0
        for k in range(count):
            v = near[k]
            cyy += (points[v, 0] - my) ** 2
            cxx += (points[v, 1] - mx) ** 2
            cxy += (points[v, 0] - my) * (points[v, 1] - mx)
        half_trace, spread, vy, vx, norm = minor_axis_2x2(cyy, cxx, cxy)
        major = half_trace + spread
        minor = half_trace - spread
        if major <= 0.0 or minor > max_minor_ratio * major:
            continue
        if norm == 0.0:
            continue
        vy /= norm
        vx /= norm
        normals[u, 0] = vy
        normals[u, 1] = vx
        # Interior test: hits at least ``interior`` cells away on both sides along the wall. Wall ends and
        # corners have normals of their own (a thin wall's end cell faces along the wall), so they are not
        # trusted for carving.
        along = along_buffer[:count]
        straight = True
        for k in range(count):
            v = near[k]
            along[k] = -(points[v, 0] - points[u, 0]) * vx + (points[v, 1] - points[u, 1]) * vy
            if abs((points[v, 0] - my) * vy + (points[v, 1] - mx) * vx) > max_residual:
                straight = False
        along.sort()
        # Contiguous: a gap wider than ``max_gap`` may be a wall end followed by another wall, where the
        # true normal turns.
        contiguous = True
        for k in range(1, count):
            if along[k] - along[k - 1] > max_gap:
                contiguous = False
        reliable[u] = straight and contiguous and along[0] <= -interior[u] and along[count - 1] >= interior[u]


@numba.njit(cache=True)
def step_deviation(points, normals, out):
    """``out[u]`` (float64 ``[U]``, radians): the largest angle between the wall line through point ``u`` (the
    direction perpendicular to ``normals[u]``) and the direction to any other point among its 8 neighbours (cell
    centres at most one cell away in each axis); 0 for a point without neighbours.

    Why: a rasterised oblique wall is a staircase, and at a step the surface of the cell itself turns off the
    wall's line (by up to 45 degrees at a one-cell jog): a scattering fan that leaves the cell along the cell's own
    surface normal does not cover the sector about the wall's fitted normal (point 3 of :mod:`.carving`).
    ``points`` must be sorted by row, as for :func:`hit_normals`."""
    n = points.shape[0]
    band_lo = 0
    for u in range(n):
        while points[band_lo, 0] < points[u, 0] - 1.5:
            band_lo += 1
        ty = -normals[u, 1]
        tx = normals[u, 0]
        worst = 0.0
        v = band_lo
        while v < n and points[v, 0] <= points[u, 0] + 1.5:
            dy = points[v, 0] - points[u, 0]
            dx = points[v, 1] - points[u, 1]
            if v != u and abs(dy) <= 1.5 and abs(dx) <= 1.5 and (dy != 0.0 or dx != 0.0):
                along = abs(dy * ty + dx * tx) / np.sqrt(dy * dy + dx * dx)
                worst = max(worst, np.arccos(min(along, 1.0)))
            v += 1
        out[u] = worst


@numba.njit(cache=True)
def face_the_robot(points, origin_y, origin_x, normals, reliable, apex):
    """Where a normal is not ``reliable`` the unit direction from the point to the robot replaces it; every
    normal is then turned to face the robot (in place). ``apex`` receives each wall cell's fan origin X1: where
    the normal through the cell centre ``points[u]`` leaves the cell."""
    for u in range(points.shape[0]):
        ty = origin_y - points[u, 0]
        tx = origin_x - points[u, 1]
        norm = max(np.sqrt(ty * ty + tx * tx), 1e-12)
        ty /= norm
        tx /= norm
        if not reliable[u]:
            normals[u, 0] = ty
            normals[u, 1] = tx
        if normals[u, 0] * ty + normals[u, 1] * tx < 0.0:
            normals[u, 0] = -normals[u, 0]
            normals[u, 1] = -normals[u, 1]
        half = 0.5 / max(abs(normals[u, 0]), abs(normals[u, 1]), 1e-12)
        apex[u, 0] = points[u, 0] + half * normals[u, 0]
        apex[u, 1] = points[u, 1] + half * normals[u, 1]


def observed_normals(wall_cells: np.ndarray, scan: SpadScan, cfg: NlosConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normals from the scan's own wall hits: the minor principal axis of the hits within
    ``normal_radius_m`` of each wall cell, facing the robot (the config's lengths in cells of the scan's grid).

    Returns ``(normals float64 [U, 2], reliable bool [U], apex float64 [U, 2])`` (apex: the fan origin X1, see
    :attr:`LosEstimate.wall_apex`). A normal is reliable when at least three hits
    with a clearly linear spread (minor/major variance below ``normal_max_minor_ratio``, every hit within
    ``normal_max_residual_m`` of the line, no gap along it wider than ``normal_max_gap_m``) support it
    and the cell lies inside that line (``normal_interior_m`` from its observed ends); elsewhere (corners,
    wall ends, sparse hits) the direction back to the robot stands in, for back-projection only: carving skips
    unreliable normals, since a wrong normal would turn the carved sector onto the wall itself.
    """
    n_walls = len(wall_cells)
    normals = np.zeros((n_walls, 2))
    reliable = np.zeros(n_walls, bool)
    apex = np.empty((n_walls, 2))
    if n_walls == 0:
        return normals, reliable, apex
    points = wall_cells + 0.5
    cells = cfg.in_cells(scan.resolution_m)
    hit_normals(points, cells.normal_radius, cfg.normal_max_minor_ratio, cells.normal_max_residual,
                cells.normal_max_gap, np.full(n_walls, cells.normal_interior), normals, reliable,
                kernel_parts(cfg.threads))
    face_the_robot(points, scan.origin_yx[0], scan.origin_yx[1], normals, reliable, apex)
    return normals, reliable, apex


def reliable_with_interior(wall_cells: np.ndarray, cfg: NlosConfig, resolution_m: float,
                           interior_cells: np.ndarray) -> np.ndarray:
    """bool ``[U]``: which wall cells' normals :func:`observed_normals` would trust, on a grid of ``resolution_m``,
    with a per-cell interior distance ``interior_cells`` (float64 ``[U]``, cells) in place of
    ``cfg.normal_interior_m`` (the carving's stricter test under pose uncertainty)."""
    n_walls = len(wall_cells)
    reliable = np.zeros(n_walls, bool)
    if n_walls:
        cells = cfg.in_cells(resolution_m)
        hit_normals(wall_cells + 0.5, cells.normal_radius, cfg.normal_max_minor_ratio,
                    cells.normal_max_residual, cells.normal_max_gap,
                    np.ascontiguousarray(interior_cells, np.float64), np.zeros((n_walls, 2)), reliable,
                    kernel_parts(cfg.threads))
    return reliable


def map_supported_normals(wall_cells: np.ndarray, normals: np.ndarray, reliable: np.ndarray, apex: np.ndarray,
                          scan: SpadScan, cfg: NlosConfig, map_walls: np.ndarray, interior_cells=None,
                          candidates=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scan's normals (``normals``, ``reliable``, ``apex`` as :func:`observed_normals` gives them) with every
    wall cell they do not trust refitted to the scan's wall hits and the map's wall cells together (``map_walls``
    bool ``[H, W]`` on the scan's grid): the same tests (straight, contiguous, interior) with more of the wall to
    pass them, and only where the map holds that cell a wall too (a wall-cell estimate one cell off the wall, in
    front of it, would fit the map's wall with an apex where no fan starts). Cells the scan trusts keep their
    normals.

    Why: a wall cell at the end of *this scan's* hits is not trusted (point 3 of :mod:`.carving`), though most such
    ends are where the scan stops seeing the wall (an occluder, grazing incidence, the edge of the fan), not where
    the wall stops. The map has seen more of it: where its wall cells run on straight past the cell on both sides,
    the cell lies inside a wall and its fan faces the wall's normal. Where the map shows the wall ending or turning
    (a corner, a wall end, another wall within ``normal_radius_m``), the union fails the same tests and the cell
    stays untrusted. ``interior_cells`` (float64 ``[U]``, cells; None: ``normal_interior_m``) widens the interior
    test, as :func:`reliable_with_interior` does under pose uncertainty; ``candidates`` (bool ``[U]``; None: all)
    limits the refit to the cells that could carve at all (the carving passes those whose rays' first late photons
    leave a radius past the wall strip), which keeps it cheap.

    The wall's turn at a cell trusted so (:func:`step_deviation`, which narrows its carved sector) is taken over
    the same union: where the map shows the wall stepping beside the cell, its surface turns there though the
    scan's hits ran straight (the property test over random L-corners found such a cell, the scan's hits
    straight up to it and the map's wall stepping one cell back).

    Returns new ``(normals float64 [U, 2], reliable bool [U], apex float64 [U, 2], steps float64 [U])``; ``steps``:
    the wall's turn (radians) at each cell newly trusted, NaN at the others (for
    :func:`.carving.sector_cos_limits`).

    Raises:
        ValueError: ``map_walls`` not a bool array of the scan's grid shape.
    """
    map_walls = np.asarray(map_walls)
    if map_walls.dtype != np.bool_ or map_walls.shape != tuple(scan.grid_shape):
        raise ValueError(f"map_walls must be a bool array of the scan's grid shape {tuple(scan.grid_shape)}, got "
                         f"{map_walls.dtype} {map_walls.shape}")
    normals, reliable, apex = normals.copy(), reliable.copy(), apex.copy()
    steps = np.full(len(wall_cells), np.nan)
    refit = ~reliable & map_walls[wall_cells[:, 0], wall_cells[:, 1]]
    if candidates is not None:
        refit &= candidates
    untrusted = np.flatnonzero(refit)
    if len(untrusted) == 0:
        return normals, reliable, apex, steps
    cells = cfg.in_cells(scan.resolution_m)
    interior = (np.full(len(wall_cells), cells.normal_interior) if interior_cells is None
                else np.asarray(interior_cells, np.float64))
    # The support: the map's wall cells in the square of the fit's radius around each cell refitted (every point
    # its fit can read), and the scan's, marked on the box of those squares; read back in row order (as hit_normals
    # needs) with each point's index kept on the box. Only the cells refitted are fitted, the others support them.
    reach = int(np.floor(cells.normal_radius))
    span = np.arange(-reach, reach + 1)
    offsets = np.stack(np.meshgrid(span, span, indexing="ij"), axis=-1).reshape(-1, 2)
    refit_cells = wall_cells[untrusted]
    top, left = np.maximum(refit_cells.min(axis=0) - reach, 0)
    bottom, right = np.minimum(refit_cells.max(axis=0) + reach + 1, map_walls.shape)
    window = np.zeros((bottom - top, right - left), bool)
    around = (refit_cells[:, None, :] + offsets[None] - (top, left)).reshape(-1, 2)
    around = around[np.all((around >= 0) & (around < window.shape), axis=1)]
    window[around[:, 0], around[:, 1]] = True
    support = window & map_walls[top:bottom, left:right]
    local = wall_cells - (top, left)
    inside = np.all((local >= 0) & (local < window.shape), axis=1)
    support[local[inside, 0], local[inside, 1]] = True
    points = np.argwhere(support).astype(np.float64) + (top + 0.5, left + 0.5)
    index = np.full(window.shape, -1, np.int64)
    index[support] = np.arange(len(points))
    position = np.full(len(wall_cells), -1, np.int64)
    position[inside] = index[local[inside, 0], local[inside, 1]]
    fitted = position[untrusted]
    union_interior = np.full(len(points), np.inf)
    union_interior[fitted] = interior[untrusted]
    union_normals = np.zeros((len(points), 2))
    union_reliable = np.zeros(len(points), bool)
    # Sequential (hit_normals' own loop, outside any parallel region): the cells refitted are few (tens to
    # hundreds), and a parallel region waits for numba's thread pool (shared with the prediction's worker thread):
    # in the shipped pipeline on the largest eval floor, on a loaded machine, that wait was about 12 ms a frame, the
    # fit well under one.
    _hit_normals_of(points, cells.normal_radius, cfg.normal_max_minor_ratio, cells.normal_max_residual,
                    cells.normal_max_gap, union_interior, union_normals, union_reliable, 0, len(points))
    gained = untrusted[union_reliable[fitted]]
    if len(gained):
        gained_normals = union_normals[position[gained]]
        gained_apex = np.empty((len(gained), 2))
        face_the_robot(wall_cells[gained] + 0.5, scan.origin_yx[0], scan.origin_yx[1], gained_normals,
                       np.ones(len(gained), bool), gained_apex)
        normals[gained], apex[gained], reliable[gained] = gained_normals, gained_apex, True
        union_steps = np.zeros(len(points))
        step_deviation(points, union_normals, union_steps)
        steps[gained] = union_steps[position[gained]]
    return normals, reliable, apex, steps

