"""NLOS processing, stage 3: space carving, the cells proven free by each ray's first late photon.

Space carving (Tsai et al., CVPR 2017) and why it is sound
-----------------------------------------------------------
For a ray whose direct return lies in bin ``b1`` and whose first late (three-bounce) photon lies in bin ``bf``,
``2 d1 < (b1 + 1) w`` and ``2 d1 + 2 d2 >= bf w`` (``w``: path per bin), so every secondary ray of that wall
point travelled at least ``r = (bf - b1 - 1) w / 2`` before meeting a surface. Turning that into free cells
needs three more arguments, each a margin below:

1. **Angular sampling.** The simulator (like any finite model of the scattering) samples ``K`` secondary
   directions, ``pi / K`` apart. A wall cell of side ``s`` at distance ``rho`` spans an angle of at least
   ``~ s / rho``; it is certain to be crossed by a sampled direction only while ``s / rho >= pi / K``. Beyond
   ``rho_max = s K / pi`` a thin wall end pointing at the wall point can slip between two rays, and the first
   return then overstates the empty radius. The carve radius is therefore capped at ``rho_max``: a denser
   fan (``SpadConfig.n_secondary``) carves further (8.1 m at the default 256 rays of 0.1 m cells, 2.0 m at 64).
2. **Where the wall point is.** The processing knows ``h1`` only from the direct-return bin: its estimate can
   be one cell off, and the simulator's fans start at ``X1`` on the cell's face. The radius is reduced by
   ``apex_margin_m`` plus ``s / sqrt(2)`` (a cell counts as a wall when any part of it is hit, and we test
   cell centres).
3. **Which side.** The fan spans +-90 degrees about the true normal, the carve uses a normal estimated from the
   scan's own wall hits; the carved sector is narrowed to +-(90 - sector_margin_deg) and a strip of
   ``wall_strip_m`` along the wall itself is left out (it is seen directly anyway). A normal is trusted
   only where the hits around the wall cell lie on one straight line (small minor/major variance ratio and
   every hit within ``normal_max_residual_m`` of the fitted line, no gap along it wider than
   ``normal_max_gap_m``), the cell is inside that line, and
   the robot does not see it at grazing incidence; other wall cells are not carved from. The property test
   found each of these cases: three hits from two walls (a thin wall's face and a wall seen past its end)
   fitted a line tilted 25 degrees, which flipped the carved sector onto the far wall; and a wall-end cell
   whose hits ran on, across a 4-cell gap, to a second wall carved a sector the end's own fan never covered.
   Where the wall steps (a rasterised oblique wall is a staircase; a thin wall jogs by a cell) the fan leaves
   the cell along the cell's own surface normal, which turns off the fitted line as the step does (45 degrees
   at a one-cell jog): the sector is narrowed to +-(90 - max(sector_margin_deg, step)), ``step`` the largest
   angle between the fitted line and the direction to a neighbouring hit (:func:`sector_cos_limits`). The
   property test over random L-shaped walls (tests/test_carving_corners.py) found it, the sector's edge
   reaching a far wall's corner past the fan's. What no rule here sees: the simulator's cell normal (Sobel of
   the 3x3 neighbourhood) also reads the cells behind the surface, so a wall two cells thick whose back face
   steps turns the fan of a front cell that looks straight (2 of 3,000 random L-corner scans carved a wall
   cell so; docs/benchmarks/carving.md).
4. **Where the robot is.** With an uncertain pose the whole frame (wall points, normals, carved sectors) is
   placed by the believed pose: the scan is rigid, so every carved point lands off its true place by at most
   ``|dxy| + rho |dyaw|`` (position error, yaw error, ``rho`` its distance from the robot). Each wall point's
   carve radius is reduced, and its wall strip widened, by ``pose_sigma_margin`` times
   ``sigma_xy + rho_max sigma_yaw`` (``rho_max``: the farthest point its disc could hold); the sector's
   narrowing by ``sector_margin_deg`` (20 degrees) covers the normal's turn by the yaw error. The displacement
   also moves the hits across cell borders, so a wall cell's estimate may land beside a corner or a wall end
   whose hits, re-drawn, look straight: the property test found a 4.6 m distant staircase corner trusted under
   a 2 cm / 0.7 degree error, whose true fan faced elsewhere. A normal is therefore trusted for carving only
   with the interior distance (``normal_interior_m``) widened by the same margin at the wall cell
   (``sigma_xy + rho sigma_yaw``, ``rho`` its distance). Without a covariance every margin is zero and the
   carving is the noise-free one, bit for bit.
"""

