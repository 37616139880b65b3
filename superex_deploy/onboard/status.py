"""What an exploration is doing, and what it does around the choice of goals: the region it is bounded to, the goals
it gave up on, the finish timer and the drive back to the start (:class:`Mission`, one per
:class:`~superex_deploy.onboard.explorer.Explorer`).

Every :class:`~superex_deploy.messages.Command` carries a ``status`` (:data:`~superex_deploy.messages.STATUSES`) and
a ``reason`` (why no goal was given, empty while one is). The phases follow one another: ``waiting_for_scan`` until
the map holds a known cell; ``exploring`` (or ``no_reachable_frontier`` while no goal has been found for less than
``finish_after_s``); then, with ``return_to_start``, ``returning`` along a path to the start pose (the first
observation's) until within ``goal_reached_m`` of it; ``done`` last. Once returning, new frontiers are not explored
again. A start no path reaches is tried again at every step (a SLAM map that restarts, a doorway closed by a noisy
scan, reopen), with reason ``"start unreachable"`` and no goal; the return ends, ``done``, only once the start has
been unreachable for ``goal_policy.no_progress_s``, or once the path to it has not become ``progress_m`` shorter
for that long (reason ``"no progress towards the start"``); with ``no_progress_s`` None it never gives up.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np

from superex_deploy.messages import DONE, EXPLORING, NO_REACHABLE_FRONTIER, RETURNING, MapFrame
from superex_deploy.onboard.config import ExplorerConfig
from superex_deploy.onboard.planning.bounds import clip_frontiers, reachable_goals
from superex_deploy.onboard.planning.frontiers import find_frontiers, open_frontiers
from superex_deploy.onboard.planning.goal_policy import GoalTracker, path_length_m
from superex_deploy.onboard.planning.motion import path_is_clear, planning_map
from superex_deploy.onboard.types import Frontier

__all__ = ["Mission", "NO_MEASUREMENT", "NO_FRONTIER", "OUTSIDE_BOUNDS", "ALL_BLACKLISTED", "UNREACHABLE",
           "BACK_AT_START", "START_UNREACHABLE", "NO_PROGRESS_HOME"]

NO_MEASUREMENT = "no valid measurement yet"
NO_FRONTIER = "no frontier left"
OUTSIDE_BOUNDS = "no frontier inside the bounds"
ALL_BLACKLISTED = "every frontier blacklisted"
UNREACHABLE = "no frontier reachable"
BACK_AT_START = "back at the start"
START_UNREACHABLE = "start unreachable"
NO_PROGRESS_HOME = "no progress towards the start"


class Mission:
    """The explorer's bounds, blacklist, finish timer and return to the start (see the module docstring).

    Attributes:
        cfg: the explorer's configuration (``bounds``, ``goal_policy``, ``return_to_start``, ``finish_after_s``).
        tracker: the :class:`~superex_deploy.onboard.planning.goal_policy.GoalTracker` (blacklist, progress).
        start_xy: the first observation's position (metres), or None before it.
        phase: ``"exploring"``, ``"returning"`` or ``"done"``.
        reason: why the latest step gave no goal ("" when it gave one).
    """

    def __init__(self, cfg: ExplorerConfig):
        self.cfg = cfg
        self.tracker = GoalTracker(cfg.goal_policy)
        self.start_xy: Optional[tuple[float, float]] = None
        self.phase = EXPLORING
        self.reason = ""
        self.no_goal_since: Optional[float] = None
        self.home_tracker = GoalTracker(cfg.goal_policy)  # the return's progress (never blacklists)
        self.unreachable_since: Optional[float] = None  # when the start was last found unreachable, in a row
        self._mask: Optional[tuple[MapFrame, np.ndarray]] = None

    def go_home(self) -> bool:
        """Return to the start from the next step on, whatever is left to explore (an operator's command); False
        when already returning or done."""
        if self.phase != EXPLORING:
            return False
        self.phase = RETURNING
        return True

    def set_bounds(self, bounds, pose=None) -> ExplorerConfig:
        """Replace the bounds (an :class:`~superex_deploy.onboard.planning.bounds.ExplorationBounds`, a sequence of
        ``(x, y)`` metres, or None) from the next step on; returns the new configuration.

        Raises:
            ValueError: a polygon :class:`ExplorerConfig` refuses (too small for the robot, crossing itself, ...),
                or one that does not hold ``pose`` (the robot's latest, a Pose2D; None: not checked).
        """
        cfg = replace(self.cfg, bounds=bounds)
        if cfg.bounds is not None and pose is not None:
            cfg.bounds.check_contains(pose.x, pose.y)
        self.cfg, self._mask = cfg, None
        return cfg

    def begin(self, x: float, y: float) -> None:
        """The first observation's position (metres): refused outside the bounds, else kept as the start.

        Raises:
            ValueError: a position outside ``cfg.bounds``.
        """
        if self.start_xy is None:
            if self.cfg.bounds is not None:
                self.cfg.bounds.check_contains(x, y)
            self.start_xy = (float(x), float(y))

    def inside(self, frame: MapFrame) -> Optional[np.ndarray]:
        """bool ``[H, W]`` the cells of ``frame`` inside the bounds (computed again when the grid changes), or None
        without bounds."""
        if self.cfg.bounds is None:
            return None
        if self._mask is None or self._mask[0] != frame:
            self._mask = (frame, self.cfg.bounds.mask(frame))
        return self._mask[1]

    def admit(self, frontiers: tuple[Frontier, ...], frame: MapFrame, stamp_s: float) -> tuple[Frontier, ...]:
        """The frontier regions the planner may be offered: cut to the bounds, those whose goal cell lies near a
        blacklisted goal dropped (``frontiers`` itself when neither applies)."""
        frontiers = clip_frontiers(frontiers, self.inside(frame))
        if not frontiers or not self.tracker.blacklist:
            return frontiers
        forbidden = self.tracker.forbidden(frame.centres_xy(np.array([f.cell_rc for f in frontiers])), stamp_s)
        return tuple(f for f, no in zip(frontiers, forbidden) if not no) if forbidden.any() else frontiers

    def why_no_goal(self, planning: np.ndarray, frame: MapFrame, stamp_s: float, min_cells: int = 1,
                    travel_cost: Optional[np.ndarray] = None, pockets=None) -> str:
        """Why a step found no goal on the map ``planning``: no frontier region of at least ``min_cells`` cells at all
        (with ``pockets``, a :class:`~superex_deploy.onboard.planning.frontiers.Pockets` of the map: none that
        borders unknown space a robot could enter), none inside the bounds, every one the robot can reach
        blacklisted (float ``[H, W]`` ``travel_cost``: the step's cost-to-go, ``inf`` where unreachable; None: every
        one), or none the robot can reach (or every one reached already)."""
        every = tuple(f for f in find_frontiers(planning, 1) if f.size >= min_cells)
        if pockets is not None and pockets.shape == planning.shape:
            every = open_frontiers(every, pockets)
        if not every:
            return NO_FRONTIER
        inside = clip_frontiers(every, self.inside(frame))
        if not inside:
            return OUTSIDE_BOUNDS
        if travel_cost is not None:
            reachable = tuple(f for f in reachable_goals(inside, travel_cost) if np.isfinite(travel_cost[f.cell_rc]))
            if reachable and not self.admit(reachable, frame, stamp_s):
                return ALL_BLACKLISTED
        if not self.admit(inside, frame, stamp_s):
            return ALL_BLACKLISTED
        return UNREACHABLE

    def gives_up(self, goal_xy: tuple[float, float], path, resolution_m: float, stamp_s: float) -> bool:
        """Whether to let go of the kept goal at ``goal_xy`` (metres), ``path`` the cells to it (empty: no path
        reaches it any more): no path, or no progress for ``goal_policy.no_progress_s``. A stalled goal is
        blacklisted here, an unreachable one too with ``goal_policy.blacklist_unreachable``."""
        if not path:
            if self.cfg.goal_policy.blacklist_unreachable:
                self.tracker.add(goal_xy, stamp_s)
            return True
        if self.tracker.stalled(goal_xy, path_length_m(path, resolution_m), stamp_s):
            self.tracker.add(goal_xy, stamp_s)
            return True
        return False

    def settle(self, alive: bool, stamp_s: float) -> bool:
        """Whether exploration is finished: nothing kept the run alive (``alive`` False: no reachable frontier
        region of at least ``cfg.finish_frontier_m``, or under the simulated rule no goal) for
        ``cfg.finish_after_s`` seconds of the observations' clock."""
        if alive:
            self.no_goal_since = None
            return False
        if self.no_goal_since is None:
            self.no_goal_since = stamp_s
        return stamp_s - self.no_goal_since >= self.cfg.finish_after_s

    def status(self, has_goal: bool, finished: bool) -> str:
        """The command's status for a step with a map: see :data:`~superex_deploy.messages.STATUSES`."""
        if finished or self.phase == DONE:
            return DONE
        if self.phase == RETURNING:
            return RETURNING
        return EXPLORING if has_goal else NO_REACHABLE_FRONTIER

    def home(self, planning: np.ndarray, pose: tuple[int, int], frame: MapFrame, path: list,
             reach_cells: float, radius_cells: float, stamp_s: float) -> tuple[Optional[tuple[int, int]], list]:
        """One step of the return at ``stamp_s``: the start cell and the path to it from ``pose`` on the map
        ``planning`` (the kept ``path`` while it is clear); ``(None, [])`` once within ``reach_cells`` of it
        (``phase`` is then ``"done"``), or while no path reaches it (``reason`` says so; ``"done"`` once that has
        lasted ``goal_policy.no_progress_s``), or once the path has made no progress for that long."""
        self.phase = RETURNING
        start = frame.cell_of(*self.start_xy)
        if np.hypot(start[0] - pose[0], start[1] - pose[1]) <= reach_cells:
            self.phase, self.reason = DONE, BACK_AT_START
            return None, []
        patience = self.cfg.goal_policy.no_progress_s
        path = path[path.index(pose):] if pose in path and path[-1] == start else []
        if not path or not path_is_clear(planning, path[1:], radius_cells):
            path = planning_map(planning, pose, frame.resolution_m, self.cfg.motion).path_to(start)
        if not path:
            if self.unreachable_since is None:
                self.unreachable_since = stamp_s
            self.reason = START_UNREACHABLE
            if patience is not None and stamp_s - self.unreachable_since >= patience:
                self.phase = DONE
            return None, []
        self.unreachable_since = None
        if self.home_tracker.stalled(self.start_xy, path_length_m(path, frame.resolution_m), stamp_s):
            self.phase, self.reason = DONE, NO_PROGRESS_HOME
            return None, []
        self.reason = ""
        return start, path
