"""Goal selection for exploration: nearest frontier, IG-Hector, UPEN and MapEx.

These reproduce the line-of-sight planners of the MapEx benchmark (castacks/MapEx, ICRA 2025) in our own
code, one class per method (MapEx selects them with mode strings: ``nearest``, ``hectoraug``, ``upen``,
``visvarprob``). Each planner reads a :class:`~superex_deploy.explore.types.PlanningContext` and returns a goal
cell; the episode loop plans the path to it with A* and keeps it until reached or unreachable.

Shared machinery: :func:`predicted_visibility` casts rays from a cell on the predicted mean map and fills the
visibility polygon they bound (MapEx's "probabilistic raycast + flood fill"); a ray stops once the accumulated
probability that it has been blocked, ``1 - prod(1 - p_i)``, reaches the hit threshold (0.8 in MapEx).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar, Optional

import numba
import numpy as np

from superex_deploy.explore.types import Frontier, PlanningContext, Planner
from superex_deploy.geometry import _dda_start

__all__ = [
    "VisibilityConfig", "predicted_visibility", "visible_gains",
    "NearestFrontier", "HectorConfig", "HectorPlanner", "UpenConfig", "UpenPlanner", "MapexConfig", "MapexPlanner",
    "PLANNERS", "make_planner", "grow_rrt",
]


@dataclass(frozen=True)
class VisibilityConfig:
    """Predicted-visibility raycast (MapEx ``pred_vis_configs``).

    Attributes:
        n_rays: rays cast over a full turn from each candidate cell (MapEx: 250).
        range_m: ray range in metres (MapEx: 20).
        hit_threshold: a ray stops once its accumulated blocking probability reaches this (MapEx: 0.8).
    """

    n_rays: int = 250
    range_m: float = 20.0
    hit_threshold: float = 0.8

    def __post_init__(self) -> None:
        if self.n_rays < 3:
            raise ValueError(f"n_rays must be >= 3, got {self.n_rays}")
        if not self.range_m > 0:
            raise ValueError(f"range_m must be positive, got {self.range_m}")
        if not 0.0 < self.hit_threshold <= 1.0:
            raise ValueError(f"hit_threshold must lie in (0, 1], got {self.hit_threshold}")


@numba.njit(cache=True)
def _ray_visible_ranges(mean, y0, x0, n_rays, max_t, hit_threshold, ranges):
    """Visible range (cells) of each of ``n_rays`` rays: up to the centre of the cell where the accumulated
    blocking probability reaches ``hit_threshold``, or to ``max_t`` / the grid border."""
    n_rows, n_cols = mean.shape
    for k in range(n_rays):
        angle = 2.0 * np.pi * k / n_rays
        r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = _dda_start(
            y0, x0, np.sin(angle), np.cos(angle))
        transmittance = 1.0 - mean[r, c]
        if 1.0 - transmittance >= hit_threshold:
            ranges[k] = 0.5
            continue
        reach = max_t
        while True:
            if t_next_c <= t_next_r:
                t = t_next_c
                c += step_c
                t_next_c += t_delta_c
            else:
                t = t_next_r
                r += step_r
                t_next_r += t_delta_r
            if t >= max_t:
                break
            if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                reach = t
                break
            transmittance *= 1.0 - mean[r, c]
            if 1.0 - transmittance >= hit_threshold:
                reach = min(t + 0.5, max_t)
                break
        ranges[k] = reach


@numba.njit(cache=True)
def _fill_visibility(ranges, y0, x0, n_rows, n_cols, observed, variance, visible_out, write_mask):
    """Fill the polygon bounded by the ray ranges: a cell centre at polar (rho, phi) from the origin is visible
    when rho is within the smaller range of the two rays that bracket phi. Returns the number of visible
    UNKNOWN cells and their summed variance."""
    n_rays = ranges.shape[0]
    reach = 0.0
    for k in range(n_rays):
        reach = max(reach, ranges[k])
    r_lo = max(0, int(np.floor(y0 - reach)))
    r_hi = min(n_rows - 1, int(np.ceil(y0 + reach)))
    c_lo = max(0, int(np.floor(x0 - reach)))
    c_hi = min(n_cols - 1, int(np.ceil(x0 + reach)))
    step = 2.0 * np.pi / n_rays
    count = 0
    var_sum = 0.0
    for r in range(r_lo, r_hi + 1):
        for c in range(c_lo, c_hi + 1):
            vy = r + 0.5 - y0
            vx = c + 0.5 - x0
            rho = np.sqrt(vy * vy + vx * vx)
            if rho > reach:
                continue
            phi = np.arctan2(vy, vx)
            if phi < 0.0:
                phi += 2.0 * np.pi
            k0 = int(np.floor(phi / step)) % n_rays
            k1 = (k0 + 1) % n_rays
            if rho <= min(ranges[k0], ranges[k1]) or rho < 0.75:
                if write_mask:
                    visible_out[r, c] = True
                if observed[r, c] == -1:
                    count += 1
                    var_sum += variance[r, c]
    return count, var_sum


def _check_maps(mean: np.ndarray, observed: np.ndarray, variance: np.ndarray) -> None:
    for name, array, dtype in (("mean", mean, np.float32), ("variance", variance, np.float32),
                               ("observed", observed, np.int8)):
        if not isinstance(array, np.ndarray) or array.dtype != dtype or array.ndim != 2:
            raise ValueError(f"{name} must be a {np.dtype(dtype).name} [H, W] array")
        if array.shape != mean.shape:
            raise ValueError(f"{name} has shape {array.shape}, mean has {mean.shape}")


def _check_cell(cell_rc, shape) -> tuple[int, int]:
    r, c = int(cell_rc[0]), int(cell_rc[1])
    if not (0 <= r < shape[0] and 0 <= c < shape[1]):
        raise ValueError(f"cell {(r, c)} lies outside the map of shape {shape}")
    return r, c


def predicted_visibility(mean: np.ndarray, cell_rc, cfg: VisibilityConfig, resolution_m: float) -> np.ndarray:
    """Region predicted visible from a cell: probabilistic raycast on the mean map, polygon filled.

    Args:
        mean: float32 ``[H, W]`` predicted wall probability.
        cell_rc: viewpoint cell (row, col); rays start at its centre.
        cfg: ray count, range (m) and hit threshold.
        resolution_m: metres per cell.

    Returns:
        bool ``[H, W]`` visible cells.
    """
    shape = mean.shape
    blank_observed = np.zeros(shape, np.int8)
    _check_maps(mean, blank_observed, np.zeros(shape, np.float32))
    r, c = _check_cell(cell_rc, shape)
    ranges = np.empty(cfg.n_rays, np.float64)
    _ray_visible_ranges(mean, r + 0.5, c + 0.5, cfg.n_rays, cfg.range_m / resolution_m, cfg.hit_threshold, ranges)
    visible = np.zeros(shape, bool)
    _fill_visibility(ranges, r + 0.5, c + 0.5, shape[0], shape[1], blank_observed,
                     np.zeros(shape, np.float32), visible, True)
    return visible


def visible_gains(mean: np.ndarray, variance: np.ndarray, observed: np.ndarray, cells_rc, cfg: VisibilityConfig,
                  resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Information gain of viewpoints: currently unknown cells predicted visible from each.

    Args:
        mean, variance: float32 ``[H, W]`` prediction.
        observed: int8 ``[H, W]`` observed map (UNKNOWN = -1).
        cells_rc: ``[N, 2]`` viewpoint cells.
        cfg, resolution_m: as in :func:`predicted_visibility`.

    Returns:
        ``(unknown_count int64 [N], variance_sum float64 [N])``.
    """
    _check_maps(mean, observed, variance)
    cells = np.asarray(cells_rc, dtype=np.int64).reshape(-1, 2)
    counts = np.zeros(len(cells), np.int64)
    var_sums = np.zeros(len(cells), np.float64)
    ranges = np.empty(cfg.n_rays, np.float64)
    no_mask = np.zeros((1, 1), bool)
    for i, cell in enumerate(cells):
        r, c = _check_cell(cell, mean.shape)
        _ray_visible_ranges(mean, r + 0.5, c + 0.5, cfg.n_rays, cfg.range_m / resolution_m, cfg.hit_threshold,
                            ranges)
        counts[i], var_sums[i] = _fill_visibility(ranges, r + 0.5, c + 0.5, mean.shape[0], mean.shape[1],
                                                  observed, variance, no_mask, False)
    return counts, var_sums


