"""NLOS processing of SPAD histograms: LOS peaks, space carving and back-projection.

Everything here works from what a real sensor gives: the histograms, the ray angles, the robot pose, the bin
width and the sensor's own configuration. Only the detections are read (bins whose count exceeds the detection
threshold: every non-zero bin without noise), as :class:`~superex_deploy.spad_types.SparseHistograms`: the simulator's
noise-free scans come in that form, dense (noisy) histograms are read once to extract them. The simulator's
ground truth (``scan.truth``) is never read here: the labels come from
:func:`superex_deploy.sim.spad.nlos_ground_truth`.

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
   return then overstates the empty radius. The carve radius is therefore capped at ``rho_max``.
2. **Where the wall point is.** The processing knows ``h1`` only from the direct-return bin: its estimate can
   be one cell off, and the simulator's fans start at ``X1`` on the cell's face. The radius is reduced by
   ``apex_margin_cells`` plus ``s / sqrt(2)`` (a cell counts as a wall when any part of it is hit, and we test
   cell centres).
3. **Which side.** The fan spans +-90 degrees about the true normal, the carve uses a normal estimated from the
   scan's own wall hits; the carved sector is narrowed to +-(90 - sector_margin_deg) and a strip of
   ``wall_strip_cells`` along the wall itself is left out (it is seen directly anyway). A normal is trusted
   only where the hits around the wall cell lie on one straight line (small minor/major variance ratio and
   every hit within ``normal_max_residual_cells`` of the fitted line, no gap along it wider than
   ``normal_max_gap_cells``), the cell is inside that line, and
   the robot does not see it at grazing incidence; other wall cells are not carved from. The property test
   found each of these cases: three hits from two walls (a thin wall's face and a wall seen past its end)
   fitted a line tilted 25 degrees, which flipped the carved sector onto the far wall; and a wall-end cell
   whose hits ran on, across a 4-cell gap, to a second wall carved a sector the end's own fan never covered.

In noisy mode the first late bin is the first bin whose count exceeds a Poisson threshold chosen so that a
ray sees a false detection in its late part with probability at most ``false_alarm_rate`` (Bonferroni over its
late bins).

Back-projection (Velten et al., 2012)
-------------------------------------
Each late bin votes on the ring of radius ``r(b)`` (one cell wide) about the estimated wall point, on its
normal side, with its counts compensated for the ``1 / (d1 d2^2)`` fall-off and the sensor constants. Votes
are first summed per (wall cell, radius bin) over every ray that shares the wall cell; then each wall cell's
half-disc is swept once (every cell adds the summed vote of the ring it lies on), only inside a window around
the robot and only on cells not already known (runs of known cells are jumped over). The cost is about one
visit per (wall cell, unknown window cell in its half-disc), independent of the number of rays and bins.

Cost
----
The results cover a small part of the map, so :func:`process_scan` makes them as :class:`GridPatch` es (the
window, the carved sectors' box); whole maps are made only when asked for. The normals, the votes, the carving
and the ring drawing run on numba's threads (``NlosConfig.threads``), each part owning its wall cells or rows,
so the results do not depend on the thread count; the Laplacian filter is ``scipy.ndimage``'s, rewritten in
numba with the same order of operations (equal to the last bit) to skip scipy's per-call overhead and the
whole-map copies.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Optional

import numba
import numpy as np
from scipy import ndimage, stats

from superex_deploy.geometry import group_by_cell
from superex_deploy.spad_types import SpadScan, SparseHistograms

__all__ = ["NlosConfig", "LosEstimate", "GridPatch", "NlosResult", "estimate_los", "carve", "back_project",
           "laplacian_filter", "process_scan", "wall_iou", "wall_iou_tolerant",
           "carve_radius_cap_m"]


@dataclass(frozen=True)
class NlosConfig:
    """NLOS processing parameters.

    Attributes:
        window_m: back-projection is computed within this distance of the robot (square window, metres).
        apex_margin_cells: carve-radius reduction for the wall point's estimate (cells).
        sector_margin_deg: the carved half-disc is narrowed to +-(90 - this) degrees about the normal.
        wall_strip_cells: cells within this distance of the wall's own line are never carved.
        false_alarm_rate: noisy mode: probability that a ray's late part holds a false detection.
        normal_radius_cells: observed wall hits within this radius of a wall cell estimate its normal.
        normal_max_minor_ratio: a normal is trusted for carving only if the hits' minor/major variance ratio is
            below this (the hits lie on a line, not around a corner).
        normal_max_residual_cells: ... and only if every one of those hits lies within this distance of the
            fitted line (the cells a straight wall face exposes have centres within sqrt(2)/2 of it; a larger
            residual means hits from two walls, e.g. a thin wall's face and a wall seen past its end, whose
            fitted line and normal can be tilted far enough to put the carved sector on the far side).
        normal_max_gap_cells: ... and only if consecutive hits along that line are at most this far apart (a
            wider gap can be a wall end followed by another wall, and the end's true normal turns away; the
            property test found a wall-end cell whose line ran on to a second wall 4 cells away).
        normal_interior_cells: ... and only if observed hits extend at least this far on both sides of the
            cell along the wall (wall ends and corners carry normals of their own; the margin also covers a
            wall-cell estimate one cell off).
        max_incidence_deg: wall points seen more obliquely than this are not carved: at grazing incidence a
            small error in the estimated normal flips which side of the wall faces the robot.
        threads: the parallel kernels (wall normals, votes, carving, the back-projection's rings) split their
            work into this many parts (0: numba's thread count, ``NUMBA_NUM_THREADS`` or
            ``numba.set_num_threads``; 1: sequential). Every part owns its outputs (wall cells, rows), so the
            result does not depend on it.
    """

    window_m: float = 8.0
    apex_margin_cells: float = 1.5
    sector_margin_deg: float = 35.0
    wall_strip_cells: float = 1.5
    false_alarm_rate: float = 1e-3
    normal_radius_cells: float = 5.0
    normal_max_minor_ratio: float = 0.1
    normal_max_residual_cells: float = 0.9
    normal_max_gap_cells: float = 2.0
    normal_interior_cells: float = 2.5
    max_incidence_deg: float = 70.0
    threads: int = 0

    def __post_init__(self) -> None:
        for name in ("window_m", "apex_margin_cells", "wall_strip_cells"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"NlosConfig.{name} must be finite and >= 0, got {value}")
        if not 0.0 <= self.sector_margin_deg < 90.0:
            raise ValueError(f"NlosConfig.sector_margin_deg must lie in [0, 90), got {self.sector_margin_deg}")
        if not 0.0 < self.false_alarm_rate < 1.0:
            raise ValueError(f"NlosConfig.false_alarm_rate must lie in (0, 1), got {self.false_alarm_rate}")
        if not 0.0 < self.max_incidence_deg <= 90.0:
            raise ValueError(f"NlosConfig.max_incidence_deg must lie in (0, 90], got {self.max_incidence_deg}")
        if not self.normal_max_gap_cells >= 1.0:
            raise ValueError(f"NlosConfig.normal_max_gap_cells must be >= 1, got {self.normal_max_gap_cells}")
        if not self.normal_max_residual_cells > 0.0:
            raise ValueError(f"NlosConfig.normal_max_residual_cells must be > 0, got {self.normal_max_residual_cells}")
        if int(self.threads) != self.threads or self.threads < 0:
            raise ValueError(f"NlosConfig.threads must be an integer >= 0, got {self.threads}")
        if not self.normal_radius_cells >= 1.5:
            raise ValueError(f"NlosConfig.normal_radius_cells must be >= 1.5, got {self.normal_radius_cells}")


@dataclass(frozen=True)
class LosEstimate:
    """Per-ray estimates from the histograms.

    Attributes:
        los_bin: int64 ``[n_rays]`` bin of the direct return, -1 where none was detected.
        d1_m: float64 ``[n_rays]`` distance to the wall point (bin centre; NaN where none).
        h1_rc: int64 ``[n_rays, 2]`` estimated wall cell (-1 where none).
        first_late_bin: int64 ``[n_rays]`` first detected late bin, -1 where the late part is empty.
        empty_radius_m: float64 ``[n_rays]`` lower bound on the distance from the wall point to any sampled
            hidden surface (``(bf - b1 - 1) w / 2``; the secondary range where the late part is empty; NaN where
            there is no direct return).
        wall_cells: int64 ``[U, 2]`` distinct estimated wall cells; ``ray_wall[i]`` indexes them (-1: none).
        wall_normal: float64 ``[U, 2]`` unit normal (dy, dx) at each wall cell, facing the robot.
        wall_apex: float64 ``[U, 2]`` each wall cell's fan origin X1 (cells, (y, x)): where its normal through the
            cell centre leaves the cell; the carved sectors and the back-projected rings are centred there.
        normal_reliable: bool ``[U]`` normals backed by enough elongated wall hits (only these are carved).
        late_threshold: detection threshold on late-bin counts (0 in noise-free mode: any photon).
        detections: the bins whose count exceeds ``late_threshold``, every ray's (what the estimates and the
            back-projection read).
    """

    los_bin: np.ndarray
    d1_m: np.ndarray
    h1_rc: np.ndarray
    first_late_bin: np.ndarray
    empty_radius_m: np.ndarray
    wall_cells: np.ndarray
    ray_wall: np.ndarray
    wall_normal: np.ndarray
    wall_apex: np.ndarray
    normal_reliable: np.ndarray
    late_threshold: float
    detections: SparseHistograms


@dataclass(frozen=True, eq=False)
class GridPatch:
    """A rectangle of a grid's cells, ``grid[top:top + h, left:left + w]``; every other cell of the grid is zero
    (False). The NLOS results cover a small part of the map (the back-projection window, the carved sectors), so
    they are made and kept as patches; :meth:`to_grid` gives the whole map.

    Attributes:
        values: ``[h, w]`` array (``h`` or ``w`` may be 0).
        top, left: grid row and column of ``values[0, 0]``.
        grid_shape: ``(rows, cols)`` of the whole grid.
    """

    values: np.ndarray
    top: int
    left: int
    grid_shape: tuple[int, int]

    @property
    def slices(self) -> tuple[slice, slice]:
        """The patch's rows and columns in the grid: ``grid[patch.slices]`` is the patch's area."""
        height, width = self.values.shape
        return slice(self.top, self.top + height), slice(self.left, self.left + width)

    def to_grid(self) -> np.ndarray:
        """The whole grid, ``grid_shape``, of the values' dtype, zero outside the patch."""
        grid = np.zeros(self.grid_shape, self.values.dtype)
        grid[self.slices] = self.values
        return grid


