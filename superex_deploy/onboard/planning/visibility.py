"""Predicted visibility and the frontier helpers that every planner shares.

The **predicted visibility** of a viewpoint (MapEx's ``get_vis_mask`` in ``probabilistic``
mode): rays are cast on the predicted mean wall probability and stop at the first cell that blocks them; the
visible region is the polygon through the rays' end points, filled. MapEx rasterises that polygon's outline
(grown by one cell) and flood-fills inside it from the viewpoint; we fill the polygon by scanlines
(:func:`_fill_visibility`): a cell is visible when its centre lies inside, with no outline to leak through and
no seed to re-pick, at a cost proportional to the visible area. A cell blocks a ray when its own
probability reaches the hit threshold (0.8): that is what MapEx's ``get_free_points(use_prob=True)`` computes,
since it resets its "accumulated" probability at every cell. The accumulated rule that MapEx's paper describes,
``1 - prod(1 - p_i) >= threshold``, is available as ``VisibilityConfig(accumulate=True)``.

The gains of many viewpoints (:func:`visible_gains`, :func:`union_visible_unknown`) live in
:mod:`~superex_deploy.onboard.planning.viewpoint_gains`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.types import UNKNOWN, Frontier, PlanningContext, check_observed
from superex_deploy.geometry import dda_start, dda_step

__all__ = ["MAX_RAYS", "VisibilityConfig", "visible_ranges", "predicted_visibility", "connected_unknown_gains",
           "reachable_frontiers", "best_frontier", "check_map", "check_cells"]


_NO_STAMP = np.zeros((1, 1), np.int32)  # the stamp of calls that count every visible unknown cell

MAX_RAYS = 100_000
"""The most rays a visibility cast takes (0.06 mm apart at 20 m): its arrays grow with them."""


@dataclass(frozen=True)
class VisibilityConfig(JsonConfig):
    """Predicted-visibility raycast (MapEx ``pred_vis_configs`` and ``hit_prob_threshold``).

    Attributes:
        n_rays: rays over a full turn from each viewpoint (MapEx: 250).
        range_m: ray range in metres (MapEx: 20).
        hit_threshold: probability at which a cell blocks a ray (MapEx: 0.8), in (0, 1].
        accumulate: False: a cell blocks when its own wall probability reaches the threshold (MapEx as run).
            True: when the accumulated blocking probability ``1 - prod(1 - p_i)`` along the ray, the viewpoint's
            cell included, reaches it (MapEx as described in its paper).

    Raises:
        ValueError: a field of another type or out of its range, named: ``n_rays`` an integer in ``[3,``
            :data:`MAX_RAYS` ``]``, ``range_m`` positive and finite, ``hit_threshold`` in ``(0, 1]``,
            ``accumulate`` a bool (the checks of :mod:`~superex_deploy.onboard.checks`).
    """

    n_rays: int = 250
    range_m: float = 20.0
    hit_threshold: float = 0.8
    accumulate: bool = False

    def __post_init__(self) -> None:
        # Imported here: the planners package imports this module.
        from superex_deploy.onboard.checks import check_instance, check_int, check_real

        object.__setattr__(self, "n_rays", check_int("n_rays", self.n_rays, 3, MAX_RAYS))
        object.__setattr__(self, "range_m", check_real("range_m", self.range_m, 0.0, low_open=True))
        object.__setattr__(self, "hit_threshold", check_real("hit_threshold", self.hit_threshold, 0.0, 1.0,
                                                             low_open=True))
        check_instance("accumulate", self.accumulate, bool)


@numba.njit(cache=True)
def ray_visible_ranges(mean, y0, x0, n_rays, max_t, hit_threshold, accumulate, ranges):
    """Visible range (cells) of ray ``k`` at angle ``2 pi k / n_rays``: to the centre of the first blocking cell
    (entry + 0.5 cells), to ``max_t``, or to the grid border, whichever comes first. All zero when the
    viewpoint's own cell blocks (MapEx: nothing is visible from inside a wall)."""
    n_rows, n_cols = mean.shape
    own = mean[int(np.floor(y0)), int(np.floor(x0))]
    if own >= hit_threshold:
        ranges[:] = 0.0
        return
    for k in range(n_rays):
        angle = 2.0 * np.pi * k / n_rays
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
            y0, x0, np.sin(angle), np.cos(angle))
        transmittance = 1.0 - own
        reach = max_t
        while True:
            r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                      t_delta_c)
            if t >= max_t:
                break
            if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                reach = t
                break
            p = mean[r, c]
            if accumulate:
                transmittance *= 1.0 - p
                blocked = 1.0 - transmittance >= hit_threshold
            else:
                blocked = p >= hit_threshold
            if blocked:
                reach = min(t + 0.5, max_t)
                break
        ranges[k] = reach