def _reachable(frontiers: tuple[Frontier, ...], travel_cost: np.ndarray) -> list[tuple[Frontier, float]]:
    out = []
    for frontier in frontiers:
        cost = float(travel_cost[frontier.cell_rc])
        if np.isfinite(cost):
            out.append((frontier, cost))
    return out


class NearestFrontier(Planner):
    """Nearest frontier (MapEx ``nearest``): the reachable frontier with the least travel cost."""

    name = "nearest"

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        candidates = _reachable(ctx.frontiers, ctx.travel_cost)
        if not candidates:
            return None
        best = min(candidates, key=lambda fc: (fc[1], fc[0].cell_rc))
        return best[0].cell_rc


@dataclass(frozen=True)
class HectorConfig:
    """IG-Hector (Shrestha et al. ICRA 2019; MapEx ``hectoraug``).

    Attributes:
        visibility: predicted-visibility raycast used for the information gain.
        info_gain_weight: weight of ``sqrt(max IG) - sqrt(IG)`` against travel cost in cells (MapEx: 200).
    """

    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    info_gain_weight: float = 200.0


class HectorPlanner(Planner):
    """IG-Hector: exploration transform seeded at the frontiers with an information-gain cost.

    The information gain IG of a frontier is the number of currently unknown cells predicted visible from it.
    MapEx seeds a BFS exploration transform at the frontiers with ``w * (sqrt(max IG) - sqrt(IG))`` and descends
    its gradient from the robot; the robot's value in that transform is the minimum over frontiers of seed cost
    plus travel cost, so we pick that minimising frontier directly and let A* drive there (the same goal,
    without a second whole-map BFS per step).
    """

    name = "hector"

    def __init__(self, cfg: HectorConfig = HectorConfig()):
        self.cfg = cfg

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        candidates = _reachable(ctx.frontiers, ctx.travel_cost)
        if not candidates:
            return None
        prediction = ctx.predict()
        cells = [f.cell_rc for f, _ in candidates]
        gains, _ = visible_gains(prediction.mean, prediction.variance, ctx.observed, cells, self.cfg.visibility,
                                 ctx.resolution_m)
        root_gain = np.sqrt(gains.astype(np.float64))
        totals = [cost + self.cfg.info_gain_weight * (root_gain.max() - root_gain[i])
                  for i, (_, cost) in enumerate(candidates)]
        best = min(range(len(candidates)), key=lambda i: (totals[i], candidates[i][0].cell_rc))
        return candidates[best][0].cell_rc


