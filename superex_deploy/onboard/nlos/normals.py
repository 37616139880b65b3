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
    (float64 ``[U]``: one distance per point).

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
