"""The explorer's locked goal (MapEx's locked frontier): the goal block, the path to it, the goals reached whose
frontier did not resolve, and the rules that keep it or let it go at each step (:meth:`LockedGoal.keep`).

A goal is kept until it is reached (within the tolerance it was chosen with, and in line of sight:
:func:`~superex_deploy.onboard.planning.goal_choice.goal_reached`), let go by the planner
(:meth:`~superex_deploy.onboard.types.Planner.keep_goal`), resolved (no frontier left near it:
``GoalPolicy.drop_resolved_m``), blocked with no other path, or given up by the mission (no progress, unreachable:
:class:`~superex_deploy.onboard.status.Mission`). A goal reached on a map that holds no new measurement (a SLAM map
published every few seconds) waits there for the next one, which alone can show its frontier resolved; with
``GoalPolicy.confirm_visit_m`` a goal whose frontier is still there is driven onto before it is judged. Everything is
in blocks of the explorer's planning grid.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from superex_deploy.onboard.planning.goal_choice import goal_reached, near_frontier
from superex_deploy.onboard.planning.motion import PlanningMap, path_is_clear, planning_map
from superex_deploy.onboard.types import Frontier

__all__ = ["LockedGoal"]


class LockedGoal:
    """The goal an explorer drives to, its path, and the goals it reached.

    Args:
        reach_cells: a goal is reached within this many blocks (``MotionConfig.goal_reached_m``); the tolerance of
            a goal chosen in a later tier may be wider (:meth:`lock`).
        radius_cells: the robot's radius in blocks (a path is clear when no wall lies this close to it).

    Attributes:
        goal: the locked goal block, or None.
        path: blocks from the robot to the goal.
        visited: goal blocks reached whose frontier did not resolve (not offered again).
        tolerance: the reach tolerance of the locked goal (blocks).
        chosen_step: the step the goal was chosen at (-1: none yet).
    """

    def __init__(self, reach_cells: float, radius_cells: float):
        self.reach_cells, self.radius_cells = float(reach_cells), float(radius_cells)
        self.goal: Optional[tuple[int, int]] = None
        self.path: list[tuple[int, int]] = []
        self.visited: set[tuple[int, int]] = set()
        self.tolerance = self.reach_cells
        self.chosen_step = -1

    def release(self) -> None:
        """Let go of the goal and its path (the goal does not count as reached)."""
        self.goal, self.path = None, []

    def lock(self, goal: tuple[int, int], path: list[tuple[int, int]], tolerance: float, step: int) -> None:
        """Drive to ``goal`` along ``path`` from now on, reached within ``tolerance`` blocks; chosen at ``step``."""
        self.goal, self.path, self.tolerance, self.chosen_step = goal, path, float(tolerance), int(step)

    def regrid(self, move: Callable[[tuple[int, int]], tuple[int, int]]) -> None:
        """Move the goal, its path and the goals reached by ``move`` (a grid that grew by whole blocks)."""
        self.goal = None if self.goal is None else move(self.goal)
        self.path, self.visited = [move(cell) for cell in self.path], {move(cell) for cell in self.visited}

    def keep(self, observed: np.ndarray, not_free: np.ndarray, pose: tuple[int, int], step: int, *, fresh: bool,
             planner, goal_policy,
             regions: tuple[Frontier, ...], resolved_cells: Optional[float], gives_up: Callable, resolution_m: float,
             motion) -> tuple[bool, Optional[PlanningMap]]:
        """This step's verdict on the locked goal, on the planning map ``observed`` (int8 blocks) with the robot at
        block ``pose`` (``not_free``: bool, ``observed != FREE``, computed once by the caller, which reads it too):
        the goal and path are updated (kept, re-planned around a new wall, or released; a reached
        goal joins :attr:`visited` unless its frontier is to be confirmed).

        Args:
            step: the step's index (the planner's ``keep_goal`` reads the steps since the goal was chosen).
            fresh: whether the step's map holds a new measurement (a stale SLAM map cannot show a frontier resolved).
            planner: the explorer's planner (``keep_goal``).
            goal_policy: the :class:`~superex_deploy.onboard.planning.goal_policy.GoalPolicy` (``confirm_visit_m``).
            regions: the step's frontier regions of every size (for ``confirm_visit_m`` and ``resolved_cells``).
            resolved_cells: let the goal go once no frontier lies this close to it (blocks); None: keep it.
            gives_up: ``gives_up(goal_xy_block, path) -> bool``: the mission's verdict (no progress, no path).
            resolution_m: metres per block; motion: the :class:`~superex_deploy.onboard.planning.motion.MotionConfig`.

        Returns:
            ``(wait, plan)``: ``wait`` True when the robot waits at its reached goal for a fresh map (the step chooses
            no goal); ``plan``: the planning map computed to re-plan a blocked path, else None.
        """
        plan: Optional[PlanningMap] = None
        goal = self.goal
        path = self.path[self.path.index(pose):] if pose in self.path else []
        if goal is not None and goal_reached(not_free, pose, goal, self.tolerance):
            if not fresh:  # a stale SLAM map cannot show the frontier resolved yet: wait at the goal for one
                self.path = path or [pose]
                return True, None
            confirm = goal_policy.confirm_visit_m
            if confirm is not None and self.tolerance > confirm / resolution_m and near_frontier(regions, goal, 1.5):
                self.tolerance = confirm / resolution_m  # its frontier is still there: drive onto it, then judge
            else:
                self.visited.add(goal)
                goal, path = None, []
        if goal is not None and not planner.keep_goal(observed, pose, goal, step - self.chosen_step):
            goal, path = None, []
        if goal is not None and resolved_cells is not None and not near_frontier(regions, goal, resolved_cells):
            goal, path = None, []  # its frontier is gone: drive to none
        if goal is not None and (not path or not path_is_clear(observed, path[1:], self.radius_cells)):
            # Blocked by a newly seen wall, or the robot did not stop on its path: plan again to the same goal.
            plan = planning_map(observed, pose, resolution_m, motion)
            path = plan.path_to(goal)
        if goal is not None and gives_up(goal, path):
            goal, path = None, []  # no progress for too long, or (blacklisting unreachable goals) no path
        self.goal, self.path = goal, path
        return False, plan