@dataclass(frozen=True)
class MapexConfig:
    """MapEx (``visvarprob``): visibility-masked variance per unit distance.

    Attributes:
        visibility: probabilistic raycast (MapEx: 250 rays over 20 m, hit threshold 0.8).
        min_distance_cells: floor on the travel cost used as divisor (a frontier under the robot would
            otherwise divide by zero).
    """

    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    min_distance_cells: float = 1.0


class MapexPlanner(Planner):
    """MapEx: score each frontier by the summed predicted variance over currently unknown cells predicted
    visible from it, divided by the travel cost; pick the best.

    Where the predictor has no variance at all (a deterministic predictor such as
    :class:`~superex_deploy.explore.prediction.ObservedAsPrediction`), every score would be zero; the planner then
    uses the number of visible unknown cells instead (MapEx's ``visunk`` ablation) rather than a blind tie.
    SuperEx reuses :meth:`score` with its own predictor and evidence.
    """

    name = "mapex"

    def __init__(self, cfg: MapexConfig = MapexConfig()):
        self.cfg = cfg

    def score(self, ctx: PlanningContext, candidates: list[tuple[Frontier, float]]) -> np.ndarray:
        """float64 ``[N]`` information per unit travel cost of each (frontier, travel cost) candidate."""
        prediction = ctx.predict()
        counts, var_sums = visible_gains(prediction.mean, prediction.variance, ctx.observed,
                                         [f.cell_rc for f, _ in candidates], self.cfg.visibility, ctx.resolution_m)
        information = var_sums if np.any(var_sums > 0.0) else counts.astype(np.float64)
        distances = np.maximum([cost for _, cost in candidates], self.cfg.min_distance_cells)
        return information / distances

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        candidates = _reachable(ctx.frontiers, ctx.travel_cost)
        if not candidates:
            return None
        scores = self.score(ctx, candidates)
        best = max(range(len(candidates)), key=lambda i: (scores[i], -candidates[i][1]))
        return candidates[best][0].cell_rc


