"""Visible-unknown gains of many viewpoints at once: what a goal choice scores (MapEx, IG-Hector, SuperEx).

The gains of a goal choice are computed in compiled passes over all the viewpoints at once, since scoring them
one by one made the tail of the step time: each distinct viewpoint is cast once; the polygons are filled in the
order of ``visibility._fill_visibility``, so counts and variance sums are the same additions; and the unions of
:func:`union_visible_unknown` fill each node of the trie of the groups once (groups that start alike, as the SuperEx
paths from the robot, share their first nodes; ``_trie_union_counts``). The per-viewpoint code they replace is kept
in ``tests/naive.py``, the reference of the tests (same counts, sums and goals) and of
``scripts/bench_goal_choice.py`` (measured in docs/benchmarks/realtime.md, "Goal choices"). The kernels run on one
thread: split over two numba threads (as the NLOS kernels are) they were slower on a 2-core machine, whose second
core a robot gives to the predictor.

The visibility of one viewpoint (the raycast and its polygon) is :mod:`~superex_deploy.onboard.planning.visibility`'s.
"""

from __future__ import annotations

import numba
import numpy as np

from superex_deploy.onboard.types import Prediction, check_observed
from superex_deploy.onboard.planning.visibility import (VisibilityConfig, check_cells, check_map, max_range_cells,
                                                        polygon_runs, ray_visible_ranges)

__all__ = ["visible_gains", "union_visible_unknown", "union_visible_unknown_flat"]


@numba.njit(cache=True)
def _cast_distinct(mean, cast_rows, cast_cols, n_rays, max_t, hit_threshold, accumulate):
    """float64 ``[U, n_rays]``: :func:`ray_visible_ranges` from each distinct viewpoint cell."""
    ranges = np.empty((cast_rows.shape[0], n_rays))
    for u in range(cast_rows.shape[0]):
        ray_visible_ranges(mean, cast_rows[u] + 0.5, cast_cols[u] + 0.5, n_rays, max_t, hit_threshold, accumulate,
                           ranges[u])
    return ranges


@numba.njit(cache=True)
def _viewpoint_gains(ranges, observed, variance, view_rows, view_cols, view_cast):
    """Visible-unknown count and variance sum of each viewpoint ``v`` (cell ``view_rows[v], view_cols[v]``, rays
    ``ranges[view_cast[v]]``), in one compiled pass: its polygon (:func:`polygon_runs`) is filled in the
    row-major order of ``_fill_visibility``, so counts and sums are the same additions. (Jumping over runs of
    known cells through per-row links was measured and dropped: no faster in the trie fill, slower here, where the
    views from frontier cells are mostly unknown.)

    Returns ``(counts int64 [V], variance_sums float64 [V])``."""
    n_rows, n_cols = observed.shape
    n_views = view_rows.shape[0]
    counts = np.zeros(n_views, np.int64)
    var_sums = np.zeros(n_views)
    for v in range(n_views):
        rows, firsts, lasts = polygon_runs(ranges[view_cast[v]], view_rows[v] + 0.5, view_cols[v] + 0.5, n_rows,
                                           n_cols)
        count = 0
        var_sum = 0.0
        for k in range(rows.shape[0]):
            r = rows[k]
            for c in range(firsts[k], lasts[k] + 1):
                if observed[r, c] == -1:
                    count += 1
                    var_sum += variance[r, c]
        counts[v] = count
        var_sums[v] = var_sum
    return counts, var_sums


