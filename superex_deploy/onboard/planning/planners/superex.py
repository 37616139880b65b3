"""The SuperEx planner: pathwise expected gain per unit of travel.

MapEx scores a frontier by what its predicted map says is visible from the frontier cell alone. The robot,
though, scans every 0.3 m on its way there: a frontier down a corridor lined with doors is worth what the robot
sees through every door it passes, a frontier behind a wall that the prediction closes is worth little even if
its own view is open. The SuperEx planner scores each reachable frontier by the **pathwise gain** (as the PIPE
planner does): the currently unknown cells it expects to see from its goal cell *or* from any point of the path
to it, sampled every ``sense_every_m``, per unit of travel cost; the best frontier wins and is kept until
reached or blocked (MapEx's locked goal).

The gain reads the prediction as probabilities (``gain="expected"``,
:mod:`~superex_deploy.onboard.planning.expected_visibility`): each unknown cell counts with the probability that a
ray reaches it, the largest over the path's viewpoints, and a ray passes the cells it crosses with probability
``1 - max p`` over their predicted wall probabilities (correlated transmittance: the cells of one predicted wall
are one event). Measured in docs/benchmarks/better-map.md, "Reading predictions as probabilities"
(``benchmarks/expected_gain/``): a count on the thresholded prediction (``gain="path"``) pays for every wrong
predicted wall. Measured there and retired: the product of ``1 - p`` along a ray (cells independent), which cuts the
rays short where a learned prediction spreads a little wall probability over every unknown cell, and a "wall
support" that shrank predicted walls neither NLOS evidence nor an observed wall supported.

Options a user may choose (measured on the train floors, docs/benchmarks/better-map.md):

* ``gain="path"``: the count of unknown cells visible along the path on the prediction thresholded at
  ``wall_threshold`` (rays stop at cells predicted walls at or above it); ``"goal"``: the same from the goal cell
  only (MapEx's gain); ``"expected_goal"``: the expected gain from the goal cell only;
* ``drop_resolved_m``: drop the goal as soon as no unknown cell is left within this distance of it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.planning.expected_visibility import ExpectedVisibility, expected_visible_gains
from superex_deploy.onboard.checks import check_choice, check_instance, check_int, check_real
from superex_deploy.onboard.planning.viewpoint_gains import union_visible_unknown_flat, visible_gains
from superex_deploy.onboard.planning.visibility import (MAX_RAYS, VisibilityConfig, check_cells, check_map,
                                                       reachable_frontiers)
from superex_deploy.onboard.types import (UNKNOWN, Planner, PlanningContext, Prediction, frontiers_at,
                                          scores_by_cell)

__all__ = ["SuperexConfig", "SuperexPlanner", "descend", "descend_all", "path_viewpoints"]


@dataclass(frozen=True)
class SuperexConfig(JsonConfig):
    """Settings of :class:`SuperexPlanner` (chosen on the train floors only, never on ``eval/``).

    Attributes:
        gain: ``"expected"`` / ``"expected_goal"``: the expected number of unknown cells seen along the path to
            the goal / from the goal (transmittance ``1 - max p`` through the predicted wall probabilities, no
            threshold);
            ``"path"``: unknown cells visible from the goal or along the path to it on the prediction thresholded
            at ``wall_threshold``; ``"goal"``: the same from the goal cell only (MapEx). ``n_rays`` and
            ``range_m`` serve all four.
        wall_threshold: for ``gain="path"`` and ``"goal"``, a cell blocks a ray when its predicted wall probability
            reaches this. 0.5, chosen on the held-out train buildings with LaMa-LOS (docs/benchmarks/better-map.md,
            "Ceilings first"): a lower threshold lets the ensembles' faint predicted walls stop most rays, and the
            choice drifts towards the nearest frontier. Binary maps (observed, oracle) do not depend on it.
        sense_every_m: the path is sampled every this many metres for the pathwise gain.
        range_m: the sensor's range (metres; the LiDAR's 20 m).
        n_rays: rays of each visibility cast (over a full turn).
        drop_resolved_m: None keeps a goal until it is reached or blocked (MapEx); a distance drops it as soon as
            no unknown cell is left that close to it.

    Every distance is finite and positive (``drop_resolved_m``: None or finite and >= 0), ``n_rays`` an integer in
    ``[3, MAX_RAYS]``. The rollout and tour choices were measured and retired (docs/benchmarks/better-map.md).

    Raises:
        ValueError: a field of another type or out of its range, named (see
            :mod:`~superex_deploy.onboard.checks`).
    """

    gain: str = "expected"
    wall_threshold: float = 0.5
    sense_every_m: float = 1.5
    range_m: float = 20.0
    n_rays: int = 250
    drop_resolved_m: Optional[float] = None

    def __post_init__(self) -> None:
        check_choice("gain", self.gain, ("path", "goal", "expected", "expected_goal"))
        values = {"wall_threshold": check_real("wall_threshold", self.wall_threshold, 0.0, 1.0, low_open=True),
                  "drop_resolved_m": check_real("drop_resolved_m", self.drop_resolved_m, 0.0, allow_none=True),
                  "n_rays": check_int("n_rays", self.n_rays, 3, MAX_RAYS)}
        for name in ("sense_every_m", "range_m"):
            values[name] = check_real(name, getattr(self, name), 0.0, low_open=True)
        for name, value in values.items():
            object.__setattr__(self, name, value)


@numba.njit(cache=True)
def _descend_paths(travel_cost, goal_rows, goal_cols):
    """The descents of :func:`descend` from every goal (each finite), in one compiled pass.

    Each step goes to the cell of least cost in the 3 x 3 window around the current cell (clipped at the
    border; ties to the first in row-major order, as ``np.argmin``), until the robot (cost 0) or a cell with no
    lower neighbour. Returns ``(rows int64 [M], cols int64 [M], offsets int64 [N + 1])``: path ``i``, from the
    robot's end to goal ``i``, is ``[offsets[i], offsets[i + 1])``."""
    n_rows, n_cols = travel_cost.shape
    n_goals = goal_rows.shape[0]
    rows = np.empty(64, np.int64)
    cols = np.empty(64, np.int64)
    offsets = np.zeros(n_goals + 1, np.int64)
    n = 0
    for i in range(n_goals):
        r, c = goal_rows[i], goal_cols[i]
        start = n
        while True:
            if n == rows.shape[0]:  # amortised doubling
                grown_rows = np.empty(2 * n, np.int64)
                grown_cols = np.empty(2 * n, np.int64)
                grown_rows[:n] = rows[:n]
                grown_cols[:n] = cols[:n]
                rows, cols = grown_rows, grown_cols
            rows[n] = r
            cols[n] = c
            n += 1
            here = travel_cost[r, c]
            if not here > 0.0:
                break
            best_r, best_c = max(r - 1, 0), max(c - 1, 0)
            best = travel_cost[best_r, best_c]
            for rr in range(max(r - 1, 0), min(r + 2, n_rows)):
                for cc in range(max(c - 1, 0), min(c + 2, n_cols)):
                    if travel_cost[rr, cc] < best:
                        best, best_r, best_c = travel_cost[rr, cc], rr, cc
            if best >= here:
                break  # a local minimum other than the robot: cannot happen on a Dijkstra field
            r, c = best_r, best_c
        # Walked from the goal down: reverse to run from the robot's end.
        rows[start:n] = rows[start:n][::-1].copy()
        cols[start:n] = cols[start:n][::-1].copy()
        offsets[i + 1] = n
    return rows[:n], cols[:n], offsets