@numba.njit(cache=True)
def _polygon_spans(ranges, y0, x0, n_rows):
    """The scanline spans of the polygon through the ray end points ``(y0 + ranges[k] sin a_k, x0 + ranges[k] cos
    a_k)``, ``a_k = 2 pi k / n``: each row's centre line crosses the polygon's edges (half-open in y, so a vertex
    on the line counts once); the cells of row ``row_lo + i`` whose centres lie between crossings ``2j`` and
    ``2j + 1`` (of ``crossings[offsets[i]:offsets[i + 1]]``, sorted) are inside. The work is the edges' row spans.

    Returns ``(row_lo, n_scan, offsets int64 [n_scan + 1], crossings float64 [M])``; ``n_scan`` is 0 when no row
    centre line crosses the polygon (or every range is zero)."""
    n_rays = ranges.shape[0]
    no_offsets = np.zeros(1, np.int64)
    no_crossings = np.empty(0)
    if ranges.max() <= 0.0:
        return 0, 0, no_offsets, no_crossings
    step = 2.0 * np.pi / n_rays
    vert_y = np.empty(n_rays)
    vert_x = np.empty(n_rays)
    for k in range(n_rays):
        vert_y[k] = y0 + ranges[k] * np.sin(step * k)
        vert_x[k] = x0 + ranges[k] * np.cos(step * k)
    # Row r is scanned along y = r + 0.5; an edge meets it when min(y) <= r + 0.5 < max(y).
    row_lo = max(0, int(np.ceil(vert_y.min() - 0.5)))
    row_hi = min(n_rows - 1, int(np.ceil(vert_y.max() - 0.5)) - 1)
    if row_hi < row_lo:
        return 0, 0, no_offsets, no_crossings
    n_scan = row_hi - row_lo + 1
    offsets = np.zeros(n_scan + 1, np.int64)
    for k in range(n_rays):
        k1 = (k + 1) % n_rays
        first = max(row_lo, int(np.ceil(min(vert_y[k], vert_y[k1]) - 0.5)))
        last = min(row_hi, int(np.ceil(max(vert_y[k], vert_y[k1]) - 0.5)) - 1)
        for r in range(first, last + 1):
            offsets[r - row_lo + 1] += 1
    for i in range(n_scan):
        offsets[i + 1] += offsets[i]
    crossings = np.empty(offsets[n_scan])
    filled = offsets[:n_scan].copy()
    for k in range(n_rays):
        k1 = (k + 1) % n_rays
        first = max(row_lo, int(np.ceil(min(vert_y[k], vert_y[k1]) - 0.5)))
        last = min(row_hi, int(np.ceil(max(vert_y[k], vert_y[k1]) - 0.5)) - 1)
        for r in range(first, last + 1):
            fraction = (r + 0.5 - vert_y[k]) / (vert_y[k1] - vert_y[k])
            crossings[filled[r - row_lo]] = vert_x[k] + fraction * (vert_x[k1] - vert_x[k])
            filled[r - row_lo] += 1
    for i in range(n_scan):
        lo, hi = offsets[i], offsets[i + 1]
        for a in range(lo + 1, hi):  # insertion sort: a row crosses few edges
            x = crossings[a]
            b = a - 1
            while b >= lo and crossings[b] > x:
                crossings[b + 1] = crossings[b]
                b -= 1
            crossings[b + 1] = x
    return row_lo, n_scan, offsets, crossings