@numba.njit(cache=True)
def _trie_union_counts(ranges, observed, node_rows, node_cols, node_cast, subtree_end):
    """Union of visible unknown cells along every root-to-node chain of a trie of viewpoints, one fill per node.

    Nodes come in preorder (a node's subtree is positions ``p`` to ``subtree_end[p]``); node ``p`` is the cell
    ``node_rows[p], node_cols[p]`` with rays ``ranges[node_cast[p]]``. Visiting the nodes in preorder, an unknown
    cell seen by node ``p`` is already counted for ``p``'s whole subtree if an earlier node whose subtree holds
    ``p`` saw it (its recorded subtree end is ``>= p``: preorder subtrees nest or are disjoint); otherwise it is
    added to positions ``p .. subtree_end[p]`` (a difference array). Returns int64 ``[N]``: for each node, the
    number of unknown cells seen from at least one node of its chain from the root."""
    n_rows, n_cols = observed.shape
    n_nodes = node_rows.shape[0]
    covered_until = np.full((n_rows, n_cols), -1, np.int32)
    difference = np.zeros(n_nodes + 1, np.int64)
    for p in range(n_nodes):
        end = subtree_end[p]
        added = 0
        rows, firsts, lasts = polygon_runs(ranges[node_cast[p]], node_rows[p] + 0.5, node_cols[p] + 0.5, n_rows,
                                           n_cols)
        for k in range(rows.shape[0]):
            r = rows[k]
            for c in range(firsts[k], lasts[k] + 1):
                if observed[r, c] == -1 and covered_until[r, c] < p:
                    covered_until[r, c] = end
                    added += 1
        difference[p] += added
        difference[end + 1] -= added
    return np.cumsum(difference[:n_nodes])


