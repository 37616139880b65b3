"""Goal selection for exploration: nearest frontier, IG-Hector, UPEN and MapEx, and the registry of all planners
(the SuperEx planner lives in :mod:`superex_deploy.explore.superex_planner`).

These reproduce the line-of-sight planners of the MapEx benchmark (castacks/MapEx, ICRA 2025; its
``scripts/explore.py``, ``sim_utils.py``, ``simple_mask_utils.py`` and ``upen_baseline.py``) in our own code,
one class per method where MapEx selects them with mode strings (``nearest``, ``hectoraug``, ``upen``,
``visvarprob``). Each planner reads a :class:`~superex_deploy.explore.types.PlanningContext` and returns a goal
cell of finite travel cost; the episode loop drives there and keeps the goal until it is reached or blocked.

Differences common to all planners, and why:

* Distances are the engine's cost-to-go (``ctx.travel_cost``: path length weighted by the wall-proximity cost),
  not MapEx's straight-line distance from the robot to the frontier centre: a frontier behind a wall is not
  near, and an unreachable one (``inf``) is never chosen (MapEx picks by straight line, then drops goals that A*
  cannot reach).
* Ties are broken by travel cost, then by cell, so a choice never depends on the order of the frontiers.

The predicted visibility that MapEx and IG-Hector score lives in :mod:`superex_deploy.explore.visibility`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numba
import numpy as np

from superex_deploy.explore.superex_planner import SuperexConfig, SuperexPlanner
from superex_deploy.explore.types import OCCUPIED, Frontier, Planner, PlanningContext, Prediction
from superex_deploy.explore.visibility import (VisibilityConfig, best_frontier, check_cells, check_map,
                                               connected_unknown_gains, predicted_visibility, reachable_frontiers,
                                               visible_gains, visible_ranges)

__all__ = [
    "VisibilityConfig", "visible_ranges", "predicted_visibility", "visible_gains", "connected_unknown_gains",
    "reachable_frontiers",
    "RandomTree", "grow_rrt",
    "NearestFrontier", "HectorConfig", "HectorPlanner", "UpenConfig", "UpenPlanner", "MapexConfig", "MapexPlanner",
    "SuperexConfig", "SuperexPlanner", "PLANNERS", "make_planner",
]

class NearestFrontier(Planner):
    """Nearest frontier (MapEx ``nearest``): the frontier of least travel cost.

    MapEx ranks frontier centres by straight-line distance and skips those A* cannot reach; we rank by the
    cost-to-go, which already says which are reachable and how far they really are.
    """

    name = "nearest"

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return None
        return best_frontier(costs, costs, frontiers)


@dataclass(frozen=True)
class HectorConfig:
    """IG-Hector (Shrestha et al., ICRA 2019, as MapEx runs it: ``hectoraug``).

    Attributes:
        visibility: information gain region: the unknown cells predicted visible from the frontier (default),
            or None for MapEx's code path, which skips the raycast and counts the whole predicted-free region
            connected to the frontier (:func:`connected_unknown_gains`).
        info_gain_weight: weight ``w`` of ``floor(w * (sqrt(max IG) - sqrt(IG)))`` against travel cost
            (MapEx: 200).
        wall_threshold: binarisation of the prediction for the connected region (MapEx: 0.5).
    """

    visibility: Optional[VisibilityConfig] = field(default_factory=VisibilityConfig)
    info_gain_weight: float = 200.0
    wall_threshold: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.info_gain_weight) and self.info_gain_weight >= 0):
            raise ValueError(f"info_gain_weight must be finite and >= 0, got {self.info_gain_weight}")


class HectorPlanner(Planner):
    """IG-Hector: the exploration transform seeded at the frontiers with an information-gain cost.

    MapEx seeds a BFS over the observed free cells at each frontier centre with ``floor(w * (sqrt(max IG) -
    sqrt(IG)))`` and descends its gradient from the robot. The robot's value in that transform is the least,
    over frontiers, of seed plus travel cost, so we pick that frontier directly and let the engine drive there.
    Differences, and why:

    * IG counts the currently unknown cells predicted *visible* from the frontier (MapEx's ``score_frontiers``
      with ``hectoraug`` casts the rays but then skips them, ``skip_raycast=True``, and counts the whole
      predicted-free region connected to the frontier). That region holds the known free space, so every
      frontier the robot can reach gets the same IG and the IG term vanishes: plain Hector. Visibility keeps the
      method the paper describes; ``HectorConfig(visibility=None)`` gives MapEx's code path.
    * Travel cost is the engine's (1 per cell far from walls, up to about 10 beside them) where MapEx's
      transform adds Hector's danger cost, ``5 (15 - d)`` per cell within 15 cells of a wall; the weight of 200
      therefore counts for more against distance here than in MapEx, most in narrow corridors.
    * MapEx re-plans Hector at every step; the episode loop keeps a goal until it is reached or blocked.
    """

    name = "hector"

    def __init__(self, cfg: HectorConfig = HectorConfig()):
        self.cfg = cfg

    def information_gain(self, prediction: Prediction, observed: np.ndarray, cells_rc,
                         resolution_m: float) -> np.ndarray:
        """int64 ``[N]`` IG of each cell (see :class:`HectorConfig`)."""
        if self.cfg.visibility is None:
            return connected_unknown_gains(prediction.mean, observed, cells_rc, self.cfg.wall_threshold)
        counts, _ = visible_gains(prediction, observed, cells_rc, self.cfg.visibility, resolution_m)
        return counts

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return None
        gains = self.information_gain(ctx.predict(), ctx.observed, [f.cell_rc for f in frontiers],
                                      ctx.resolution_m)
        root_gain = np.sqrt(gains.astype(np.float64))
        seeds = np.floor(self.cfg.info_gain_weight * (root_gain.max() - root_gain))
        return best_frontier(costs + seeds, costs, frontiers)


@dataclass(frozen=True)
class MapexConfig:
    """MapEx (``visvarprob``): predicted-visible variance per unit distance.

    Attributes:
        visibility: the probabilistic raycast (MapEx: 250 rays over 20 m, hit threshold 0.8).
        distance: the divisor: ``"travel"`` (default), the cost-to-go of the planning map (path length weighted
            by the wall-proximity cost), or ``"euclidean"``, the straight-line distance from the robot to the
            frontier cell in cells, as MapEx's code divides (``sim_utils.py``: ``frontier_val / cost_dist``).
        min_distance_cells: floor on the divisor. Frontiers within the goal tolerance (1 m) are never offered,
            so it only guards against a zero distance.
    """

    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    distance: str = "travel"
    min_distance_cells: float = 1.0

    def __post_init__(self) -> None:
        if not self.min_distance_cells > 0:
            raise ValueError(f"min_distance_cells must be positive, got {self.min_distance_cells}")
        if self.distance not in ("travel", "euclidean"):
            raise ValueError(f"MapexConfig.distance must be 'travel' or 'euclidean', got {self.distance!r}")


class MapexPlanner(Planner):
    """MapEx: each frontier scores the predicted variance summed over the currently unknown cells predicted
    visible from it, divided by its distance; the best score wins.

    As MapEx, visibility comes from the probabilistic raycast on the ensemble mean and the variance from the
    ensemble. Differences: the divisor is the travel cost rather than the straight-line distance (see the
    module docstring; ``MapexConfig(distance="euclidean")`` divides as MapEx's code does); and when the
    prediction carries no variance at all (a deterministic predictor such as
    :class:`~superex_deploy.explore.prediction.ObservedAsPrediction` or the oracle), where MapEx would tie every
    frontier at zero and take the first, the visible unknown cells are counted instead (MapEx's ``visunk``).

    Reuse: the predictor and its evidence reach the planner only through ``ctx.predict``, so a SuperEx variant
    is this class run with another predictor; :meth:`information` is the hook for a different information
    measure and :meth:`score` gives every reachable frontier's score.
    """

    name = "mapex"

    def __init__(self, cfg: MapexConfig = MapexConfig()):
        self.cfg = cfg

    def information(self, prediction: Prediction, observed: np.ndarray, cells_rc, resolution_m: float
                    ) -> np.ndarray:
        """float64 ``[N]``: visible-unknown variance of each viewpoint, or the visible unknown count when the
        prediction has no variance anywhere."""
        counts, var_sums = visible_gains(prediction, observed, cells_rc, self.cfg.visibility, resolution_m)
        if np.any(prediction.variance > 0.0):
            return var_sums
        return counts.astype(np.float64)

    def score(self, ctx: PlanningContext) -> tuple[list[Frontier], np.ndarray, np.ndarray]:
        """The reachable frontiers, their travel costs and their scores (information per unit of
        ``cfg.distance``), float64 ``[N]`` each."""
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return [], costs, np.zeros(0)
        cells = np.array([f.cell_rc for f in frontiers], np.float64)
        information = self.information(ctx.predict(), ctx.observed, cells.astype(np.int64), ctx.resolution_m)
        if self.cfg.distance == "euclidean":
            distance = np.hypot(cells[:, 0] - ctx.pose_rc[0], cells[:, 1] - ctx.pose_rc[1])
        else:
            distance = costs
        return frontiers, costs, information / np.maximum(distance, self.cfg.min_distance_cells)

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs, scores = self.score(ctx)
        if not frontiers:
            return None
        return best_frontier(-scores, costs, frontiers)


@numba.njit(cache=True)
def _segment_free(passable, y0, x0, y1, x1):
    """Whether every point sampled every half cell or less along the segment lies on a passable cell."""
    n = int(np.ceil(np.hypot(y1 - y0, x1 - x0) / 0.5)) + 1
    for i in range(n + 1):
        f = i / n
        if not passable[int(np.floor(y0 + f * (y1 - y0))), int(np.floor(x0 + f * (x1 - x0)))]:
            return False
    return True


@numba.njit(cache=True)
def _grow_rrt(passable, reachable, start_y, start_x, samples, expand_cells, variance, node_yx, parent, depth,
              path_variance, exit_rc):
    """Grow an RRT from ``(start_y, start_x)`` over ``samples`` ([n, 2] points, cells); returns the node count.

    Each sample pulls its nearest node (first in insertion order on ties) at most ``expand_cells`` towards it;
    the new node is kept when the segment stays on passable cells. Arrays are filled in place, node 0 being the
    start. Each edge is sampled at the points ``i / n`` along it, ``i = 1..n``, ``n`` its Chebyshev length in
    cells rounded up (at least 1); over the cells of those points along the root-to-node path, ``path_variance``
    is the variance summed and ``exit_rc`` the last cell before the first one outside ``reachable`` (the node's
    own cell if there is none): a node inherits its parent's exit once the path has left ``reachable``.
    """
    node_yx[0, 0] = start_y
    node_yx[0, 1] = start_x
    parent[0] = -1
    depth[0] = 0
    path_variance[0] = 0.0
    exit_rc[0, 0] = int(np.floor(start_y))
    exit_rc[0, 1] = int(np.floor(start_x))
    has_left = np.zeros(node_yx.shape[0], np.bool_)
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
        by = node_yx[best, 0]
        bx = node_yx[best, 1]
        ny = by + scale * (sy - by)
        nx = bx + scale * (sx - bx)
        if not _segment_free(passable, by, bx, ny, nx):
            continue
        new = n_nodes
        node_yx[new, 0] = ny
        node_yx[new, 1] = nx
        parent[new] = best
        depth[new] = depth[best] + 1
        n = max(1, int(np.ceil(max(abs(ny - by), abs(nx - bx)))))
        total = 0.0
        exit_r = exit_rc[best, 0]
        exit_c = exit_rc[best, 1]
        left = has_left[best]
        for i in range(1, n + 1):
            f = i / n
            r = int(np.floor(by + f * (ny - by)))
            c = int(np.floor(bx + f * (nx - bx)))
            total += variance[r, c]
            if not left:
                if reachable[r, c]:
                    exit_r = r
                    exit_c = c
                else:
                    left = True
        path_variance[new] = path_variance[best] + total
        exit_rc[new, 0] = exit_r
        exit_rc[new, 1] = exit_c
        has_left[new] = left
        n_nodes += 1
    return n_nodes


@dataclass(frozen=True)
class RandomTree:
    """An RRT from :func:`grow_rrt`.

    Attributes:
        nodes_yx: float64 ``[n, 2]`` node positions (y, x) in cells; node 0 is the root.
        parent: int64 ``[n]`` parent index, -1 at the root (a parent always precedes its children).
        depth: int64 ``[n]`` edges from the root.
        path_variance: float64 ``[n]`` variance summed over the cells of the root-to-node path (see
            :meth:`path_cells`), the root's cell excluded.
        exit_rc: int64 ``[n, 2]`` the last cell of that path before it first leaves the reachable cells (the
            node's own cell when it never does).
    """

    nodes_yx: np.ndarray
    parent: np.ndarray
    depth: np.ndarray
    path_variance: np.ndarray
    exit_rc: np.ndarray

    def path_cells(self, node: int) -> np.ndarray:
        """int64 ``[m, 2]`` cells of the root-to-``node`` path: the root's cell, then for each edge the cells
        of the points ``i / n`` along it, ``i = 1..n``, ``n`` its Chebyshev length in cells rounded up."""
        chain = [int(node)]
        while self.parent[chain[-1]] >= 0:
            chain.append(int(self.parent[chain[-1]]))
        chain.reverse()
        cells = [np.floor(self.nodes_yx[chain[0]]).astype(np.int64)[None]]
        for a, b in zip(chain[:-1], chain[1:]):
            start, end = self.nodes_yx[a], self.nodes_yx[b]
            n = max(1, int(np.ceil(np.abs(end - start).max())))
            fractions = np.arange(1, n + 1)[:, None] / n
            cells.append(np.floor(start + fractions * (end - start)).astype(np.int64))
        return np.concatenate(cells)


def grow_rrt(passable: np.ndarray, start_rc, n_samples: int, expand_cells: float, rng: np.random.Generator,
             variance: Optional[np.ndarray] = None, reachable: Optional[np.ndarray] = None) -> RandomTree:
    """RRT over the passable cells from the centre of ``start_rc``, samples uniform over the whole map.

    Args:
        passable: bool ``[H, W]`` cells the tree may cross.
        start_rc: root cell (row, col), passable.
        n_samples: samples drawn (each adds at most one node).
        expand_cells: the longest edge, in cells.
        rng: source of the samples.
        variance: float32 ``[H, W]`` summed along the paths, or None (zeros).
        reachable: bool ``[H, W]`` cells whose exit the tree reports (``RandomTree.exit_rc``), or None (all).

    Returns:
        The :class:`RandomTree`.
    """
    passable = check_map("passable", passable, np.bool_)
    variance = (np.zeros(passable.shape, np.float32) if variance is None
                else check_map("variance", variance, np.float32, passable.shape))
    reachable = (np.ones(passable.shape, np.bool_) if reachable is None
                 else check_map("reachable", reachable, np.bool_, passable.shape))
    (r, c), = check_cells([start_rc], passable.shape)
    if not passable[r, c]:
        raise ValueError(f"RRT start {(int(r), int(c))} is not passable")
    if int(n_samples) != n_samples or n_samples < 1 or not (np.isfinite(expand_cells) and expand_cells > 0):
        raise ValueError(f"n_samples must be an integer >= 1 and expand_cells positive, got {n_samples}, "
                         f"{expand_cells}")
    size = int(n_samples) + 1
    samples = rng.random((size - 1, 2)) * np.array(passable.shape, np.float64)
    node_yx, parent, depth = np.empty((size, 2)), np.empty(size, np.int64), np.empty(size, np.int64)
    path_variance, exit_rc = np.empty(size), np.empty((size, 2), np.int64)
    n = _grow_rrt(passable, reachable, r + 0.5, c + 0.5, samples, float(expand_cells), variance, node_yx, parent,
                  depth, path_variance, exit_rc)
    return RandomTree(node_yx[:n].copy(), parent[:n].copy(), depth[:n].copy(), path_variance[:n].copy(),
                      exit_rc[:n].copy())


@dataclass(frozen=True)
class UpenConfig:
    """UPEN (Georgakis et al., ICRA 2022) as MapEx runs it (``upen_config`` of its ``base.yaml``).

    Attributes:
        rrt_samples: RRT iterations (MapEx: 2500).
        expand_cells: RRT step length in cells (MapEx: 5).
        reach_horizon: the longest path scored, in RRT edges (MapEx: 50).
        min_goal_distance_m: a goal this close to the robot counts as reached already (MapEx's
            ``cur_pose_dist_threshold_m``: 1 m).
    """

    rrt_samples: int = 2500
    expand_cells: float = 5.0
    reach_horizon: int = 50
    min_goal_distance_m: float = 1.0

    def __post_init__(self) -> None:
        if int(self.rrt_samples) != self.rrt_samples or self.rrt_samples < 1:
            raise ValueError(f"rrt_samples must be an integer >= 1, got {self.rrt_samples}")
        if not (np.isfinite(self.expand_cells) and self.expand_cells > 0):
            raise ValueError(f"expand_cells must be positive, got {self.expand_cells}")
        if int(self.reach_horizon) != self.reach_horizon or self.reach_horizon < 1:
            raise ValueError(f"reach_horizon must be an integer >= 1, got {self.reach_horizon}")
        if not self.min_goal_distance_m >= 0:
            raise ValueError(f"min_goal_distance_m must be >= 0, got {self.min_goal_distance_m}")


class UpenPlanner(Planner):
    """UPEN: grow an RRT from the robot through everything not known to be a wall, score each root-to-node path
    of up to ``reach_horizon`` edges by the ensemble variance summed along it, and head along the best path.

    As MapEx: the tree crosses unknown cells (only observed walls block it), 2500 samples of 5-cell steps, and
    the score is the summed variance of the ensemble's occupancy. Differences, and why:

    * A plain RRT: MapEx grows an RRT* whose rewiring radius, ``min(5, 20 sqrt(log n / n))`` cells, is half the
      step or less from about 400 nodes on (1.1 cells at 2500), so rewiring only reaches near-duplicate nodes.
    * Samples cover the map; MapEx's cover a square of the map's height on a side (its ``rand_area``).
    * MapEx scores only paths of exactly ``reach_horizon`` edges and, when the tree has none (common while
      little is known), drives towards the map's bottom-right corner; we score every root-to-node path of at
      most ``reach_horizon`` edges. The summed variance only grows along a path, so long paths through
      uncertain space still win, and a shallow tree still has a choice.
    * MapEx samples each edge's cells with the end's column but the start's row throughout (a slip in
      ``eval_path_expl``); we sample along the edge.
    * MapEx plans A* through unknown cells to reach a goal there; the engine drives on known free cells only,
      so the goal is the path's exit: its last cell of finite travel cost before it first leaves them (where
      the robot starts to see into the chosen unknown). Paths whose exit lies within ``min_goal_distance_m``
      of the robot are passed over for the next best.
    * MapEx re-chooses UPEN's goal every 10 steps; the episode loop keeps it until reached or blocked.
    * With no variance anywhere (deterministic predictors) UPEN has no signal; it then falls back to the
      nearest frontier, as it does when no path finds variance.
    """

    name = "upen"

    def __init__(self, cfg: UpenConfig = UpenConfig()):
        self.cfg = cfg

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        variance = ctx.predict().variance
        passable = ctx.observed != OCCUPIED
        if np.any(variance > 0.0) and passable[ctx.pose_rc]:
            tree = grow_rrt(passable, ctx.pose_rc, self.cfg.rrt_samples, self.cfg.expand_cells, ctx.rng, variance,
                            reachable=np.isfinite(ctx.travel_cost))
            far_enough = np.hypot(tree.exit_rc[:, 0] - ctx.pose_rc[0], tree.exit_rc[:, 1] - ctx.pose_rc[1]) > (
                self.cfg.min_goal_distance_m / ctx.resolution_m)
            candidates = np.flatnonzero((tree.depth <= self.cfg.reach_horizon) & (tree.path_variance > 0.0)
                                        & far_enough)
            if len(candidates):
                best = candidates[np.argmax(tree.path_variance[candidates])]  # first of equals: the oldest node
                return int(tree.exit_rc[best, 0]), int(tree.exit_rc[best, 1])
        return NearestFrontier().choose_goal(ctx)


PLANNERS: dict[str, type[Planner]] = {
    NearestFrontier.name: NearestFrontier,
    HectorPlanner.name: HectorPlanner,
    UpenPlanner.name: UpenPlanner,
    MapexPlanner.name: MapexPlanner,
    SuperexPlanner.name: SuperexPlanner,
}

_CONFIGS = {HectorPlanner: HectorConfig, UpenPlanner: UpenConfig, MapexPlanner: MapexConfig,
            SuperexPlanner: SuperexConfig}


def make_planner(name: str, **config_overrides) -> Planner:
    """Create a planner by name (``nearest``, ``hector``, ``upen``, ``mapex``), overriding its config fields.

    Raises:
        ValueError: an unknown name (the message lists the valid ones), or overrides the config does not take.
    """
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(sorted(PLANNERS))}")
    planner_class = PLANNERS[name]
    config_class = _CONFIGS.get(planner_class)
    if config_class is None:
        if config_overrides:
            raise ValueError(f"planner {name!r} takes no configuration, got {sorted(config_overrides)}")
        return planner_class()
    try:
        config = replace(config_class(), **config_overrides)
    except TypeError as error:
        raise ValueError(f"bad configuration for planner {name!r}: {error}") from None
    return planner_class(config)
