"""Nearest frontier (MapEx ``nearest``): the frontier of least travel cost."""

from __future__ import annotations

from typing import Optional

import numpy as np

from superex_deploy.onboard.types import Planner, PlanningContext, frontiers_at
from superex_deploy.onboard.planning.visibility import best_frontier, reachable_frontiers

__all__ = ["NearestFrontier"]


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

    def goal_scores(self, ctx: PlanningContext, cells_rc) -> np.ndarray:
        """The inverse travel cost of each cell (1 / cells; 0 where unreachable)."""
        cells = np.asarray(cells_rc, np.int64).reshape(-1, 2)
        costs = np.array([ctx.travel_cost[f.cell_rc] for f in frontiers_at(cells)], np.float64)
        return np.where(np.isfinite(costs), 1.0 / np.maximum(costs, 1.0), 0.0)