def visible_gains(prediction: Prediction, observed: np.ndarray, cells_rc, cfg: VisibilityConfig,
                  resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Information of viewpoints: the currently unknown cells predicted visible from each.

    Args:
        prediction: float32 ``[H, W]`` mean and variance.
        observed: int8 ``[H, W]`` observed map (UNKNOWN = -1).
        cells_rc: ``[N, 2]`` viewpoint cells (row, col).
        cfg, resolution_m: as in :func:`visible_ranges`.

    Returns:
        ``(unknown_count int64 [N], variance_sum float64 [N])`` over the visible unknown cells.
    """
    mean = check_map("prediction.mean", prediction.mean, np.float32)
    variance = check_map("prediction.variance", prediction.variance, np.float32, mean.shape)
    observed = np.ascontiguousarray(check_observed(observed, mean.shape))
    cells = check_cells(cells_rc, mean.shape)
    ranges, cast = _distinct_casts(mean, cells, cfg, resolution_m)
    return _viewpoint_gains(ranges, observed, variance, np.ascontiguousarray(cells[:, 0]),
                            np.ascontiguousarray(cells[:, 1]), cast)


def _distinct_casts(mean: np.ndarray, cells: np.ndarray, cfg: VisibilityConfig, resolution_m: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The rays of each distinct cell of ``cells`` (int64 ``[V, 2]``, checked), cast once: ``(ranges float64 [U,
    n_rays], cast int64 [V])``, cell ``v``'s rays being ``ranges[cast[v]]``."""
    max_t = max_range_cells(cfg, resolution_m)
    distinct, cast = np.unique(cells[:, 0] * mean.shape[1] + cells[:, 1], return_inverse=True)
    ranges = _cast_distinct(mean, distinct // mean.shape[1], distinct % mean.shape[1], cfg.n_rays, max_t,
                            float(cfg.hit_threshold), bool(cfg.accumulate))
    return ranges, cast.astype(np.int64).reshape(-1)


def _viewpoint_trie(keys: np.ndarray, group_offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The groups of viewpoints as chains of a trie (groups that start with the same viewpoints share their first
    nodes: the SuperEx paths all leave from the robot along one Dijkstra tree).

    Args:
        keys: int64 ``[V]`` a key per viewpoint (its flat cell index).
        group_offsets: int64 ``[G + 1]``.

    Returns:
        ``(node_view int64 [N], subtree_end int64 [N], group_node int64 [G])``: the nodes in preorder, each as the
        index of a viewpoint with its key, the last preorder position of its subtree, and each group's last node
        (-1 for an empty group).
    """
    node_of: dict = {}
    parents: list = []
    views: list = []
    group_node = np.full(len(group_offsets) - 1, -1, np.int64)
    for g in range(len(group_offsets) - 1):
        node = -1
        for v in range(group_offsets[g], group_offsets[g + 1]):
            key = (node, int(keys[v]))
            child = node_of.get(key)
            if child is None:
                child = node_of[key] = len(parents)
                parents.append(node)
                views.append(v)
            node = child
        group_node[g] = node
    children: list = [[] for _ in parents]
    roots = []
    for node, parent in enumerate(parents):
        (roots if parent < 0 else children[parent]).append(node)
    position = np.empty(len(parents), np.int64)
    subtree_end = np.empty(len(parents), np.int64)
    order: list = []
    stack = [(node, False) for node in reversed(roots)]
    while stack:
        node, done = stack.pop()
        if done:
            subtree_end[position[node]] = len(order) - 1
            continue
        position[node] = len(order)
        order.append(node)
        stack.append((node, True))
        stack.extend((child, False) for child in reversed(children[node]))
    node_view = np.asarray(views, np.int64)[np.asarray(order, np.int64)] if order else np.zeros(0, np.int64)
    group_node = np.where(group_node >= 0, position[np.maximum(group_node, 0)] if len(parents) else -1, -1)
    return node_view, subtree_end, group_node


def union_visible_unknown(mean: np.ndarray, observed: np.ndarray, viewpoints: list, cfg: VisibilityConfig,
                          resolution_m: float) -> np.ndarray:
    """For each group of viewpoints, the unknown cells predicted visible from at least one of them.

    Args:
        mean: float32 ``[H, W]`` predicted wall probability.
        observed: int8 ``[H, W]`` observed map (UNKNOWN = -1).
        viewpoints: ``N`` lists of viewpoint cells (row, col); a cell shared by several groups is cast once.
        cfg, resolution_m: as in :func:`visible_ranges`.

    Returns:
        int64 ``[N]``: the size of the union of each group's visible unknown cells (0 for an empty group).
    """
    sizes = [len(group) for group in viewpoints]
    cells = np.asarray([cell for group in viewpoints for cell in group], np.int64).reshape(-1, 2)
    return union_visible_unknown_flat(mean, observed, cells, np.concatenate([[0], np.cumsum(sizes)]), cfg,
                                      resolution_m)


def union_visible_unknown_flat(mean: np.ndarray, observed: np.ndarray, cells_rc, group_offsets,
                               cfg: VisibilityConfig, resolution_m: float) -> np.ndarray:
    """:func:`union_visible_unknown` with the groups as one array: group ``g`` is
    ``cells_rc[group_offsets[g]:group_offsets[g + 1]]``.

    Args:
        cells_rc: ``[V, 2]`` viewpoint cells (row, col).
        group_offsets: ``[N + 1]`` non-decreasing integers from 0 to ``V``.

    Returns:
        int64 ``[N]``, as :func:`union_visible_unknown`.
    """
    mean = check_map("mean", mean, np.float32)
    observed = np.ascontiguousarray(check_observed(observed, mean.shape))
    cells = check_cells(cells_rc, mean.shape)
    offsets = np.asarray(group_offsets, np.int64).reshape(-1)
    if len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != len(cells) or np.any(np.diff(offsets) < 0):
        raise ValueError(f"group_offsets must rise from 0 to the {len(cells)} cells, got {offsets.tolist()[:8]}")
    ranges, cast = _distinct_casts(mean, cells, cfg, resolution_m)
    node_view, subtree_end, group_node = _viewpoint_trie(cells[:, 0] * mean.shape[1] + cells[:, 1], offsets)
    per_node = _trie_union_counts(ranges, observed, cells[node_view, 0].copy(),
                                  cells[node_view, 1].copy(), cast[node_view].copy(), subtree_end)
    return np.where(group_node >= 0, per_node[np.maximum(group_node, 0)] if len(per_node) else 0, 0)
