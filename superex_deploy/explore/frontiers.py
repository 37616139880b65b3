"""Frontier regions: free cells next to unknown ones (MapEx's frontier detection)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from superex_deploy.explore.types import FREE, UNKNOWN, Frontier

__all__ = ["find_frontiers", "frontier_cells"]

_FOUR = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], bool)
_EIGHT = np.ones((3, 3), bool)


def frontier_cells(observed: np.ndarray) -> np.ndarray:
    """bool ``[H, W]``: FREE cells with an UNKNOWN 4-neighbour (cells beyond the border are not unknown)."""
    unknown = observed == UNKNOWN
    return (observed == FREE) & ndimage.binary_dilation(unknown, structure=_FOUR)


def find_frontiers(observed: np.ndarray, min_cells: int = 10) -> tuple[Frontier, ...]:
    """Frontier regions of an observed map.

    Frontier cells are grouped 8-connected; regions under ``min_cells`` cells are dropped; each region is
    represented by its cell nearest to the region's centroid (ties: the first in row-major order). Regions come
    in row-major order of their first cell.

    Args:
        observed: int8 ``[H, W]`` (UNKNOWN / FREE / OCCUPIED).
        min_cells: smallest region kept.
    """
    observed = np.asarray(observed)
    if observed.dtype != np.int8 or observed.ndim != 2:
        raise ValueError(f"observed must be an int8 [H, W] array, got {observed.dtype} {observed.shape}")
    if min_cells < 1:
        raise ValueError(f"min_cells must be >= 1, got {min_cells}")
    labels, n_regions = ndimage.label(frontier_cells(observed), structure=_EIGHT)
    if n_regions == 0:
        return ()
    rows, cols = np.nonzero(labels)
    region = labels[rows, cols]
    order = np.argsort(region, kind="stable")
    rows, cols, region = rows[order], cols[order], region[order]
    starts = np.flatnonzero(np.r_[True, region[1:] != region[:-1]])
    ends = np.r_[starts[1:], len(region)]
    frontiers = []
    for start, end in zip(starts, ends):
        if end - start < min_cells:
            continue
        cells = np.stack([rows[start:end], cols[start:end]], axis=1).astype(np.int32)
        centroid = cells.mean(axis=0)
        nearest = int(np.argmin(((cells - centroid) ** 2).sum(axis=1)))
        frontiers.append(Frontier(cell_rc=(int(cells[nearest, 0]), int(cells[nearest, 1])), cells=cells))
    return tuple(frontiers)