from __future__ import annotations

from typing import Optional

import numba
import numpy as np

from superex_deploy.parallel import kernel_parts
from superex_deploy.onboard.nlos.shared import (ROW_BLOCK, GridPatch, LosEstimate, NlosConfig,
                                                carve_radius_cap_m)
from superex_deploy.onboard.nlos.normals import map_supported_normals, reliable_with_interior, step_deviation
from superex_deploy.spad_types import SpadScan


@numba.njit(cache=True, parallel=True)
def carve_sectors(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, n_parts):
    """Mark cells whose centre lies within ``radius_cells[u]`` of ``apex[u]``, at least ``strip_cells[u]`` in front
    of the wall line, and within the sector ``cos(angle to the normal) >= cos_limit[u]`` (float64 ``[U]``: one
    sector per wall point, narrowed where the wall steps, see :func:`sector_cos_limits`) seen from a vertex 0.75
    cells in front of the apex (a scattering model may start its fan off the surface, as the simulator does;
    a vertex moved forward only narrows the sector, so the choice errs on the safe side). ``out`` bool
    ``[h, w]`` holds grid rows ``top..top + h - 1`` and columns ``left..left + w - 1``; cells outside it are not
    marked. Blocks of :data:`ROW_BLOCK` rows of ``out`` are dealt round-robin to ``n_parts`` parts marked in
    parallel."""
    for part in numba.prange(n_parts):
        _carve_sector_rows(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, part, n_parts)


@numba.njit(cache=True)
def _carve_sector_rows(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, part, n_parts):
    """:func:`carve_sectors` in the rows of ``out`` that belong to ``part``."""
    row_end = top + out.shape[0]
    col_end = left + out.shape[1]
    for u in range(apex.shape[0]):
        radius = radius_cells[u]
        strip = strip_cells[u]
        limit = cos_limit[u]
        if not radius > strip:
            continue
        ay = apex[u, 0]
        ax = apex[u, 1]
        ny = normals[u, 0]
        nx = normals[u, 1]
        oy = ay + 0.75 * ny
        ox = ax + 0.75 * nx
        for r in range(max(top, int(np.floor(ay - radius))), min(row_end, int(np.ceil(ay + radius)) + 1)):
            if (r - top) // ROW_BLOCK % n_parts != part:
                continue
            vy = r + 0.5 - ay
            rest = radius * radius - vy * vy
            if rest <= 0.0:
                continue
            # Columns of the disc and of the strip's far side (linear in c), widened by a cell: the exact tests
            # below decide.
            span = np.sqrt(rest)
            lo = ax - 0.5 - span
            hi = ax - 0.5 + span
            if nx > 1e-9:
                lo = max(lo, ax - 0.5 + (strip - vy * ny) / nx)
            elif nx < -1e-9:
                hi = min(hi, ax - 0.5 + (strip - vy * ny) / nx)
            elif vy * ny + (span + 2.0) * abs(nx) < strip:
                continue
            if lo > hi + 2.0:
                continue
            c_first = max(left, int(np.floor(max(lo, left - 2.0))) - 1)
            c_last = min(col_end - 1, int(np.ceil(min(hi, col_end + 1.0))) + 1)
            for c in range(c_first, c_last + 1):
                if out[r - top, c - left]:  # marked by another wall point already (neighbours' discs overlap)
                    continue
                vx = c + 0.5 - ax
                if vy * vy + vx * vx >= radius * radius:
                    continue
                if vy * ny + vx * nx < strip:
                    continue
                wy = r + 0.5 - oy
                wx = c + 0.5 - ox
                norm = np.sqrt(wy * wy + wx * wx)
                if norm == 0.0 or (wy * ny + wx * nx) / norm >= limit:
                    out[r - top, c - left] = True


@numba.njit(cache=True)
def _empty_bounds(ray_wall, first_late, empty_radius_m, n_walls):
    """float64 ``[U]`` metres: per wall cell the smallest empty radius of the rays that share it (rays sharing a
    wall-cell estimate may come from different true wall points); 0 where one of them saw no late photon (at grazing
    incidence no three-bounce light exists however empty the space is); inf for a cell no ray hit."""
    bound = np.full(n_walls, np.inf)
    for i in range(ray_wall.shape[0]):
        u = ray_wall[i]
        if u < 0:
            continue
        radius = 0.0 if first_late[i] < 0 else empty_radius_m[i]
        bound[u] = min(bound[u], radius)
    return bound


