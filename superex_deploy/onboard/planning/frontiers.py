"""Frontier regions: known-free cells next to unknown ones, grouped into regions with one goal cell each.

A frontier cell is a FREE cell with an UNKNOWN 4-neighbour (cells beyond the grid border count as neither).
Frontier cells are grouped 8-connected (a diagonal step joins a region, as in MapEx's frontier detection);
regions smaller than a minimum size are dropped (MapEx: 10 cells) because they are mostly single unknown cells
wedged between walls that no scan will ever resolve (the episode falls back on them only when no larger
region gives a goal). Each region is represented by its own cell nearest to the
region's centroid, so the goal is always a frontier cell (a centroid can lie in a wall or in the unknown).

One compiled pass finds and labels the frontier cells, vectorised reductions pick each region's goal cell, and only
kept regions become Python objects, so a whole-map call stays a few milliseconds on the largest eval map (measured
in docs/benchmarks/exploration.md). The numpy :func:`frontier_cells` is an independent second implementation
of the cell rule. ``skimage.measure.label`` (connectivity 2) on that mask gives the same regions in the same order,
but :func:`find_frontiers` built on it measured 4.7x slower on the largest eval floor at 0.05 m (8.7x at 0.1 m;
``benchmarks/skimage``): it labels the whole map where the flood fill visits only the frontier cells.
"""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.onboard.types import FREE, UNKNOWN, Frontier, check_observed

__all__ = ["frontier_cells", "find_frontiers", "frontiers_of_regions", "Pockets", "open_frontiers"]


@numba.njit(cache=True)
def _frontier_regions(observed):
    """Frontier cells in row-major order and their 8-connected region index.

    Returns ``(rows int64 [n], cols int64 [n], region int64 [n], n_regions)``; regions are numbered in the
    row-major order of their first cell. Two passes over the map find the cells, then a depth-first flood fill
    over the frontier cells alone labels them, so the cost beyond the map scan scales with the frontier, not
    the map.
    """
    n_rows, n_cols = observed.shape
    index = np.full((n_rows, n_cols), -1, np.int32)
    n = 0
    for r in range(n_rows):
        for c in range(n_cols):
            if observed[r, c] == 0 and ((r > 0 and observed[r - 1, c] == -1)
                                        or (r + 1 < n_rows and observed[r + 1, c] == -1)
                                        or (c > 0 and observed[r, c - 1] == -1)
                                        or (c + 1 < n_cols and observed[r, c + 1] == -1)):
                index[r, c] = n
                n += 1
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    for r in range(n_rows):
        for c in range(n_cols):
            k = index[r, c]
            if k >= 0:
                rows[k] = r
                cols[k] = c
    region = np.full(n, -1, np.int64)
    stack = np.empty(n, np.int64)
    n_regions = 0
    for seed in range(n):
        if region[seed] >= 0:
            continue
        region[seed] = n_regions
        stack[0] = seed
        top = 1
        while top > 0:
            top -= 1
            k = stack[top]
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    rr = rows[k] + dr
                    cc = cols[k] + dc
                    if 0 <= rr < n_rows and 0 <= cc < n_cols:
                        m = index[rr, cc]
                        if m >= 0 and region[m] < 0:
                            region[m] = n_regions
                            stack[top] = m
                            top += 1
        n_regions += 1
    return rows, cols, region, n_regions


def frontier_cells(observed: np.ndarray) -> np.ndarray:
    """Frontier mask of an observed map.

    Args:
        observed: int8 ``[H, W]`` with UNKNOWN / FREE / OCCUPIED codes.

    Returns:
        bool ``[H, W]``: FREE cells with at least one UNKNOWN 4-neighbour.
    """
    observed = check_observed(observed)
    unknown = observed == UNKNOWN
    near_unknown = np.zeros_like(unknown)
    near_unknown[1:, :] |= unknown[:-1, :]
    near_unknown[:-1, :] |= unknown[1:, :]
    near_unknown[:, 1:] |= unknown[:, :-1]
    near_unknown[:, :-1] |= unknown[:, 1:]
    return near_unknown & (observed == FREE)