@numba.njit(cache=True)
def polygon_runs(ranges, y0, x0, n_rows, n_cols):
    """The cells inside the polygon of :func:`_polygon_spans` as runs, in row-major order: run ``k`` is row
    ``rows[k]``, columns ``firsts[k]..lasts[k]`` (inclusive; a cell is inside when its centre lies between
    crossings ``2j`` and ``2j + 1`` of its row; runs clipped to the map may be empty, ``first > last``).

    Returns ``(rows, firsts, lasts)``, int64 ``[K]`` each."""
    row_lo, n_scan, offsets, crossings = _polygon_spans(ranges, y0, x0, n_rows)
    n_runs = 0
    for i in range(n_scan):
        n_runs += (offsets[i + 1] - offsets[i]) // 2
    rows = np.empty(n_runs, np.int64)
    firsts = np.empty(n_runs, np.int64)
    lasts = np.empty(n_runs, np.int64)
    k = 0
    for i in range(n_scan):
        for j in range(offsets[i], offsets[i + 1] - 1, 2):
            rows[k] = row_lo + i
            firsts[k] = max(0, int(np.ceil(crossings[j] - 0.5)))
            lasts[k] = min(n_cols - 1, int(np.floor(crossings[j + 1] - 0.5)))
            k += 1
    return rows, firsts, lasts


@numba.njit(cache=True)
def _fill_visibility(ranges, y0, x0, observed, variance, visible_out, write_mask, stamp, label):
    """Cells whose centre lies inside the polygon of :func:`_polygon_spans`, by scanline fill
    (:func:`polygon_runs`). The work is the edges' row spans plus the visible cells.

    Marks the cells in ``visible_out`` when ``write_mask``; returns the number of those whose ``observed`` code
    is UNKNOWN (-1) and the sum of their ``variance``. With ``label >= 0`` an unknown cell counts only if
    ``stamp`` (int32, the map's shape) does not hold ``label`` there yet, and is then stamped with it: calls with
    one label count the union of their views. Nothing is visible when every range is zero."""
    n_rows, n_cols = observed.shape
    rows, firsts, lasts = polygon_runs(ranges, y0, x0, n_rows, n_cols)
    count = 0
    var_sum = 0.0
    for k in range(rows.shape[0]):
        r = rows[k]
        for c in range(firsts[k], lasts[k] + 1):
            if write_mask:
                visible_out[r, c] = True
            if observed[r, c] == -1:
                if label >= 0:
                    if stamp[r, c] == label:
                        continue
                    stamp[r, c] = label
                count += 1
                var_sum += variance[r, c]
    return count, var_sum


def check_map(name: str, array, dtype, shape=None) -> np.ndarray:
    if not isinstance(array, np.ndarray) or array.dtype != dtype or array.ndim != 2 or min(array.shape) < 1:
        found = f"{array.dtype} {array.shape}" if isinstance(array, np.ndarray) else type(array).__name__
        raise ValueError(f"{name} must be a non-empty {np.dtype(dtype).name} [H, W] array, got {found}")
    if shape is not None and array.shape != tuple(shape):
        raise ValueError(f"{name} has shape {array.shape}, expected {tuple(shape)}")
    return np.ascontiguousarray(array)


def check_cells(cells_rc, shape) -> np.ndarray:
    cells = np.asarray(cells_rc, dtype=np.int64).reshape(-1, 2)
    outside = (cells[:, 0] < 0) | (cells[:, 0] >= shape[0]) | (cells[:, 1] < 0) | (cells[:, 1] >= shape[1])
    if outside.any():
        raise ValueError(f"cell {tuple(int(v) for v in cells[np.argmax(outside)])} lies outside the map of "
                         f"shape {tuple(shape)}")
    return cells


def max_range_cells(cfg: VisibilityConfig, resolution_m: float) -> float:
    """The visibility range ``cfg.range_m`` in cells of ``resolution_m`` metres (float).

    Raises:
        ValueError: ``resolution_m`` is not positive and finite.
    """
    if not (np.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"resolution_m must be positive and finite, got {resolution_m}")
    return cfg.range_m / float(resolution_m)


