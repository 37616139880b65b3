"""The SPAD simulator's histograms: eq. (1) and eq. (2) written as sparse histograms
(:class:`~superex_deploy.spad_types.SparseHistograms`) from the primaries' hits and their fans' sorted paths.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def fill_sparse(direction, hit_fan, d1_cells, fan_normal, fan_row, path_m, gain, n_paths, resolution_m,
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