@dataclass(frozen=True, eq=False)
class NlosResult:
    """Output of :func:`process_scan`.

    Attributes:
        carved_patch: bool cells proven free (a :class:`GridPatch` around the carved sectors).
        bp_patch: float32 back-projection in [0, 1] (a :class:`GridPatch` of the back-projection window).
        bp_filtered_patch: float32 Laplacian-filtered back-projection in [0, 1] (the window and a margin).
        los: the per-ray :class:`LosEstimate`.
    """

    carved_patch: GridPatch
    bp_patch: GridPatch
    bp_filtered_patch: GridPatch
    los: LosEstimate

    @cached_property
    def carved(self) -> np.ndarray:
        """bool ``[H, W]`` cells proven free."""
        return self.carved_patch.to_grid()

    @cached_property
    def bp(self) -> np.ndarray:
        """float32 ``[H, W]`` back-projection, in [0, 1]."""
        return self.bp_patch.to_grid()

    @cached_property
    def bp_filtered(self) -> np.ndarray:
        """float32 ``[H, W]`` Laplacian-filtered back-projection, in [0, 1]."""
        return self.bp_filtered_patch.to_grid()


def carve_radius_cap_m(n_secondary: int, resolution_m: float) -> float:
    """Largest radius (metres) within which ``n_secondary`` rays over 180 degrees must cross every cell."""
    return resolution_m * n_secondary / np.pi


def _check_scan(scan: SpadScan) -> None:
    if not isinstance(scan, SpadScan):
        raise ValueError(f"scan must be a SpadScan, got {type(scan).__name__}")
    stored = scan.stored
    if isinstance(stored, SparseHistograms):
        shape = (stored.n_rays, stored.n_bins)
        ok = (stored.counts.dtype == np.float32 and stored.bins.dtype == np.int32
              and stored.bins.shape == stored.counts.shape and stored.row_start.shape == (shape[0] + 1,))
        dtype = stored.counts.dtype
    else:
        shape, dtype = np.shape(stored), getattr(stored, "dtype", None)
        ok = dtype == np.float32 and len(shape) == 2
    if not ok or shape[0] != scan.angles.shape[0]:
        raise ValueError(f"scan histograms must be float32 [n_rays, n_bins] matching the angles, got {dtype} "
                         f"{shape}")