@numba.njit(cache=True)
def _segment_free(traversable, y0, x0, y1, x1):
    length = np.hypot(y1 - y0, x1 - x0)
    n = int(np.ceil(length / 0.5)) + 1
    for i in range(n + 1):
        f = i / n
        r = int(np.floor(y0 + f * (y1 - y0)))
        c = int(np.floor(x0 + f * (x1 - x0)))
        if not traversable[r, c]:
            return False
    return True


@numba.njit(cache=True)
def _grow_rrt(traversable, start_y, start_x, samples, expand_cells, node_yx, parent, depth):
    """Grow an RRT from the start over ``samples`` ([n, 2] points in cells); returns the number of nodes.

    Each sample pulls the nearest node up to ``expand_cells`` towards it; the new node is kept when the segment
    stays on traversable cells. ``node_yx`` / ``parent`` / ``depth`` are filled in place (node 0 = start).
    """
    node_yx[0, 0] = start_y
    node_yx[0, 1] = start_x
    parent[0] = -1
    depth[0] = 0
    n_nodes = 1
    for s in range(samples.shape[0]):
        sy = samples[s, 0]
        sx = samples[s, 1]
        best = 0
        best_d = np.inf
        for j in range(n_nodes):
            d = (node_yx[j, 0] - sy) ** 2 + (node_yx[j, 1] - sx) ** 2
            if d < best_d:
                best_d = d
                best = j
        dist = np.sqrt(best_d)
        if dist < 1e-9:
            continue
        scale = min(1.0, expand_cells / dist)
        ny = node_yx[best, 0] + scale * (sy - node_yx[best, 0])
        nx = node_yx[best, 1] + scale * (sx - node_yx[best, 1])
        if _segment_free(traversable, node_yx[best, 0], node_yx[best, 1], ny, nx):
            node_yx[n_nodes, 0] = ny
            node_yx[n_nodes, 1] = nx
            parent[n_nodes] = best
            depth[n_nodes] = depth[best] + 1
            n_nodes += 1
    return n_nodes