@numba.njit(cache=True)
def _carve_radii(bound, wall_cells, wall_normal, reliable, origin_y, origin_x, cap_m, resolution_m,
                 apex_margin_cells, cos_max_incidence, strip_cells, sigma_xy_cells, sigma_yaw_rad, strip_out):
    """Carve radius (cells) of each wall cell: its empty radius ``bound`` (:func:`_empty_bounds`), capped at
    ``cap_m`` and reduced by ``apex_margin_cells`` (the config's ``apex_margin_m`` in cells), half a cell diagonal
    and the pose-error margin; zero for a wall cell without a ``reliable`` normal or seen more obliquely than
    ``cos_max_incidence``. ``strip_out[u]`` (float64, preset to ``strip_cells``) gets the wall strip widened by
    the same margin: ``sigma_xy_cells + rho sigma_yaw_rad`` with ``rho`` the distance from the robot to the wall cell's centre plus the radius and a
    cell (both sigmas already multiplied by the margin factor; zero: no pose error)."""
    n_walls = wall_cells.shape[0]
    radius_cells = np.zeros(n_walls)
    for u in range(n_walls):
        if not reliable[u]:
            continue
        ty = origin_y - (wall_cells[u, 0] + 0.5)
        tx = origin_x - (wall_cells[u, 1] + 0.5)
        norm = max(np.sqrt(ty * ty + tx * tx), 1e-12)
        if wall_normal[u, 0] * (ty / norm) + wall_normal[u, 1] * (tx / norm) < cos_max_incidence:
            continue
        radius = min(bound[u], cap_m) / resolution_m - apex_margin_cells - np.sqrt(0.5)
        margin = 0.0
        if sigma_xy_cells > 0.0 or sigma_yaw_rad > 0.0:
            margin = sigma_xy_cells + (norm + max(radius, 0.0) + 1.0) * sigma_yaw_rad
        radius_cells[u] = radius - margin
        strip_out[u] = strip_cells + margin
    return radius_cells


@numba.njit(cache=True)
def _carved_box(apex, radius_cells, strip_cells, n_rows, n_cols):
    """Rows ``top:bottom`` and columns ``left:right`` of the grid holding the discs of every wall point that
    carves (``radius_cells[u] > strip_cells[u]``): every carved cell lies inside. All zero when none carves."""
    top, left, bottom, right = n_rows, n_cols, 0, 0
    for u in range(apex.shape[0]):
        radius = radius_cells[u]
        if not radius > strip_cells[u]:
            continue
        top = min(top, max(int(np.floor(apex[u, 0] - radius)), 0))
        left = min(left, max(int(np.floor(apex[u, 1] - radius)), 0))
        bottom = max(bottom, min(int(np.ceil(apex[u, 0] + radius)) + 1, n_rows))
        right = max(right, min(int(np.ceil(apex[u, 1] + radius)) + 1, n_cols))
    if bottom <= top or right <= left:
        return 0, 0, 0, 0
    return top, left, bottom, right


def sector_cos_limits(wall_cells: np.ndarray, wall_normal: np.ndarray, cfg: NlosConfig, yaw_margin_rad: float = 0.0,
                      steps: Optional[np.ndarray] = None) -> np.ndarray:
    """float64 ``[U]``: the cosine of each wall point's carved half-angle about its fitted normal,
    ``90 deg - max(sector_margin_deg, step + yaw_margin_rad)`` with ``step`` the wall's turn at that cell
    (:func:`.normals.step_deviation`; point 3 of the module docstring).

    ``wall_cells`` int ``[U, 2]`` sorted by row (as :class:`LosEstimate` holds them), ``wall_normal`` float64
    ``[U, 2]`` unit normals; ``yaw_margin_rad``: the pose-error margin on the yaw (0 for an exact pose), which turns
    a step's normal as it turns the fitted one; ``steps``: float64 ``[U]`` radians, the turn where it is known
    from more than the scan's hits (:func:`.normals.map_supported_normals`), NaN elsewhere (None: nowhere)."""
    step = np.zeros(len(wall_cells))
    if len(wall_cells):
        step_deviation(np.ascontiguousarray(wall_cells + 0.5, np.float64), np.ascontiguousarray(wall_normal), step)
    if steps is not None:
        step = np.where(np.isnan(steps), step, steps)
    narrowing = np.maximum(np.deg2rad(cfg.sector_margin_deg), step + yaw_margin_rad)
    return np.cos(np.pi / 2 - np.minimum(narrowing, np.pi / 2))


