"""Motion planning on the observed map: inflated walls, a wall-proximity cost, cost-to-go and paths.

One Dijkstra pass (scikit-image's ``MCP_Geometric``, 8-connected, geometric step lengths) gives both the
cost-to-go to every cell, which the planners need to rank frontiers, and the path to the chosen goal by
traceback; a separate A* search would repeat that work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from superex_deploy.explore.types import FREE, OCCUPIED

__all__ = ["MotionConfig", "PlanningMap", "planning_map"]


@dataclass(frozen=True)
class MotionConfig:
    """Robot motion.

    Attributes:
        robot_radius_m: walls are inflated by this (MapEx dilates by a 3-cell diameter: 0.15 m).
        wall_cost_weight: extra cost per cell next to a wall, falling linearly to zero at ``wall_cost_range_m``
            (the Hector-style danger ramp MapEx uses for planning).
        wall_cost_range_m: reach of the wall-proximity cost.
        step_cells: cells advanced along the path per step (0.3 m).
        goal_reached_m: a goal counts as reached within this distance.
    """

    robot_radius_m: float = 0.15
    wall_cost_weight: float = 5.0
    wall_cost_range_m: float = 1.0
    step_cells: int = 3
    goal_reached_m: float = 1.0

    def __post_init__(self) -> None:
        if self.robot_radius_m < 0 or self.wall_cost_weight < 0 or self.wall_cost_range_m <= 0:
            raise ValueError("MotionConfig: radius and weight must be >= 0, the cost range > 0")
        if self.step_cells < 1 or self.goal_reached_m < 0:
            raise ValueError("MotionConfig: step_cells must be >= 1 and goal_reached_m >= 0")


@dataclass(frozen=True)
class PlanningMap:
    """Cost-to-go from the robot.

    Attributes:
        traversable: bool ``[H, W]``: known free and farther than the robot radius from every observed wall;
            unknown cells are never traversable; the robot's own cell always is.
        travel_cost: float64 ``[H, W]`` cost-to-go from the robot (cells times the proximity factor); ``inf``
            where unreachable.
        origin_rc: offset of the planning window (the bounding box of known free cells) in the full map.
    """

    traversable: np.ndarray
    travel_cost: np.ndarray
    origin_rc: tuple[int, int]
    _mcp: MCP_Geometric

    def path_to(self, goal_rc: tuple[int, int]) -> list[tuple[int, int]]:
        """Cells (row, col) from the robot to ``goal_rc``; empty if unreachable."""
        if not np.isfinite(self.travel_cost[goal_rc]):
            return []
        r0, c0 = self.origin_rc
        local = self._mcp.traceback((goal_rc[0] - r0, goal_rc[1] - c0))
        return [(int(r + r0), int(c + c0)) for r, c in local]


def planning_map(observed: np.ndarray, pose_rc: tuple[int, int], resolution_m: float,
                 cfg: MotionConfig = MotionConfig()) -> PlanningMap:
    """Build the planning map and run Dijkstra from ``pose_rc`` over the bounding box of known free cells."""
    free = observed == FREE
    free[pose_rc] = True
    rows, cols = np.nonzero(free)
    r0, r1 = max(rows.min() - 1, 0), min(rows.max() + 2, observed.shape[0])
    c0, c1 = max(cols.min() - 1, 0), min(cols.max() + 2, observed.shape[1])
    window = observed[r0:r1, c0:c1]
    # Unknown cells are not traversable, but only observed walls are inflated: frontier cells border the
    # unknown by definition and must stay reachable.
    passable = window == FREE
    passable[pose_rc[0] - r0, pose_rc[1] - c0] = True
    observed_walls = window == OCCUPIED
    wall_distance_m = (ndimage.distance_transform_edt(~observed_walls) * resolution_m if observed_walls.any()
                       else np.full(window.shape, np.inf))
    traversable_local = passable & (wall_distance_m > cfg.robot_radius_m)
    traversable_local[pose_rc[0] - r0, pose_rc[1] - c0] = True
    proximity = np.clip((cfg.wall_cost_range_m - wall_distance_m) / cfg.wall_cost_range_m, 0.0, 1.0)
    costs = np.where(traversable_local, 1.0 + cfg.wall_cost_weight * proximity, np.inf)
    mcp = MCP_Geometric(costs)
    local_cost, _ = mcp.find_costs([(pose_rc[0] - r0, pose_rc[1] - c0)])
    travel_cost = np.full(observed.shape, np.inf)
    travel_cost[r0:r1, c0:c1] = local_cost
    traversable = np.zeros(observed.shape, bool)
    traversable[r0:r1, c0:c1] = traversable_local
    return PlanningMap(traversable=traversable, travel_cost=travel_cost, origin_rc=(int(r0), int(c0)), _mcp=mcp)