def descend_all(travel_cost: np.ndarray, goals_rc) -> tuple[np.ndarray, np.ndarray]:
    """The least-cost paths from the robot (cost 0) to several goals down a Dijkstra cost-to-go field (each as
    :func:`descend`), in one compiled pass.

    Args:
        travel_cost: float64 ``[H, W]`` cost-to-go from the robot, ``inf`` where unreachable.
        goals_rc: ``[N, 2]`` goal cells (row, col), each of finite cost.

    Returns:
        ``(cells int64 [M, 2], offsets int64 [N + 1])``: path ``i`` is ``cells[offsets[i]:offsets[i + 1]]``, from
        the robot's cell to goal ``i``.

    Raises:
        ValueError: a cost map that is not float64 ``[H, W]``, a goal off the map or of infinite cost.
    """
    travel_cost = check_map("travel_cost", travel_cost, np.float64)
    goals = check_cells(goals_rc, travel_cost.shape)
    unreachable = ~np.isfinite(travel_cost[goals[:, 0], goals[:, 1]])
    if unreachable.any():
        r, c = goals[np.argmax(unreachable)]
        raise ValueError(f"goal {(int(r), int(c))} is unreachable (infinite travel cost)")
    rows, cols, offsets = _descend_paths(travel_cost, np.ascontiguousarray(goals[:, 0]),
                                         np.ascontiguousarray(goals[:, 1]))
    return np.stack([rows, cols], axis=1), offsets


def descend(travel_cost: np.ndarray, goal_rc) -> list[tuple[int, int]]:
    """The least-cost path from the robot (cost 0) to ``goal_rc`` down a Dijkstra cost-to-go field.

    Args:
        travel_cost: float64 ``[H, W]`` cost-to-go from the robot, ``inf`` where unreachable.
        goal_rc: a cell of finite cost.

    Returns:
        Cells from the robot's to the goal's, 8-connected; each step goes to the neighbour of least cost (ties
        to the first in row-major order).
    """
    cells, _ = descend_all(np.asarray(travel_cost, np.float64), [goal_rc])
    return [(int(r), int(c)) for r, c in cells]


