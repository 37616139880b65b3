"""UPEN (Georgakis et al., ICRA 2022), as MapEx runs it: an RRT grown into predicted-free space, scored by the
variance along its branches."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_instance, check_int, check_real, in_cells
from superex_deploy.onboard.types import OCCUPIED, Planner, PlanningContext
from superex_deploy.onboard.planning.planners.nearest import NearestFrontier
from superex_deploy.onboard.planning.visibility import check_cells, check_map

__all__ = ["RandomTree", "grow_rrt", "UpenConfig", "UpenPlanner", "MAX_RRT_SAMPLES"]

MAX_RRT_SAMPLES = 1_000_000
"""The most RRT samples a UPEN planner takes: its tree's arrays grow with them, its nearest-node search with
their square (400 times MapEx's 2500)."""


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
            total += float(variance[r, c])  # float64 sums, compiled or not (numba: float32 + float64)
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
class UpenConfig(JsonConfig):
    """UPEN (Georgakis et al., ICRA 2022) as MapEx runs it (``upen_config`` of its ``base.yaml``).

    Attributes:
        rrt_samples: RRT iterations (MapEx: 2500; an integer in ``[1, MAX_RRT_SAMPLES]``).
        expand_m: RRT step length (metres, positive, finite; MapEx: 5 cells of 0.1 m).
        reach_horizon: the longest path scored, in RRT edges (MapEx: 50; an integer >= 1).
        min_goal_distance_m: a goal this close to the robot counts as reached already (MapEx's
            ``cur_pose_dist_threshold_m``: 1 m; finite, >= 0).

    Raises:
        ValueError: a field of another type or out of its range, named (see
            :mod:`~superex_deploy.onboard.checks`).
    """

    rrt_samples: int = 2500
    expand_m: float = 0.5
    reach_horizon: int = 50
    min_goal_distance_m: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rrt_samples", check_int("rrt_samples", self.rrt_samples, 1, MAX_RRT_SAMPLES))
        object.__setattr__(self, "expand_m", check_real("expand_m", self.expand_m, 0.0, low_open=True))
        object.__setattr__(self, "reach_horizon", check_int("reach_horizon", self.reach_horizon, 1))
        object.__setattr__(self, "min_goal_distance_m",
                           check_real("min_goal_distance_m", self.min_goal_distance_m, 0.0))


class UpenPlanner(Planner):
    """UPEN: grow an RRT from the robot through everything not known to be a wall, score each root-to-node path
    of up to ``reach_horizon`` edges by the ensemble variance summed along it, and head along the best path.

    As MapEx: the tree crosses unknown cells (only observed walls block it), 2500 samples of 0.5 m steps (5 cells of 0.1 m), and
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
    reads_variance = True

    def __init__(self, cfg: UpenConfig = UpenConfig()):
        self.cfg = check_instance("cfg", cfg, UpenConfig)

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        variance = ctx.predict().variance
        passable = ctx.observed != OCCUPIED
        if np.any(variance > 0.0) and passable[ctx.pose_rc]:
            expand_cells = in_cells(self.cfg.expand_m, ctx.resolution_m)
            tree = grow_rrt(passable, ctx.pose_rc, self.cfg.rrt_samples, expand_cells, ctx.rng, variance,
                            reachable=np.isfinite(ctx.travel_cost))
            far_enough = np.hypot(tree.exit_rc[:, 0] - ctx.pose_rc[0], tree.exit_rc[:, 1] - ctx.pose_rc[1]) > (
                self.cfg.min_goal_distance_m / ctx.resolution_m)
            candidates = np.flatnonzero((tree.depth <= self.cfg.reach_horizon) & (tree.path_variance > 0.0)
                                        & far_enough)
            if len(candidates):
                best = candidates[np.argmax(tree.path_variance[candidates])]  # first of equals: the oldest node
                return int(tree.exit_rc[best, 0]), int(tree.exit_rc[best, 1])
        return NearestFrontier().choose_goal(ctx)
