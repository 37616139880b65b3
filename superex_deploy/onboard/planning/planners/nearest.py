"""Nearest frontier (MapEx ``nearest``): the frontier of least travel cost."""

from __future__ import annotations

from typing import Optional

from superex_deploy.onboard.types import Planner, PlanningContext
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