def path_viewpoints(travel_cost: np.ndarray, goals_rc, every: int) -> tuple[np.ndarray, np.ndarray]:
    """The viewpoints of the pathwise gain: for each goal, the cells of its :func:`descend` path every ``every``
    cells from the robot's end (the robot's own cell excluded) and the goal cell.

    Returns:
        ``(cells int64 [V, 2], offsets int64 [N + 1])``: goal ``i``'s viewpoints are
        ``cells[offsets[i]:offsets[i + 1]]``, in path order.
    """
    cells, path_offsets = descend_all(travel_cost, goals_rc)
    picked = []
    for start, stop in zip(path_offsets[:-1], path_offsets[1:]):
        picked.append(np.append(np.arange(start + every, stop - 1, every), stop - 1))
    sizes = [len(p) for p in picked]
    index = np.concatenate(picked) if picked else np.zeros(0, np.int64)
    return cells[index.astype(np.int64)], np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


class SuperexPlanner(Planner):
    """Pathwise predicted gain per unit of travel (see the module docstring)."""

    name = "superex"

    def __init__(self, cfg: SuperexConfig = SuperexConfig()):
        self.cfg = check_instance("cfg", cfg, SuperexConfig)
        self._resolution_m = 0.1

    def keep_goal(self, observed: np.ndarray, pose_rc, goal_rc, steps_since_chosen: int) -> bool:
        if self.cfg.drop_resolved_m is None:
            return True
        radius = int(np.ceil(self.cfg.drop_resolved_m / self._resolution_m))
        r, c = goal_rc
        window = observed[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1]
        return bool(np.any(window == UNKNOWN))

    def gains(self, ctx: PlanningContext, prediction: Prediction, frontiers) -> np.ndarray:
        """float64 ``[N]`` gain of each frontier (``cfg.gain``): unknown cells predicted visible from its goal
        cell, or from its goal cell and every ``sense_every_m`` along the least-cost path to it (:meth:`viewpoints`);
        counted on the thresholded prediction, or expected (:meth:`los_gains`)."""
        cells, offsets = self.viewpoints(ctx, frontiers)
        return self.los_gains(ctx, prediction, cells, offsets)

    def viewpoints(self, ctx: PlanningContext, frontiers) -> tuple[np.ndarray, np.ndarray]:
        """``(cells int64 [V, 2], offsets int64 [N + 1])``: frontier ``i``'s viewpoints, its goal cell alone
        (``gain`` ``"goal"``, ``"expected_goal"``) or every ``sense_every_m`` along its least-cost path and its goal
        cell (:func:`path_viewpoints`)."""
        goals = np.array([f.cell_rc for f in frontiers], np.int64).reshape(-1, 2)
        if self.cfg.gain in ("goal", "expected_goal"):
            return goals, np.arange(len(goals) + 1)
        every = max(1, int(round(self.cfg.sense_every_m / ctx.resolution_m)))
        return path_viewpoints(ctx.travel_cost, goals, every)

    def los_gains(self, ctx: PlanningContext, prediction: Prediction, cells, offsets) -> np.ndarray:
        """float64 ``[N]``: the line-of-sight gain of each group of viewpoints: unknown cells predicted visible from
        them, counted on the thresholded prediction or expected (``cfg.gain``)."""
        if self.cfg.gain in ("expected", "expected_goal"):
            rays = ExpectedVisibility(n_rays=self.cfg.n_rays, range_m=self.cfg.range_m)
            viewpoints = [cells[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
            return expected_visible_gains(prediction.mean, ctx.observed, viewpoints, rays, ctx.resolution_m)[0]
        visibility = VisibilityConfig(n_rays=self.cfg.n_rays, range_m=self.cfg.range_m,
                                      hit_threshold=self.cfg.wall_threshold)
        if self.cfg.gain == "goal":
            return visible_gains(prediction, ctx.observed, cells, visibility, ctx.resolution_m)[0].astype(float)
        return union_visible_unknown_flat(prediction.mean, ctx.observed, cells, offsets, visibility,
                                          ctx.resolution_m).astype(float)

    def ratios(self, ctx: PlanningContext) -> tuple[list, np.ndarray, np.ndarray]:
        """The reachable frontiers, their travel costs and their scores (gain per unit of travel cost), float64
        ``[N]`` each."""
        self._resolution_m = float(ctx.resolution_m)
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return [], costs, np.zeros(0)
        prediction = ctx.predict()
        gains = self.gains(ctx, prediction, frontiers)
        return frontiers, costs, gains / np.maximum(costs, 1.0)

    def goal_scores(self, ctx: PlanningContext, cells_rc) -> np.ndarray:
        """:meth:`ratios` of each goal cell taken as a frontier (0 where unreachable)."""
        frontiers, _, ratio = self.ratios(replace(ctx, frontiers=frontiers_at(cells_rc)))
        return scores_by_cell(frontiers, ratio, cells_rc)

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs, ratio = self.ratios(ctx)
        if not frontiers:
            return None
        order = sorted(range(len(frontiers)), key=lambda i: (-ratio[i], costs[i], frontiers[i].cell_rc))
        return frontiers[order[0]].cell_rc
