"""NLOS processing, stage 1: per ray, the direct (LOS) return, its wall point and the first late (three-bounce)
bin, read from the detections (the bins above the detection threshold); :func:`estimate_los` also gathers the
wall cells and their normals (:mod:`.normals`).

In noisy mode the first late bin is the first bin whose count exceeds a Poisson threshold chosen so that a
ray sees a false detection in its late part with probability at most ``false_alarm_rate`` (Bonferroni over its
late bins).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import stats

from superex_deploy.geometry import group_by_cell
from superex_deploy.onboard.nlos.shared import LosEstimate, NlosConfig, check_scan
from superex_deploy.onboard.nlos.normals import observed_normals
from superex_deploy.spad_types import SpadScan, SparseHistograms


def _detections(scan: SpadScan, threshold: float) -> SparseHistograms:
    """The bins of every ray whose count exceeds ``threshold`` (no copy for a sparse scan at threshold 0)."""
    if scan.is_sparse and threshold == 0.0:
        return scan.sparse
    return SparseHistograms.from_dense(scan.histograms, threshold)


def late_threshold(scan: SpadScan, cfg: NlosConfig, n_late_bins: int) -> tuple[float, int]:
    """``(threshold, guard)``: the count (float) a late bin must exceed to be a detection, set so that the
    background alone gives ``cfg.false_alarm_rate`` false detections per ray over ``n_late_bins`` bins (0 without
    noise: any photon), and the bins (int) after the direct peak that its timing jitter can still fill."""
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
    check_scan(scan)
    res, w = scan.resolution_m, scan.bin_path_m
    n_rays, n_bins = scan.angles.shape[0], scan.n_bins
    threshold, guard = late_threshold(scan, cfg, n_bins)
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
    wall_normal, normal_reliable, wall_apex = observed_normals(wall_cells, scan, cfg)
    return LosEstimate(los_bin=los_bin, d1_m=d1, h1_rc=h1, first_late_bin=first_late,
                       empty_radius_m=empty_radius, wall_cells=wall_cells, ray_wall=ray_wall,
                       wall_normal=wall_normal, wall_apex=wall_apex, normal_reliable=normal_reliable,
                       late_threshold=threshold, detections=detections)
