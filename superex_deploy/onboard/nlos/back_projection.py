"""NLOS processing, stage 4: back-projection of the late photons onto rings about their wall points.

Back-projection (Velten et al., 2012)
-------------------------------------
Each late bin votes on the ring of radius ``r(b)`` (one cell wide) about the estimated wall point, on its
normal side, with its counts compensated for the ``1 / (d1 d2^2)`` fall-off and the sensor constants. Votes
are first summed per (wall cell, radius bin) over every ray that shares the wall cell; then each wall cell's
half-disc is swept once (every cell adds the summed vote of the ring it lies on), only inside a window around
the robot and only on cells not already known (runs of known cells are jumped over). The cost is about one
visit per (wall cell, unknown window cell in its half-disc), independent of the number of rays and bins.
"""

from __future__ import annotations

from typing import Optional

import numba
import numpy as np

from superex_deploy.parallel import kernel_parts
from superex_deploy.onboard.nlos.shared import ROW_BLOCK, GridPatch, LosEstimate, NlosConfig
from superex_deploy.onboard.nlos.los import late_threshold
from superex_deploy.spad_types import SpadScan


RING_PAD = 3
"""Zero columns past the last radius in the vote table: a cell a little beyond a wall point's outermost ring, or
behind its wall, reads one of them instead of being trimmed away (see :func:`_sweep_rings`)."""


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


def _checked_known(scan: SpadScan, known: Optional[np.ndarray]) -> np.ndarray:
    shape = scan.grid_shape
    if known is None:
        return np.zeros(shape, bool)
    known = np.asarray(known)
    if known.dtype != np.bool_ or known.shape != tuple(shape):
        raise ValueError(f"known must be a bool array of shape {tuple(shape)}, got {known.dtype} {known.shape}")
    return np.ascontiguousarray(known)


def _n_radii(scan: SpadScan) -> int:
    return int(np.ceil(scan.config.range_m / scan.resolution_m)) + 1


def back_project_patch(scan: SpadScan, los: LosEstimate, cfg: NlosConfig, known: Optional[np.ndarray]
                       ) -> GridPatch:
    """:func:`back_project` as a patch of the window."""
    shape = scan.grid_shape
    known = _checked_known(scan, known)
    ray_wall = los.ray_wall
    window = _window(scan, cfg)
    drawn = np.zeros((window[1] - window[0] + 1, window[3] - window[2] + 1))
    if (ray_wall >= 0).any():
        n_radii = _n_radii(scan)
        votes = np.zeros((len(los.wall_cells), n_radii + RING_PAD))
        q_max = np.full(len(los.wall_cells), -1, np.int64)
        threshold, guard = late_threshold(scan, cfg, scan.n_bins)
        background = scan.config.noise.background_per_bin
        n_parts = kernel_parts(cfg.threads)
        detections = los.detections
        _accumulate_votes(detections.row_start, detections.bins, detections.counts, los.los_bin, ray_wall,
                          los.d1_m, guard, threshold, background, scan.bin_path_m, scan.resolution_m, votes, q_max,
                          n_parts)
        # Nothing is drawn outside the window: only the window is drawn into and normalised.
        _draw_rings(los.wall_apex, los.wall_normal, votes, q_max, window, known, drawn, n_parts)
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
    return back_project_patch(scan, los, cfg, known).to_grid()