def _thread_parts(cfg: NlosConfig) -> int:
    """How many parts the parallel kernels split their work into (``cfg.threads``, 0: numba's threads)."""
    return int(cfg.threads) or numba.get_num_threads()


def _detections(scan: SpadScan, threshold: float) -> SparseHistograms:
    """The bins of every ray whose count exceeds ``threshold`` (no copy for a sparse scan at threshold 0)."""
    if scan.is_sparse and threshold == 0.0:
        return scan.sparse
    return SparseHistograms.from_dense(scan.histograms, threshold)


def _late_threshold(scan: SpadScan, cfg: NlosConfig, n_late_bins: int) -> tuple[float, int]:
    """(count threshold, guard bins after the direct peak)."""
    noise = scan.config.noise
    if not noise.enabled:
        return 0.0, 1
    background = noise.background_per_bin
    per_bin = cfg.false_alarm_rate / max(n_late_bins, 1)
    # Smallest k with P(Poisson(background) >= k) <= per_bin; a detection is a count >= k.
    threshold = float(stats.poisson.isf(per_bin, background)) + 1.0 if background > 0 else 1.0
    jitter_bins = noise.jitter_s / scan.config.bin_width_s
    return threshold - 0.5, 1 + int(np.ceil(4.0 * jitter_bins))


@numba.njit(cache=True)
def _los_and_first_late_bins(row_start, bins, counts, threshold, guard, los_bin, first_late):
    """Per ray of the sparse histograms ``(row_start, bins, counts)``: ``los_bin`` the strongest of the
    ``guard`` bins from the first bin whose count exceeds ``threshold`` (ties: the earliest), ``first_late``
    the first bin from ``los_bin + guard`` on exceeding it; -1 where there is none. Bins at or below the
    threshold never matter (the strongest bin near a detection is a detection), so absent bins are zeros."""
    for i in range(row_start.shape[0] - 1):
        los_bin[i] = -1
        first_late[i] = -1
        j = row_start[i]
        end = row_start[i + 1]
        while j < end and not counts[j] > threshold:
            j += 1
        if j == end:
            continue
        first = bins[j]
        peak = j
        j += 1
        while j < end and bins[j] < first + guard:
            if counts[j] > counts[peak]:
                peak = j
            j += 1
        los_bin[i] = bins[peak]
        j = peak + 1
        while j < end:
            if bins[j] >= bins[peak] + guard and counts[j] > threshold:
                first_late[i] = bins[j]
                break
            j += 1


@numba.njit(cache=True)
def _wall_points_of_rays(los_bin, first_late, angles, origin_y, origin_x, bin_path_m, resolution_m, n_rows, n_cols,
                         secondary_range_m, d1_m, h1_rc, empty_radius_m):
    """Per ray, from its direct bin ``los_bin`` and first late bin ``first_late``: ``d1_m`` the distance to the
    wall point (bin centre, metres), ``h1_rc`` the wall cell (the cell a third of a cell past ``d1`` along the ray)
    and ``empty_radius_m`` ``(bf - b1 - 1) w / 2`` clipped to ``[0, secondary_range_m]`` (the whole range where
    the late part is empty). A ray without a direct return, or whose wall cell falls outside the grid, gets NaN,
    -1 and NaN, and its ``los_bin`` and ``first_late`` are set to -1."""
    for i in range(los_bin.shape[0]):
        d1_m[i] = np.nan
        h1_rc[i, 0] = -1
        h1_rc[i, 1] = -1
        empty_radius_m[i] = np.nan
        if los_bin[i] < 0:
            continue
        d1 = (los_bin[i] + 0.5) * bin_path_m / 2.0
        # A point a third of a cell past the estimated distance lies inside the wall cell the ray entered.
        reach_cells = d1 / resolution_m + 0.3
        row = np.floor(origin_y + reach_cells * np.sin(angles[i]))
        col = np.floor(origin_x + reach_cells * np.cos(angles[i]))
        if not (0.0 <= row < n_rows and 0.0 <= col < n_cols):
            los_bin[i] = -1
            first_late[i] = -1
            continue
        d1_m[i] = d1
        h1_rc[i, 0] = np.int64(row)
        h1_rc[i, 1] = np.int64(col)
        radius = (first_late[i] - los_bin[i] - 1) * bin_path_m / 2.0 if first_late[i] >= 0 else secondary_range_m
        empty_radius_m[i] = min(max(radius, 0.0), secondary_range_m)


def estimate_los(scan: SpadScan, cfg: NlosConfig = NlosConfig()) -> LosEstimate:
    """Direct returns, wall points and their normals, and the first late bin of every ray."""
    _check_scan(scan)
    res, w = scan.resolution_m, scan.bin_path_m
    n_rays, n_bins = scan.angles.shape[0], scan.n_bins
    threshold, guard = _late_threshold(scan, cfg, n_bins)
    detections = _detections(scan, threshold)
    # The direct return is the earliest detection, not the strongest bin: a fan starting in a corner returns
    # all its rays at one tiny d2, and together they can outshine the direct photons. Timing jitter spreads the
    # direct peak over the guard bins, so with noise the peak is the strongest bin within them.
    los_bin = np.empty(n_rays, np.int64)
    first_late = np.empty(n_rays, np.int64)
    _los_and_first_late_bins(detections.row_start, detections.bins, detections.counts, threshold, guard, los_bin,
                             first_late)
    d1 = np.empty(n_rays)
    h1 = np.empty((n_rays, 2), np.int64)
    empty_radius = np.empty(n_rays)
    _wall_points_of_rays(los_bin, first_late, scan.angles, scan.origin_yx[0], scan.origin_yx[1], w, res,
                         scan.grid_shape[0], scan.grid_shape[1], scan.config.range_m, d1, h1, empty_radius)
    ray_wall, wall_cells, _ = group_by_cell(h1, scan.grid_shape[1])
    wall_normal, normal_reliable, wall_apex = _observed_normals(wall_cells, scan, cfg)
    return LosEstimate(los_bin=los_bin, d1_m=d1, h1_rc=h1, first_late_bin=first_late,
                       empty_radius_m=empty_radius, wall_cells=wall_cells, ray_wall=ray_wall,
                       wall_normal=wall_normal, wall_apex=wall_apex, normal_reliable=normal_reliable,
                       late_threshold=threshold, detections=detections)