def check_pose_sigma(pose_sigma) -> tuple[float, float]:
    """``(sigma_xy_m, sigma_yaw_rad)`` as two finite floats >= 0.

    Raises:
        ValueError: another shape, a negative or non-finite sigma.
    """
    try:
        sigma_xy, sigma_yaw = (float(v) for v in pose_sigma)
    except (TypeError, ValueError):
        raise ValueError(f"pose_sigma must be a (sigma_xy_m, sigma_yaw_rad) pair, got {pose_sigma!r}") from None
    if not (np.isfinite(sigma_xy) and np.isfinite(sigma_yaw) and sigma_xy >= 0.0 and sigma_yaw >= 0.0):
        raise ValueError(f"pose_sigma must hold finite sigmas >= 0, got {pose_sigma!r}")
    return sigma_xy, sigma_yaw


def carve_patch(scan: SpadScan, los: LosEstimate, cfg: NlosConfig, pose_sigma=(0.0, 0.0),
                map_walls: Optional[np.ndarray] = None) -> GridPatch:
    """:func:`carve` as a patch around the carved sectors."""
    shape = scan.grid_shape
    if len(los.wall_cells) == 0:
        return GridPatch(np.zeros((0, 0), bool), 0, 0, shape)
    sigma_xy, sigma_yaw = check_pose_sigma(pose_sigma)
    cells = cfg.in_cells(scan.resolution_m)
    strip_cells = np.full(len(los.wall_cells), cells.wall_strip)
    widened = None
    if sigma_xy > 0.0 or sigma_yaw > 0.0:
        distance = np.hypot(los.wall_cells[:, 0] + 0.5 - scan.origin_yx[0],
                            los.wall_cells[:, 1] + 0.5 - scan.origin_yx[1])
        widened = cells.normal_interior + cfg.pose_sigma_margin * (sigma_xy / scan.resolution_m
                                                                   + distance * sigma_yaw)
    cap_m = carve_radius_cap_m(scan.config.n_secondary, scan.resolution_m)
    bound = _empty_bounds(los.ray_wall, los.first_late_bin, los.empty_radius_m, len(los.wall_cells))
    normals, reliable, apex, steps = los.wall_normal, los.normal_reliable, los.wall_apex, None
    if widened is not None:
        reliable = reliable & reliable_with_interior(los.wall_cells, cfg, scan.resolution_m, widened)
    if map_walls is not None and cfg.normals_from_map:
        # Only cells whose rays leave a radius past the wall strip could carve, whatever their normal (the
        # normal's and the pose's tests in _carve_radii only shrink it): the refit is kept to those.
        could_carve = (np.minimum(bound, cap_m) / scan.resolution_m - cells.apex_margin - np.sqrt(0.5)
                       > cells.wall_strip)
        normals, reliable, apex, steps = map_supported_normals(los.wall_cells, normals, reliable, apex, scan, cfg,
                                                               map_walls, widened, could_carve)
    radius_cells = _carve_radii(bound, los.wall_cells, normals, reliable, scan.origin_yx[0], scan.origin_yx[1],
                                cap_m, scan.resolution_m, cells.apex_margin,
                                np.cos(np.deg2rad(cfg.max_incidence_deg)), cells.wall_strip, cfg.pose_sigma_margin * sigma_xy / scan.resolution_m,
                                cfg.pose_sigma_margin * sigma_yaw, strip_cells)
    top, left, bottom, right = _carved_box(apex, radius_cells, strip_cells, shape[0], shape[1])
    carved = np.zeros((bottom - top, right - left), bool)
    cos_limit = sector_cos_limits(los.wall_cells, normals, cfg, cfg.pose_sigma_margin * sigma_yaw, steps)
    carve_sectors(apex, normals, radius_cells, strip_cells, cos_limit, top, left, carved, kernel_parts(cfg.threads))
    return GridPatch(carved, int(top), int(left), shape)


def carve(scan: SpadScan, los: LosEstimate, cfg: NlosConfig = NlosConfig(), pose_sigma=(0.0, 0.0),
          map_walls: Optional[np.ndarray] = None) -> np.ndarray:
    """Cells proven free by the first late photons: bool ``[H, W]`` (see the module docstring for soundness).

    ``pose_sigma``: ``(sigma_xy_m, sigma_yaw_rad)`` of the pose the scan was placed by (point 4 above); zeros for
    an exact pose. ``map_walls``: bool ``[H, W]`` the wall cells the map already holds, on the scan's grid; with
    ``cfg.normals_from_map`` each wall point's normal is fitted to the scan's hits and these together (point 3
    above, :func:`.normals.map_supported_normals`); None: the scan's hits alone."""
    return carve_patch(scan, los, cfg, pose_sigma, map_walls).to_grid()
