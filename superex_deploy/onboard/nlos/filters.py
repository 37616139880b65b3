"""NLOS processing, stage 5: the classic filtered back-projection, the negative Laplacian of the lightly smoothed
back-projection (:func:`laplacian_filter`). It is ``scipy.ndimage``'s ``gaussian_filter`` and ``laplace``
rewritten in numba with the same order of operations (equal to the last bit), to skip scipy's per-call overhead
and the whole-map copies: only the back-projection's patch, widened by a margin, is filtered.
``skimage.filters.gaussian`` and ``skimage.filters.laplace`` (the negative 5-point Laplacian) on the same widened
patch give the same bits but measured 4.0x slower per scan than these kernels on the largest eval floor at 0.05 m
(4.9x at 0.1 m; ``benchmarks/skimage``).
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np

from superex_deploy.onboard.nlos.shared import GridPatch


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


def widened_box(bp: GridPatch, sigma_cells: float) -> tuple[np.ndarray, int, int]:
    """``(box float64, top row, left col)``: the patch ``bp`` on zeros, widened by twice the filter's stencil reach
    (a Gaussian of ``sigma_cells`` truncated at 4 sigma, plus the Laplacian's one cell) and cut at the grid, so
    that a filter with reflecting edges over the box only ever mirrors zeros and equals filtering the whole grid."""
    margin = 2 * (int(4.0 * sigma_cells + 0.5) + 1)
    rows, cols = bp.slices
    shape = bp.grid_shape
    r0, r1 = max(rows.start - margin, 0), min(rows.stop + margin, shape[0])
    c0, c1 = max(cols.start - margin, 0), min(cols.stop + margin, shape[1])
    box = np.zeros((r1 - r0, c1 - c0))
    box[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = bp.values
    return box, r0, c0


def laplacian_filter_patch(bp: GridPatch, sigma_cells: float) -> GridPatch:
    """:func:`laplacian_filter` of a map that is zero outside the patch ``bp``: only the patch, widened by a margin,
    is filtered. float32 in [0, 1]."""
    box, r0, c0 = widened_box(bp, sigma_cells)
    # scipy.ndimage.gaussian_filter's steps (truncate = 4), in numba: the same kernel, axis 0 then axis 1.
    if sigma_cells > 1e-15:
        weights = _gaussian_weights(float(sigma_cells))
        box = _correlate_symmetric(_correlate_symmetric(box, weights, 0), weights, 1)
    box, top = _clipped_negative_laplacian(box)
    return GridPatch((box / top if top > 0 else box).astype(np.float32), r0, c0, bp.grid_shape)


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
    return laplacian_filter_patch(nonzero, sigma_cells).to_grid()