@numba.njit(cache=True, parallel=True)
def _hit_normals(points, radius, max_minor_ratio, max_residual, max_gap, interior, normals, reliable, n_parts):
    """Minor principal axis of the points within ``radius`` of each point (itself included); ``reliable`` where
    there are at least 3 such points, the minor variance is below ``max_minor_ratio`` of the major one, every
    point lies within ``max_residual`` of the fitted line, no two neighbours along it are more than ``max_gap``
    apart, and the point lies at least ``interior`` cells inside the extent of its neighbours along the wall.

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
    """:func:`_hit_normals` of the points ``first .. stop - 1``."""
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
        half_trace = 0.5 * (cyy + cxx)
        spread = np.sqrt(0.25 * (cyy - cxx) ** 2 + cxy * cxy)
        major = half_trace + spread
        minor = half_trace - spread
        if major <= 0.0 or minor > max_minor_ratio * major:
            continue
        vy1, vx1 = minor - cxx, cxy
        vy2, vx2 = cxy, minor - cyy
        if vy1 * vy1 + vx1 * vx1 >= vy2 * vy2 + vx2 * vx2:
            vy, vx = vy1, vx1
        else:
            vy, vx = vy2, vx2
        norm = np.sqrt(vy * vy + vx * vx)
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
        reliable[u] = straight and contiguous and along[0] <= -interior and along[count - 1] >= interior


@numba.njit(cache=True)
def _face_the_robot(points, origin_y, origin_x, normals, reliable, apex):
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


def _observed_normals(wall_cells: np.ndarray, scan: SpadScan, cfg: NlosConfig
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normals from the scan's own wall hits: the minor principal axis of the hits within
    ``normal_radius_cells`` of each wall cell, facing the robot.

    Returns ``(normals float64 [U, 2], reliable bool [U], apex float64 [U, 2])`` (apex: the fan origin X1, see
    :attr:`LosEstimate.wall_apex`). A normal is reliable when at least three hits
    with a clearly linear spread (minor/major variance below ``normal_max_minor_ratio``, every hit within
    ``normal_max_residual_cells`` of the line, no gap along it wider than ``normal_max_gap_cells``) support it
    and the cell lies inside that line (``normal_interior_cells`` from its observed ends); elsewhere (corners,
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
    _hit_normals(points, float(cfg.normal_radius_cells), cfg.normal_max_minor_ratio,
                 cfg.normal_max_residual_cells, cfg.normal_max_gap_cells, cfg.normal_interior_cells, normals,
                 reliable, _thread_parts(cfg))
    _face_the_robot(points, scan.origin_yx[0], scan.origin_yx[1], normals, reliable, apex)
    return normals, reliable, apex


RING_PAD = 3
"""Zero columns past the last radius in the vote table: a cell a little beyond a wall point's outermost ring, or
behind its wall, reads one of them instead of being trimmed away (see :func:`_sweep_rings`)."""
ROW_BLOCK = 8
"""Rows of the back-projection window and of the carved patch are dealt to the threads in blocks of this many."""


@numba.njit(cache=True, parallel=True)
def _carve_sectors(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, n_parts):
    """Mark cells whose centre lies within ``radius_cells[u]`` of ``apex[u]``, at least ``strip_cells`` in front
    of the wall line, and within the sector ``cos(angle to the normal) >= cos_limit`` seen from a vertex 0.75
    cells in front of the apex (a scattering model may start its fan off the surface, as the simulator does;
    a vertex moved forward only narrows the sector, so the choice errs on the safe side). ``out`` bool
    ``[h, w]`` holds grid rows ``top..top + h - 1`` and columns ``left..left + w - 1``; cells outside it are not
    marked. Blocks of :data:`ROW_BLOCK` rows of ``out`` are dealt round-robin to ``n_parts`` parts marked in
    parallel."""
    for part in numba.prange(n_parts):
        _carve_sector_rows(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, part, n_parts)


@numba.njit(cache=True)
def _carve_sector_rows(apex, normals, radius_cells, strip_cells, cos_limit, top, left, out, part, n_parts):
    """:func:`_carve_sectors` in the rows of ``out`` that belong to ``part``."""
    row_end = top + out.shape[0]
    col_end = left + out.shape[1]
    for u in range(apex.shape[0]):
        radius = radius_cells[u]
        if not radius > strip_cells:
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
                lo = max(lo, ax - 0.5 + (strip_cells - vy * ny) / nx)
            elif nx < -1e-9:
                hi = min(hi, ax - 0.5 + (strip_cells - vy * ny) / nx)
            elif vy * ny + (span + 2.0) * abs(nx) < strip_cells:
                continue
            if lo > hi + 2.0:
                continue
            c_first = max(left, int(np.floor(max(lo, left - 2.0))) - 1)
            c_last = min(col_end - 1, int(np.ceil(min(hi, col_end + 1.0))) + 1)
            for c in range(c_first, c_last + 1):
                vx = c + 0.5 - ax
                if vy * vy + vx * vx >= radius * radius:
                    continue
                if vy * ny + vx * nx < strip_cells:
                    continue
                wy = r + 0.5 - oy
                wx = c + 0.5 - ox
                norm = np.sqrt(wy * wy + wx * wx)
                if norm == 0.0 or (wy * ny + wx * nx) / norm >= cos_limit:
                    out[r - top, c - left] = True


@numba.njit(cache=True)
def _carve_radii(ray_wall, first_late, empty_radius_m, wall_cells, wall_normal, reliable, origin_y, origin_x,
                 cap_m, resolution_m, apex_margin_cells, cos_max_incidence):
    """Carve radius (cells) of each wall cell: the smallest empty radius of the rays that share it (rays sharing
    a wall-cell estimate may come from different true wall points), capped at ``cap_m`` and reduced by
    ``apex_margin_cells`` and half a cell diagonal; zero for a wall cell with a ray that saw no late photon (at
    grazing incidence no three-bounce light exists however empty the space is), without a ``reliable`` normal,
    or seen more obliquely than ``cos_max_incidence``."""
    n_walls = wall_cells.shape[0]
    bound = np.full(n_walls, np.inf)
    for i in range(ray_wall.shape[0]):
        u = ray_wall[i]
        if u < 0:
            continue
        radius = 0.0 if first_late[i] < 0 else empty_radius_m[i]
        bound[u] = min(bound[u], radius)
    radius_cells = np.zeros(n_walls)
    for u in range(n_walls):
        if not reliable[u]:
            continue
        ty = origin_y - (wall_cells[u, 0] + 0.5)
        tx = origin_x - (wall_cells[u, 1] + 0.5)
        norm = max(np.sqrt(ty * ty + tx * tx), 1e-12)
        if wall_normal[u, 0] * (ty / norm) + wall_normal[u, 1] * (tx / norm) < cos_max_incidence:
            continue
        radius_cells[u] = min(bound[u], cap_m) / resolution_m - apex_margin_cells - np.sqrt(0.5)
    return radius_cells


@numba.njit(cache=True)
def _carved_box(apex, radius_cells, strip_cells, n_rows, n_cols):
    """Rows ``top:bottom`` and columns ``left:right`` of the grid holding the discs of every wall point that
    carves (``radius_cells > strip_cells``): every carved cell lies inside. All zero when none carves."""
    top, left, bottom, right = n_rows, n_cols, 0, 0
    for u in range(apex.shape[0]):
        radius = radius_cells[u]
        if not radius > strip_cells:
            continue
        top = min(top, max(int(np.floor(apex[u, 0] - radius)), 0))
        left = min(left, max(int(np.floor(apex[u, 1] - radius)), 0))
        bottom = max(bottom, min(int(np.ceil(apex[u, 0] + radius)) + 1, n_rows))
        right = max(right, min(int(np.ceil(apex[u, 1] + radius)) + 1, n_cols))
    if bottom <= top or right <= left:
        return 0, 0, 0, 0
    return top, left, bottom, right


def _carved_patch(scan: SpadScan, los: LosEstimate, cfg: NlosConfig) -> GridPatch:
    """:func:`carve` as a patch around the carved sectors."""
    shape = scan.grid_shape
    if len(los.wall_cells) == 0:
        return GridPatch(np.zeros((0, 0), bool), 0, 0, shape)
    radius_cells = _carve_radii(los.ray_wall, los.first_late_bin, los.empty_radius_m, los.wall_cells,
                                los.wall_normal, los.normal_reliable, scan.origin_yx[0], scan.origin_yx[1],
                                carve_radius_cap_m(scan.config.n_secondary, scan.resolution_m), scan.resolution_m,
                                cfg.apex_margin_cells, np.cos(np.deg2rad(cfg.max_incidence_deg)))
    top, left, bottom, right = _carved_box(los.wall_apex, radius_cells, cfg.wall_strip_cells, shape[0], shape[1])
    carved = np.zeros((bottom - top, right - left), bool)
    cos_limit = np.cos(np.deg2rad(90.0 - cfg.sector_margin_deg))
    _carve_sectors(los.wall_apex, los.wall_normal, radius_cells, cfg.wall_strip_cells, cos_limit, top, left, carved,
                   _thread_parts(cfg))
    return GridPatch(carved, int(top), int(left), shape)


def carve(scan: SpadScan, los: LosEstimate, cfg: NlosConfig = NlosConfig()) -> np.ndarray:
    """Cells proven free by the first late photons: bool ``[H, W]`` (see the module docstring for soundness)."""
    return _carved_patch(scan, los, cfg).to_grid()


@numba.njit(cache=True, parallel=True)
def _accumulate_votes(row_start, bins, counts, los_bin, ray_wall, d1_m, first_bin_offset, threshold, background,
                      bin_path_m, resolution_m, votes, q_max, n_parts):
    """``votes[u, q]``: compensated counts of the late bins whose radius ``d2 = (b - b1) w / 2`` rounds to ``q``
    cells, summed over the rays of wall cell ``u`` (added into ``votes``, float64 ``[n_walls, n_radii + pad]``;
    columns from ``n_radii`` on are never written), read from the sparse histograms ``(row_start, bins, counts)``
    (bins increasing within a ray). ``q_max[u]`` (int64, -1 to start with) is raised to the largest ``q`` that
    received a vote.

    ``d2`` and ``q`` depend only on the bin offset ``b - b1``: they are tabulated once (the same float
    operations, so the same values) instead of dividing per detection."""
    n_radii = votes.shape[1] - RING_PAD
    n_offsets = 0
    for i in range(row_start.shape[0] - 1):
        if ray_wall[i] >= 0 and row_start[i + 1] > row_start[i]:
            n_offsets = max(n_offsets, bins[row_start[i + 1] - 1] - los_bin[i] + 1)
    radius_of_offset = np.empty(n_offsets, np.int64)
    d2_of_offset = np.empty(n_offsets)
    for k in range(n_offsets):
        d2 = k * bin_path_m / 2.0
        d2_of_offset[k] = d2
        radius_of_offset[k] = int(np.floor(d2 / resolution_m + 0.5))
    # Wall cells are dealt round-robin to the parts: each vote is summed by one part, over its rays in order, so
    # the result does not depend on the split.
    for part in numba.prange(n_parts):
        for i in range(row_start.shape[0] - 1):
            u = ray_wall[i]
            if u < 0 or u % n_parts != part:
                continue
            b1 = los_bin[i]
            d1 = d1_m[i]
            last = -1
            for j in range(row_start[i], row_start[i + 1]):
                offset = bins[j] - b1
                count = counts[j]
                if offset < first_bin_offset or count <= threshold:
                    continue
                q = radius_of_offset[offset]
                if q >= n_radii:
                    break  # q grows with b: the rest of the ray lies beyond the largest radius
                d2 = d2_of_offset[offset]
                votes[u, q] += (count - background) * d1 * d2 * d2
                last = q
            q_max[u] = max(q_max[u], last)


@numba.njit(cache=True)
def _unknown_runs(window, known):
    """Run tables of the unknown cells of ``window`` ``(r0, r1, c0, c1)`` (inclusive) for :func:`_draw_rings`.

    Returns ``next_open`` int32 ``[rows, cols + 1]`` (first column >= ``c0 + j`` of window row ``i`` that is not
    ``known``; ``c1 + 1``: none) and ``run_end`` int32 ``[rows, cols]`` (for an unknown cell, the last column of
    its run of unknown cells; -1 for a known cell)."""
    r_lo, r_hi, c_lo, c_hi = window[0], window[1], window[2], window[3]
    width = c_hi - c_lo + 1
    next_open = np.empty((r_hi - r_lo + 1, width + 1), np.int32)
    run_end = np.empty((r_hi - r_lo + 1, width), np.int32)
    for i in range(r_hi - r_lo + 1):
        following = c_hi + 1
        end = c_hi
        next_open[i, width] = following
        for c in range(c_hi, c_lo - 1, -1):
            if known[r_lo + i, c]:
                run_end[i, c - c_lo] = -1
            else:
                if following != c + 1:
                    end = c
                following = c
                run_end[i, c - c_lo] = end
            next_open[i, c - c_lo] = following
    return next_open, run_end


@numba.njit(cache=True)
def _sweep_rings(apex, normals, votes, q_max, window, next_open, run_end, part, n_parts, out):
    """Draw every wall point's rings into the rows of ``out`` float64 ``[rows, cols]`` (the window ``(r0, r1, c0,
    c1)``, ``out[0, 0]`` at ``(r0, c0)``) that belong to ``part``: blocks of :data:`ROW_BLOCK` window rows dealt
    round-robin to ``n_parts`` parts; the body of :func:`_draw_rings`.

    ``votes`` float64 ``[n_walls, n_radii + RING_PAD]`` is zero past column ``q_max[u]`` (at least
    :data:`RING_PAD` zero columns past every ``q_max``): cells a little beyond the outermost ring, or behind the
    wall, read a zero vote instead of being trimmed away one by one."""
    r_lo, r_hi, c_lo, c_hi = window[0], window[1], window[2], window[3]
    ring = np.empty(c_hi - c_lo + 1, np.int64)
    for u in range(votes.shape[0]):
        last = q_max[u]
        if last < 0:
            continue
        behind = last + RING_PAD  # a zero column: no vote
        vote_row = votes[u]
        ay = apex[u, 0]
        ax = apex[u, 1]
        ny = normals[u, 0]
        nx = normals[u, 1]
        # In front of the wall: vy ny + (c + 0.5 - ax) nx > 0 bounds the column on one side (linear in c); the
        # bound is widened by a cell below, so its rounding does not matter.
        slope = -ny / nx if abs(nx) > 1e-9 else 0.0
        # The disc of radius q_max + 1 holds every cell of ring q_max; the column bounds below are widened by a
        # cell, so a row's interval holds at most cells of rings up to q_max + 3.
        outer = last + 1.0
        outer2 = outer * outer
        r_first = max(r_lo, int(np.floor(ay - outer)))
        r_last = min(r_hi, int(np.ceil(ay + outer)))
        if r_first > r_last:
            continue
        block = (r_first - r_lo) // ROW_BLOCK
        block += (part - block) % n_parts  # this part's first block at or after r_first
        while r_lo + block * ROW_BLOCK <= r_last:
            for r in range(max(r_first, r_lo + block * ROW_BLOCK), min(r_last, r_lo + block * ROW_BLOCK
                                                                           + ROW_BLOCK - 1) + 1):
                vy = r + 0.5 - ay
                vy2 = vy * vy
                rest = outer2 - vy2
                if rest <= 0.0:
                    continue
                span = np.sqrt(rest)
                left = ax - span - 0.5
                right = ax + span - 0.5
                if nx > 1e-9:
                    left = max(left, ax - 0.5 + vy * slope)
                elif nx < -1e-9:
                    right = min(right, ax - 0.5 + vy * slope)
                elif vy * ny + (span + 2.0) * abs(nx) <= 0.0:
                    continue  # a normal along the rows: the whole row (|vx| <= span + 2 when widened) is behind
                if right < c_lo - 1.0 or left > c_hi + 1.0 or left > right + 2.0:
                    continue
                c_first = max(c_lo, int(np.floor(max(left, c_lo - 1.0))) - 1)
                c_last = min(c_hi, int(np.ceil(min(right, c_hi + 1.0))) + 1)
                i = r - r_lo
                front = vy * ny
                c = np.int64(next_open[i, c_first - c_lo])
                while c <= c_last:
                    stop = min(np.int64(run_end[i, c - c_lo]), c_last)
                    n = stop + 1 - c
                    # Two passes over the run: the ring indices first (square roots and the exact tests, no
                    # memory dependence, so the loop vectorises), then the gather of the votes.
                    for k in range(n):
                        vx = c + k + 0.5 - ax
                        q = min(np.int64(np.sqrt(vx * vx + vy2) + 0.5), behind)
                        ring[k] = q if front + vx * nx > 0.0 else behind
                    row = out[i, c - c_lo:stop + 1 - c_lo]
                    for k in range(n):
                        row[k] += vote_row[ring[k]]
                    c = np.int64(next_open[i, stop + 1 - c_lo])
            block += n_parts


@numba.njit(cache=True, parallel=True)
def _draw_rings(apex, normals, votes, q_max, window, known, out, n_parts):
    """Add ``votes[u, q]`` to every cell on ring ``q`` of ``apex[u]``, in front of the wall (normal side), inside
    ``window`` ``(r0, r1, c0, c1)`` (inclusive) and not ``known``; ``out`` float64 ``[r1 - r0 + 1, c1 - c0 + 1]``
    holds the window (``out[0, 0]`` is cell ``(r0, c0)``). ``votes`` float64 ``[n_walls, n_radii + RING_PAD]``
    is zero past column ``q_max[u]`` (-1: no vote). A cell whose centre lies at distance ``rho`` (cells) from the
    apex is on ring ``q = floor(rho + 0.5)`` (float64 square root, rounded half up, as in ``tests/naive.py``): the
    rings are one cell wide and partition the plane.

    The votes are dense in the radius (a wall point's fan returns at most radii), so each wall point's half-disc
    is swept once, row by row, and every cell looks up its own ring, rather than tracing each ring apart. In a
    row the half-disc lies within one interval of columns, taken from the analytic bounds widened by a cell;
    the sweep jumps over runs of known cells, and within a run the exact tests (ring beyond the last vote,
    behind the wall) pick a zero vote rather than a branch, so the loop vectorises. The cost is one visit per
    unknown cell of each wall point's half-disc inside the window (about a nanosecond) plus some ten
    nanoseconds per row of each half-disc.

    The window's rows are dealt in blocks of :data:`ROW_BLOCK` to ``n_parts`` parts drawn in parallel, each into
    its own rows of ``out``: every cell still adds its votes in wall-point order, so the result does not depend
    on the split at all."""
    next_open, run_end = _unknown_runs(window, known)
    for part in numba.prange(n_parts):
        _sweep_rings(apex, normals, votes, q_max, window, next_open, run_end, part, n_parts, out)


def _window(scan: SpadScan, cfg: NlosConfig) -> np.ndarray:
    half = int(np.ceil(cfg.window_m / scan.resolution_m))
    r, c = scan.pose_rc
    return np.array([max(0, r - half), min(scan.grid_shape[0] - 1, r + half),
                     max(0, c - half), min(scan.grid_shape[1] - 1, c + half)], np.int64)


def _back_projection_patch(scan: SpadScan, los: LosEstimate, cfg: NlosConfig, known: Optional[np.ndarray]
                           ) -> GridPatch:
    """:func:`back_project` as a patch of the window."""
    shape = scan.grid_shape
    if known is None:
        known = np.zeros(shape, bool)
    known = np.asarray(known)
    if known.dtype != np.bool_ or known.shape != tuple(shape):
        raise ValueError(f"known must be a bool array of shape {tuple(shape)}, got {known.dtype} {known.shape}")
    n_bins = scan.n_bins
    n_radii = int(np.ceil(scan.config.range_m / scan.resolution_m)) + 1
    votes = np.zeros((len(los.wall_cells), n_radii + RING_PAD))
    q_max = np.full(len(los.wall_cells), -1, np.int64)
    threshold, guard = _late_threshold(scan, cfg, n_bins)
    background = scan.config.noise.background_per_bin
    n_parts = _thread_parts(cfg)
    detections = los.detections
    _accumulate_votes(detections.row_start, detections.bins, detections.counts, los.los_bin, los.ray_wall,
                      los.d1_m, guard, threshold, background, scan.bin_path_m, scan.resolution_m, votes, q_max,
                      n_parts)
    window = _window(scan, cfg)
    # Nothing is drawn outside the window: only the window is drawn into and normalised.
    drawn = np.zeros((window[1] - window[0] + 1, window[3] - window[2] + 1))
    _draw_rings(los.wall_apex, los.wall_normal, votes, q_max, window, np.ascontiguousarray(known), drawn, n_parts)
    top = drawn.max(initial=0.0)
    normalised = (drawn / top if top > 0 else drawn).astype(np.float32)
    return GridPatch(normalised, int(window[0]), int(window[2]), shape)


def back_project(scan: SpadScan, los: LosEstimate, cfg: NlosConfig = NlosConfig(),
                 known: Optional[np.ndarray] = None) -> np.ndarray:
    """Back-projection map: float32 ``[H, W]`` in [0, 1] (normalised by its maximum; all zero without votes).

    Args:
        scan, los: the scan and its :func:`estimate_los`.
        cfg: processing parameters (``window_m``).
        known: optional bool ``[H, W]`` of cells already known (skipped).
    """
    return _back_projection_patch(scan, los, cfg, known).to_grid()


@numba.njit(cache=True, inline="always")
def _reflected(i, n):
    """Index ``i`` of a line of ``n`` samples extended by reflection, ``(d c b a | a b c d | d c b a)``:
    ``scipy.ndimage``'s ``mode="reflect"``."""
    i %= 2 * n
    return i if i < n else 2 * n - 1 - i


@numba.njit(cache=True)
def _correlate_down(image, weights):
    """``scipy.ndimage.correlate1d(image, weights, axis=0, mode="reflect")`` for a symmetric odd-length float64
    filter, summed in scipy's order (the centre tap, then the pairs from the outermost in), so the two agree to
    the last bit. float64 ``[H, W]`` in and out."""
    n_rows, n_cols = image.shape
    reach = weights.shape[0] // 2
    out = np.empty_like(image)
    for r in range(n_rows):
        for c in range(n_cols):
            out[r, c] = image[r, c] * weights[reach]
        for j in range(reach, 0, -1):
            above = image[_reflected(r - j, n_rows)]
            below = image[_reflected(r + j, n_rows)]
            w = weights[reach - j]
            for c in range(n_cols):
                out[r, c] += (above[c] + below[c]) * w
    return out


@numba.njit(cache=True)
def _correlate_symmetric(image, weights, axis):
    """:func:`_correlate_down` along ``axis`` (0 or 1)."""
    if axis == 0:
        return _correlate_down(image, weights)
    # Along the rows the shifted reads defeat numba's vectoriser (5x slower): filter the transpose instead.
    return np.ascontiguousarray(_correlate_down(np.ascontiguousarray(image.T), weights).T)


@numba.njit(cache=True, inline="always")
def _negative_laplacian_at(up, mid, down, left, right):
    """``-(second difference down + second difference across)`` in scipy.ndimage.laplace's order of operations
    (each correlate1d with [1, -2, 1]: the centre tap, then the pair)."""
    return -((mid * -2.0 + (up + down) * 1.0) + (mid * -2.0 + (left + right) * 1.0))


@numba.njit(cache=True)
def _clipped_negative_laplacian(smoothed):
    """``clip(-scipy.ndimage.laplace(smoothed), 0, None)`` (``mode="reflect"``), equal to the last bit, and its
    maximum (0 for an all-zero result). float64 ``[H, W]``."""
    n_rows, n_cols = smoothed.shape
    out = np.empty_like(smoothed)
    top = 0.0
    for r in range(n_rows):
        up = smoothed[_reflected(r - 1, n_rows)]
        mid = smoothed[r]
        down = smoothed[_reflected(r + 1, n_rows)]
        target = out[r]
        for c in (0, n_cols - 1):
            target[c] = max(_negative_laplacian_at(up[c], mid[c], down[c], mid[_reflected(c - 1, n_cols)],
                                                   mid[_reflected(c + 1, n_cols)]), 0.0)
        # The inner columns through views shifted by one: plain indices that vectorise.
        if n_cols > 2:
            inner = n_cols - 2
            up_in, mid_in, down_in = up[1:n_cols - 1], mid[1:n_cols - 1], down[1:n_cols - 1]
            left, right, target_in = mid[0:inner], mid[2:n_cols], target[1:n_cols - 1]
            for k in range(inner):
                target_in[k] = max(_negative_laplacian_at(up_in[k], mid_in[k], down_in[k], left[k], right[k]), 0.0)
        for c in range(n_cols):
            top = max(top, target[c])
    return out, top


@lru_cache(maxsize=8)
def _gaussian_weights(sigma_cells: float) -> np.ndarray:
    """scipy.ndimage.gaussian_filter1d's correlation weights (truncate = 4), read-only float64."""
    reach = int(4.0 * sigma_cells + 0.5)
    offsets = np.arange(-reach, reach + 1)
    weights = np.exp(-0.5 / (sigma_cells * sigma_cells) * offsets ** 2)
    weights = (weights / weights.sum())[::-1].copy()
    weights.setflags(write=False)
    return weights


def _filtered_patch(bp: GridPatch, sigma_cells: float) -> GridPatch:
    """:func:`laplacian_filter` of a map that is zero outside the patch ``bp``: only the patch, widened by a margin,
    is filtered. float32 in [0, 1]."""
    # Filter the patch plus twice the stencil reach (Gaussian truncated at 4 sigma, plus the Laplacian's one cell),
    # so the box edge's reflection only ever mirrors zeros and the result equals filtering the whole grid.
    reach = int(4.0 * sigma_cells + 0.5)
    margin = 2 * (reach + 1)
    rows, cols = bp.slices
    shape = bp.grid_shape
    r0, r1 = max(rows.start - margin, 0), min(rows.stop + margin, shape[0])
    c0, c1 = max(cols.start - margin, 0), min(cols.stop + margin, shape[1])
    box = np.zeros((r1 - r0, c1 - c0))
    box[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = bp.values
    # scipy.ndimage.gaussian_filter's steps (truncate = 4), in numba: the same kernel, axis 0 then axis 1.
    if sigma_cells > 1e-15:
        weights = _gaussian_weights(float(sigma_cells))
        box = _correlate_symmetric(_correlate_symmetric(box, weights, 0), weights, 1)
    box, top = _clipped_negative_laplacian(box)
    return GridPatch((box / top if top > 0 else box).astype(np.float32), r0, c0, shape)


def laplacian_filter(bp: np.ndarray, sigma_cells: float = 1.0) -> np.ndarray:
    """Classic filtered back-projection: negative Laplacian of the lightly smoothed map, clipped at zero and
    normalised to [0, 1]. float32 ``[H, W]``; equal to ``scipy.ndimage``'s ``gaussian_filter`` and ``laplace``
    (reflecting edges) to the last bit."""
    bp = np.asarray(bp)
    if bp.ndim != 2:
        raise ValueError(f"bp must be 2-D, got shape {bp.shape}")
    if not (np.isfinite(sigma_cells) and sigma_cells >= 0.0):
        raise ValueError(f"sigma_cells must be finite and >= 0, got {sigma_cells}")
    rows = np.flatnonzero(bp.any(axis=1))
    cols = np.flatnonzero(bp.any(axis=0))
    if len(rows) == 0:
        return np.zeros(bp.shape, np.float32)
    nonzero = GridPatch(bp[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1], int(rows[0]), int(cols[0]), bp.shape)
    return _filtered_patch(nonzero, sigma_cells).to_grid()


def process_scan(scan: SpadScan, cfg: NlosConfig = NlosConfig(), known: Optional[np.ndarray] = None) -> NlosResult:
    """LOS estimates, carved free space, back-projection and its Laplacian-filtered version (as patches; the
    result's ``carved``, ``bp`` and ``bp_filtered`` give whole maps)."""
    los = estimate_los(scan, cfg)
    bp = _back_projection_patch(scan, los, cfg, known)
    return NlosResult(carved_patch=_carved_patch(scan, los, cfg), bp_patch=bp,
                      bp_filtered_patch=_filtered_patch(bp, 1.0), los=los)


def wall_iou(pred: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two bool wall masks of equal shape; 1.0 when both are empty."""
    pred, truth = np.asarray(pred), np.asarray(truth)
    if pred.dtype != np.bool_ or truth.dtype != np.bool_ or pred.shape != truth.shape:
        raise ValueError(f"pred and truth must be bool arrays of one shape, got {pred.dtype} {pred.shape} and "
                         f"{truth.dtype} {truth.shape}")
    union = np.count_nonzero(pred | truth)
    return 1.0 if union == 0 else np.count_nonzero(pred & truth) / union


def wall_iou_tolerant(pred: np.ndarray, truth: np.ndarray, tolerance_cells: float) -> float:
    """IoU that forgives misplacement by up to ``tolerance_cells`` (Euclidean, cell centres): a predicted cell
    counts as correct within that distance of a true one, a true cell as missed only beyond that distance of
    every prediction. ``|P & dilate(T)| / (|P| + |T - dilate(P)|)``; equals :func:`wall_iou` at tolerance 0
    and 1.0 when both masks are empty."""
    pred, truth = np.asarray(pred), np.asarray(truth)
    if pred.dtype != np.bool_ or truth.dtype != np.bool_ or pred.shape != truth.shape or pred.ndim != 2:
        raise ValueError(f"pred and truth must be 2-D bool arrays of one shape, got {pred.dtype} {pred.shape} "
                         f"and {truth.dtype} {truth.shape}")
    if not (np.isfinite(tolerance_cells) and tolerance_cells >= 0.0):
        raise ValueError(f"tolerance_cells must be finite and >= 0, got {tolerance_cells}")
    reach = int(np.floor(tolerance_cells))
    offsets = np.arange(-reach, reach + 1)
    disc = offsets[:, None] ** 2 + offsets[None, :] ** 2 <= tolerance_cells ** 2
    near_truth = ndimage.binary_dilation(truth, structure=disc)
    near_pred = ndimage.binary_dilation(pred, structure=disc)
    denominator = np.count_nonzero(pred) + np.count_nonzero(truth & ~near_pred)
    return 1.0 if denominator == 0 else np.count_nonzero(pred & near_truth) / denominator