def grow_rrt(traversable: np.ndarray, start_rc, n_samples: int, expand_cells: float,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RRT over the traversable cells from the centre of ``start_rc``.

    Returns ``(node_yx float64 [n, 2] in cells, parent int64 [n] (-1 at the root), depth int64 [n])``.
    """
    traversable = np.ascontiguousarray(traversable)
    if traversable.dtype != np.bool_ or traversable.ndim != 2:
        raise ValueError("traversable must be a bool [H, W] array")
    r, c = _check_cell(start_rc, traversable.shape)
    if not traversable[r, c]:
        raise ValueError(f"RRT start {(r, c)} is not traversable")
    if n_samples < 1 or not expand_cells > 0:
        raise ValueError("n_samples must be >= 1 and expand_cells > 0")
    samples = rng.random((n_samples, 2)) * np.array(traversable.shape, np.float64)
    node_yx = np.empty((n_samples + 1, 2), np.float64)
    parent = np.empty(n_samples + 1, np.int64)
    depth = np.empty(n_samples + 1, np.int64)
    n = _grow_rrt(traversable, r + 0.5, c + 0.5, samples, float(expand_cells), node_yx, parent, depth)
    return node_yx[:n].copy(), parent[:n].copy(), depth[:n].copy()


@dataclass(frozen=True)
class UpenConfig:
    """UPEN (Georgakis et al. ICRA 2022, as run in the MapEx benchmark: ``upen_config`` of its base.yaml).

    Attributes:
        rrt_samples: RRT iterations (MapEx: 2500).
        expand_cells: RRT step length in cells (MapEx: 5).
        reach_horizon: path length in RRT edges that is scored and whose end becomes the goal (MapEx: 50).
    """

    rrt_samples: int = 2500
    expand_cells: float = 5.0
    reach_horizon: int = 50


class UpenPlanner(Planner):
    """UPEN: grow an RRT on the traversable map, score each root-to-node path of up to ``reach_horizon`` edges by
    the ensemble variance summed along it, and take the end of the best path as the goal.

    MapEx keeps only paths of exactly ``reach_horizon`` edges; early in an episode the known free space is too
    small for such paths, so we score the deepest available nodes (depth ``min(reach_horizon, max depth)``).
    With a zero-variance predictor all paths tie and UPEN has no signal; it then falls back to the nearest
    frontier (documented, so such runs are not mistaken for UPEN proper).
    """

    name = "upen"

    def __init__(self, cfg: UpenConfig = UpenConfig()):
        self.cfg = cfg

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        variance = ctx.predict().variance
        if ctx.traversable[ctx.pose_rc] and np.any(variance > 0.0):
            nodes, parent, depth = grow_rrt(ctx.traversable, ctx.pose_rc, self.cfg.rrt_samples,
                                            self.cfg.expand_cells, ctx.rng)
            target_depth = min(self.cfg.reach_horizon, int(depth.max()))
            best_node, best_value = -1, 0.0
            for node in np.flatnonzero(depth == target_depth):
                value = self._path_variance(nodes, parent, node, variance)
                if value > best_value:
                    best_node, best_value = int(node), value
            if best_node >= 0:
                goal = (int(nodes[best_node, 0]), int(nodes[best_node, 1]))
                if np.isfinite(ctx.travel_cost[goal]):
                    return goal
        return NearestFrontier().choose_goal(ctx)

    @staticmethod
    def _path_variance(nodes: np.ndarray, parent: np.ndarray, node: int, variance: np.ndarray) -> float:
        total = 0.0
        while parent[node] >= 0:
            a, b = nodes[node], nodes[parent[node]]
            n = int(np.ceil(np.hypot(*(a - b)))) + 1
            rows = np.floor(np.linspace(a[0], b[0], n)).astype(np.int64)
            cols = np.floor(np.linspace(a[1], b[1], n)).astype(np.int64)
            total += float(variance[rows[:-1], cols[:-1]].sum())
            node = int(parent[node])
        return total


PLANNERS: dict[str, type[Planner]] = {
    NearestFrontier.name: NearestFrontier,
    HectorPlanner.name: HectorPlanner,
    UpenPlanner.name: UpenPlanner,
    MapexPlanner.name: MapexPlanner,
}

_CONFIGS = {HectorPlanner: HectorConfig, UpenPlanner: UpenConfig, MapexPlanner: MapexConfig}


def make_planner(name: str, **config_overrides) -> Planner:
    """Create a planner by name (``nearest``, ``hector``, ``upen``, ``mapex``), overriding config fields."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(sorted(PLANNERS))}")
    planner_class = PLANNERS[name]
    config_class = _CONFIGS.get(planner_class)
    if config_class is None:
        if config_overrides:
            raise ValueError(f"planner {name!r} takes no configuration, got {sorted(config_overrides)}")
        return planner_class()
    try:
        return planner_class(replace(config_class(), **config_overrides))
    except TypeError as error:
        raise ValueError(f"bad configuration for planner {name!r}: {error}") from None