def find_frontiers(observed: np.ndarray, min_cells: int = 10) -> tuple[Frontier, ...]:
    """Frontier regions of an observed map.

    Args:
        observed: int8 ``[H, W]`` with UNKNOWN / FREE / OCCUPIED codes.
        min_cells: regions with fewer cells are dropped (>= 1).

    Returns:
        The kept regions, ordered by their first cell in row-major order. Each :class:`Frontier` lists its
        cells in row-major order and has as ``cell_rc`` the region cell nearest to the region's centroid (ties:
        the first such cell in row-major order).

    Raises:
        ValueError: ``observed`` is not an int8 2-D array, or ``min_cells < 1``.
    """
    observed = check_observed(observed)
    if int(min_cells) < 1:
        raise ValueError(f"min_cells must be >= 1, got {min_cells}")
    rows, cols, region, n_regions = _frontier_regions(np.ascontiguousarray(observed))
    return frontiers_of_regions(rows, cols, region, n_regions, int(min_cells))


def frontiers_of_regions(rows: np.ndarray, cols: np.ndarray, region: np.ndarray, n_regions: int,
                         min_cells: int) -> tuple[Frontier, ...]:
    """The :class:`Frontier` of each labelled region of at least ``min_cells`` cells: ``rows``, ``cols`` the
    region cells in row-major order, ``region`` int64 their region index (``0 .. n_regions - 1``, numbered in the
    row-major order of each region's first cell); its goal cell the cell nearest the centroid (ties: row-major)."""
    if n_regions == 0:
        return ()
    sizes = np.bincount(region, minlength=n_regions)
    centroid_r = np.bincount(region, weights=rows, minlength=n_regions) / sizes
    centroid_c = np.bincount(region, weights=cols, minlength=n_regions) / sizes
    distance_sq = (rows - centroid_r[region]) ** 2 + (cols - centroid_c[region]) ** 2
    # lexsort is stable, so within a region equal distances keep row-major order.
    by_region = np.lexsort((distance_sq, region))
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    nearest = by_region[starts]
    # Cells of each region, row-major: a stable sort by region alone.
    cells_by_region = np.argsort(region, kind="stable")
    frontiers = []
    for index in np.flatnonzero(sizes >= min_cells):
        members = cells_by_region[starts[index]:starts[index] + sizes[index]]
        cells = np.stack([rows[members], cols[members]], axis=1).astype(np.int32)
        frontiers.append(Frontier(cell_rc=(int(rows[nearest[index]]), int(cols[nearest[index]])), cells=cells))
    return tuple(frontiers)


class Pockets:
    """Where a robot could enter the unknown space of a map, for :func:`open_frontiers`: an unknown cell is
    *enterable* when it lies within ``narrowest_m`` plus a cell of an unknown cell that is at least that far from
    every known cell (a disc a robot of radius ``narrowest_m`` fits in lies in the unknown there: a morphological
    opening of the unknown cells by that disc). The rest of the unknown are **slivers and pockets too narrow to
    enter**: the inside of a double wall, a wall's unseen middle column, a gap between two walls no ray reaches; on
    a 0.1 m log-odds grid of an office they come by the dozen, often joined to a large unknown region elsewhere
    through the wall's inside, so no test on whole regions can tell them.

    The distances come from two exact Euclidean distance transforms (scipy): about 20 ms for a 390 x 590 map, so an
    explorer makes one now and then (:attr:`shape` says which grid it is of).

    Attributes:
        enterable: bool ``[H, W]`` the enterable unknown cells.
        shape: the map's shape.
    """

    def __init__(self, observed: np.ndarray, narrowest_m: float, resolution_m: float):
        from scipy import ndimage

        observed = check_observed(observed)
        unknown = observed == UNKNOWN
        self.shape = observed.shape
        need = narrowest_m / resolution_m + 1.0  # cells from every known cell
        wide = ndimage.distance_transform_edt(unknown) >= need
        self.enterable = unknown & (ndimage.distance_transform_edt(~wide) <= need) if wide.any() else \
            np.zeros(self.shape, bool)


def open_frontiers(regions, pockets: Pockets) -> tuple[Frontier, ...]:
    """The frontier regions of ``regions`` one of whose cells has an unknown 4-neighbour a robot could enter
    (:class:`Pockets` of the same map, or of one a little older: a cell that has become known since counts as it
    was). The others border only slivers and pockets too narrow to enter: such a region can stay for ever and no
    viewpoint the robot can reach resolves it, so it must not keep an exploration alive. Order is kept."""
    rows, cols = pockets.shape
    kept = []
    for frontier in regions:
        r, c = frontier.cells[:, 0], frontier.cells[:, 1]
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            rr, cc = r + dr, c + dc
            inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            if pockets.enterable[rr[inside], cc[inside]].any():
                kept.append(frontier)
                break
    return tuple(kept)