def visible_ranges(mean: np.ndarray, cell_rc, cfg: VisibilityConfig, resolution_m: float) -> np.ndarray:
    """Per-ray visible range from the centre of a cell on the predicted mean map.

    Args:
        mean: float32 ``[H, W]`` predicted wall probability.
        cell_rc: viewpoint cell (row, col).
        cfg: ray count, range, hit rule.
        resolution_m: metres per cell.

    Returns:
        float64 ``[cfg.n_rays]`` ranges in cells; ray ``k`` points at angle ``2 pi k / n_rays`` (geometry's
        convention: 0 along +col, pi/2 along +row).
    """
    mean = check_map("mean", mean, np.float32)
    (r, c), = check_cells([cell_rc], mean.shape)
    ranges = np.empty(cfg.n_rays, np.float64)
    ray_visible_ranges(mean, r + 0.5, c + 0.5, cfg.n_rays, max_range_cells(cfg, resolution_m), cfg.hit_threshold,
                       cfg.accumulate, ranges)
    return ranges


def predicted_visibility(mean: np.ndarray, cell_rc, cfg: VisibilityConfig, resolution_m: float) -> np.ndarray:
    """Region predicted visible from a cell: the filled polygon of :func:`visible_ranges`.

    Returns:
        bool ``[H, W]`` visible cells (empty when the viewpoint's own cell blocks).
    """
    ranges = visible_ranges(mean, cell_rc, cfg, resolution_m)
    r, c = int(cell_rc[0]), int(cell_rc[1])
    visible = np.zeros(mean.shape, bool)
    _fill_visibility(ranges, r + 0.5, c + 0.5, np.zeros(mean.shape, np.int8), np.zeros(mean.shape, np.float32),
                     visible, True, _NO_STAMP, -1)
    return visible


def connected_unknown_gains(mean: np.ndarray, observed: np.ndarray, cells_rc,
                            wall_threshold: float = 0.5) -> np.ndarray:
    """Unknown cells in the predicted-free region 4-connected to each cell (MapEx ``hectoraug`` as coded).

    The prediction is binarised (a wall where ``mean > wall_threshold``; MapEx: its visualised prediction above
    128 of 255) and each cell's 4-connected non-wall component is taken whole, with no ray range.

    Args:
        mean: float32 ``[H, W]`` predicted wall probability.
        observed: int8 ``[H, W]`` observed map.
        cells_rc: ``[N, 2]`` cells (row, col).
        wall_threshold: binarisation threshold.

    Returns:
        int64 ``[N]``; 0 for a cell predicted to be a wall.
    """
    mean = check_map("mean", mean, np.float32)
    observed = np.ascontiguousarray(check_observed(observed, mean.shape))
    cells = check_cells(cells_rc, mean.shape)
    labels, n_labels = ndimage.label(mean <= wall_threshold)
    unknown_per_label = np.bincount(labels[observed == UNKNOWN], minlength=n_labels + 1)
    unknown_per_label[0] = 0
    return unknown_per_label[labels[cells[:, 0], cells[:, 1]]].astype(np.int64)


def reachable_frontiers(ctx: PlanningContext) -> tuple[list[Frontier], np.ndarray]:
    """The frontiers of finite travel cost and those costs (float64 ``[N]``)."""
    frontiers, costs = [], []
    for frontier in ctx.frontiers:
        cost = float(ctx.travel_cost[frontier.cell_rc])
        if np.isfinite(cost):
            frontiers.append(frontier)
            costs.append(cost)
    return frontiers, np.asarray(costs, np.float64)


def best_frontier(values: np.ndarray, costs: np.ndarray, frontiers: list[Frontier]) -> tuple[int, int]:
    """Cell of the frontier with the least value; ties to the lower travel cost, then the lower cell."""
    best = min(range(len(frontiers)), key=lambda i: (values[i], costs[i], frontiers[i].cell_rc))
    return frontiers[best].cell_rc
