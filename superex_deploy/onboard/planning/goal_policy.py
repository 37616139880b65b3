"""When the explorer gives up on a goal, and when it lets a better one replace it (:class:`GoalPolicy`), in metres
and seconds of the observations' clock (``Observation.stamp_s``), never in cells.

**Blacklisting** (explore_lite's rule). The progress towards a goal is the length of the path to it (metres along the
planned cells): a goal whose path has not become ``progress_m`` shorter than its shortest so far for
``no_progress_s`` seconds is blacklisted (a robot held by an obstacle its map does not show, a localisation that has
stalled, a controller that cannot follow the path). With ``blacklist_unreachable``, a goal that no path reaches any
more is blacklisted too. A blacklisted goal's position (map-frame metres, so that a map that grows keeps it) forbids
every frontier whose goal cell lies within ``blacklist_radius_m`` of it; the entry expires after
``blacklist_expire_s`` seconds (None: never within the episode: a new explorer starts with none).

**A goal whose frontier is gone** is let go at once (``drop_resolved_m``): once no frontier cell lies within that
distance of it, the robot would drive to a place that no longer shows anything new (open-loop on a bag, or a robot
slower than the map, kept the first scan's goal for a whole recording). The simulated benchmarks keep MapEx's rule
(None: a goal is kept until it is reached).

**Commitment**. By default a goal is kept until it is reached, blocked, resolved or let go by the planner (MapEx's
locked frontier). With ``commit_margin`` a number, the planner is asked every step; its choice replaces the locked goal only
when the planner's score of it beats the locked goal's by the relative margin (``new > (1 + commit_margin) * old``;
:meth:`~superex_deploy.onboard.types.Planner.goal_scores`). A planner that gives no scores keeps its goal.

The defaults leave the simulated benchmarks unchanged: there the pose is exact and the robot always advances along
its path, so a 30 s timeout at 10 Hz never fires, and a goal blocked by a newly seen wall is dropped (not
blacklisted) as before, since another route may open later.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_real

__all__ = ["GoalPolicy", "GoalTracker", "path_length_m"]


@dataclass(frozen=True)
class GoalPolicy(JsonConfig):
    """Blacklisting and commitment settings (see the module docstring).

    Attributes:
        no_progress_s: seconds without progress after which the goal is blacklisted (None: never).
        progress_m: how much shorter (metres) the path to the goal must become to count as progress.
        blacklist_radius_m: frontiers whose goal cell lies within this distance (metres) of a blacklisted goal are
            not offered to the planner.
        blacklist_unreachable: also blacklist a goal that no path reaches any more (off by default: a goal cut off
            by a wall seen late is dropped and may be chosen again when another route to it opens).
        blacklist_expire_s: seconds after which a blacklisted goal may be chosen again (None: never within the
            episode).
        commit_margin: None (the default): keep the goal until it is reached, blocked or let go by the planner; a
            number >= 0: switch to the planner's new choice when its score beats the kept goal's by this relative
            margin.
        drop_resolved_m: let go of the kept goal once no frontier cell (of the map the planning reads, inside the
            bounds, not blacklisted) lies within this distance of it (metres); None: keep it until it is reached
            (MapEx; the simulated benchmarks, :meth:`~superex_deploy.onboard.config.ExplorerConfig.for_simulation`).
        confirm_visit_m: a goal reached within ``MotionConfig.goal_reached_m`` (and in sight) whose frontier is
            still there is driven onto, within this distance (metres; Nav2's ``xy_goal_tolerance`` is 0.25 m),
            before its frontier is taken as one no viewpoint resolves and is not offered again: from a metre away
            the robot may not see into a closet through its door. None: given up at once (MapEx; the simulated
            benchmarks).

    Raises:
        ValueError: a negative or non-finite setting, a ``progress_m`` or ``blacklist_radius_m`` of 0 or less.
    """

    no_progress_s: Optional[float] = 30.0
    progress_m: float = 0.5
    blacklist_radius_m: float = 0.5
    blacklist_unreachable: bool = False
    blacklist_expire_s: Optional[float] = None
    commit_margin: Optional[float] = None
    drop_resolved_m: Optional[float] = 0.5
    confirm_visit_m: Optional[float] = 0.3

    def __post_init__(self) -> None:
        object.__setattr__(self, "no_progress_s", check_real("no_progress_s", self.no_progress_s, 0.0,
                                                             low_open=True, allow_none=True))
        object.__setattr__(self, "progress_m", check_real("progress_m", self.progress_m, 0.0, low_open=True))
        object.__setattr__(self, "blacklist_radius_m", check_real("blacklist_radius_m", self.blacklist_radius_m, 0.0,
                                                                  low_open=True))
        if not isinstance(self.blacklist_unreachable, bool):
            raise ValueError(f"blacklist_unreachable must be true or false, got {self.blacklist_unreachable!r}")
        object.__setattr__(self, "blacklist_expire_s", check_real("blacklist_expire_s", self.blacklist_expire_s, 0.0,
                                                                  low_open=True, allow_none=True))
        object.__setattr__(self, "commit_margin", check_real("commit_margin", self.commit_margin, 0.0,
                                                             allow_none=True))
        object.__setattr__(self, "drop_resolved_m", check_real("drop_resolved_m", self.drop_resolved_m, 0.0,
                                                               allow_none=True))
        object.__setattr__(self, "confirm_visit_m", check_real("confirm_visit_m", self.confirm_visit_m, 0.0,
                                                               allow_none=True))


def path_length_m(path, resolution_m: float) -> float:
    """Length (metres) of a path of 8-connected cells ``[(row, col), ...]`` (0 for fewer than two cells)."""
    if len(path) < 2:
        return 0.0
    cells = np.asarray(path, np.float64)
    return float(np.hypot(*np.diff(cells, axis=0).T).sum() * resolution_m)


class GoalTracker:
    """The blacklist and the progress towards the current goal, kept in map-frame metres and observation seconds.

    Attributes:
        policy: the :class:`GoalPolicy`.
        blacklist: ``[(x, y, stamp_s), ...]`` the blacklisted goals (metres) and when each was blacklisted.
    """

    def __init__(self, policy: GoalPolicy):
        self.policy = policy
        self.blacklist: list[tuple[float, float, float]] = []
        self._goal: Optional[tuple[float, float]] = None
        self._best_m = np.inf
        self._since_s = 0.0

    def chosen(self, goal_xy: tuple[float, float], stamp_s: float) -> None:
        """A new goal was chosen at ``stamp_s``: its progress clock starts now."""
        self._goal, self._best_m, self._since_s = tuple(goal_xy), np.inf, float(stamp_s)

    def stalled(self, goal_xy: tuple[float, float], distance_m: float, stamp_s: float) -> bool:
        """Record the path length ``distance_m`` to the kept goal ``goal_xy`` at ``stamp_s``; returns whether it made
        no progress for ``no_progress_s`` seconds (then the caller blacklists it)."""
        if self._goal != tuple(goal_xy):
            self.chosen(goal_xy, stamp_s)
        if not np.isfinite(self._best_m):  # the first length of this goal: its clock started when it was chosen
            self._best_m = distance_m
            return False
        if distance_m <= self._best_m - self.policy.progress_m:
            self._best_m, self._since_s = distance_m, float(stamp_s)
            return False
        return self.policy.no_progress_s is not None and stamp_s - self._since_s >= self.policy.no_progress_s

    def add(self, goal_xy: tuple[float, float], stamp_s: float) -> None:
        """Blacklist the goal at ``goal_xy`` (metres) from ``stamp_s`` on."""
        self.blacklist.append((float(goal_xy[0]), float(goal_xy[1]), float(stamp_s)))
        self._goal = None

    def forbidden(self, xy, stamp_s: float) -> np.ndarray:
        """bool ``[N]``: which map-frame points of float ``[N, 2]`` ``xy`` (metres) lie within the blacklist radius of
        a blacklisted goal still in force at ``stamp_s`` (expired entries are dropped here)."""
        expire = self.policy.blacklist_expire_s
        if expire is not None:
            self.blacklist = [entry for entry in self.blacklist if stamp_s - entry[2] < expire]
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if not self.blacklist:
            return np.zeros(len(xy), bool)
        goals = np.asarray([entry[:2] for entry in self.blacklist])
        distance = np.hypot(xy[:, None, 0] - goals[None, :, 0], xy[:, None, 1] - goals[None, :, 1])
        return (distance <= self.policy.blacklist_radius_m).any(axis=1)
