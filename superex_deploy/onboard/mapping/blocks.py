"""The map on blocks of ``k x k`` cells, as the planning reads a map finer than its planning cell
(:mod:`superex_deploy.onboard.planning.coarse`): a block is a wall where any of its cells is, else free where any
is, unknown where none is known.

``skimage.measure.block_reduce`` with ``np.max`` (OCCUPIED > FREE > UNKNOWN) gives the same blocks (it is what
:func:`~superex_deploy.onboard.prediction.scale.pool_observed` calls), but measured 7.1x slower than this kernel on
the largest eval floor at 0.05 m (13x at 0.1 m; ``benchmarks/skimage``)."""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, check_observed

__all__ = ["coarsen_observed"]


@numba.njit(cache=True)
def _coarsen(observed, k, out):
    rows, cols = observed.shape
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            wall, free = False, False
            for i in range(r * k, min(r * k + k, rows)):
                for j in range(c * k, min(c * k + k, cols)):
                    value = observed[i, j]
                    if value == 1:  # OCCUPIED
                        wall = True
                    elif value == 0:  # FREE
                        free = True
            out[r, c] = 1 if wall else (0 if free else -1)


def coarsen_observed(observed: np.ndarray, k: int) -> np.ndarray:
    """int8 ``[ceil(H/k), ceil(W/k)]``: OCCUPIED where any cell of the block is, else FREE where any is, UNKNOWN
    where none is known (a block cut by the map's edge pools the cells it has); ``observed`` itself at ``k = 1``.

    The rule of a coarser map built from the same rays: a ray that crossed any cell of a block crossed the block,
    one that ended in it hit the block. A block seen only in part (the cells between two rays at range) is free, as
    a coarser cell would be; requiring all its cells would fray the seen area at range into unknown blocks and
    break its frontier into pieces.

    Raises:
        ValueError: not an int8 ``[H, W]`` map, ``k`` not an integer >= 1.
    """
    observed = check_observed(observed)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"the block size must be an integer >= 1, got {k!r}")
    if k == 1:
        return observed
    assert (FREE, OCCUPIED, UNKNOWN) == (0, 1, -1)  # the kernel's codes
    out = np.empty((-(-observed.shape[0] // k), -(-observed.shape[1] // k)), np.int8)
    _coarsen(np.ascontiguousarray(observed), int(k), out)
    return out
