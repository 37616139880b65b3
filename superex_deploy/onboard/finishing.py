"""When an exploration on a robot's data is finished, and whether its clock runs: the decisions an explorer makes
on time rather than on a map (:class:`FinishRule`, :class:`ClockWatch`).

**The finish rule** (:class:`FinishRule`): a step keeps the exploration alive, and restarts
``ExplorerConfig.finish_after_s``, when a frontier region of at least ``ExplorerConfig.finish_frontier_m`` (its size
before the bounds cut it) is left that the robot can reach, whose goal is no goal reached before, that no blacklist
holds, and that borders unknown space a robot could enter (:func:`~superex_deploy.onboard.planning.frontiers.
open_frontiers`: not a sliver or pocket narrower than the robot, as the inside of a double wall). The goal's own
region, near the goal, needs no search. Smaller regions are still offered to the planner while the timer runs; they
do not keep the run alive, so a wall's face cell flickering through the log-odds map's unknown band (a one-cell
frontier every other scan) cannot hold a robot for ever. With ``finish_frontier_m`` 0 it is the simulated
benchmarks' rule: any goal keeps the run alive, and only a goal does.

**The clock** (:class:`ClockWatch`): stamps that stop advancing (a robot on simulated time before ``/clock`` runs, a
driver without a clock) never let a delay elapse; after :data:`STALLED_CLOCK_STEPS` such steps a warning is given
once, and :attr:`ClockWatch.stalled` says so while it lasts (the ROS node's status reads it).
"""

from __future__ import annotations

import warnings
from typing import Callable, Optional

import numpy as np

from superex_deploy.onboard.planning.frontiers import Pockets, open_frontiers
from superex_deploy.onboard.planning.goal_choice import frontier_left, near_frontier
from superex_deploy.onboard.types import Frontier

__all__ = ["FinishRule", "ClockWatch", "POCKETS_EVERY_S", "STALLED_CLOCK_STEPS"]

POCKETS_EVERY_S = 1.0
"""How often (seconds of stamps) the enclosed unknown pockets are found again: a second old at most, and the finish
timer is longer."""
STALLED_CLOCK_STEPS = 20
"""Steps in a row with one stamp after which :attr:`ClockWatch.stalled` holds and a warning is given (2 s of scans
at 10 Hz)."""


class FinishRule:
    """The finish rule of one explorer (see the module docstring).

    Args:
        min_cells: the smallest region (planning blocks) that keeps the run alive; 0: the simulated rule.
        robot_radius_m: the robot's radius (unknown space narrower than it is no frontier to finish on).
        block_m: the planning blocks' size (metres).

    Attributes:
        pockets: the latest :class:`~superex_deploy.onboard.planning.frontiers.Pockets` (None before one was
            needed).
    """

    def __init__(self, min_cells: int, robot_radius_m: float, block_m: float):
        self.min_cells, self.robot_radius_m, self.block_m = int(min_cells), float(robot_radius_m), float(block_m)
        self.pockets: Optional[Pockets] = None
        self._pockets_stamp = -np.inf

    def alive(self, regions: tuple[Frontier, ...], planning: np.ndarray, goal, reach_cells: float, visited,
              travel_cost: Callable[[], np.ndarray], stamp_s: float) -> bool:
        """Whether this step keeps the exploration alive: ``regions`` the step's frontier regions of every size as
        offered (cut to the bounds, blacklisted ones dropped), ``planning`` its map, ``goal`` the goal block (or
        None), ``reach_cells`` the goal tolerance, ``visited`` the goals reached, ``travel_cost()`` the step's
        cost-to-go (called only when needed: a Dijkstra)."""
        if self.min_cells == 0:
            return goal is not None
        regions = tuple(f for f in regions if f.extent >= self.min_cells)
        if self.pockets is None or self.pockets.shape != planning.shape or \
                stamp_s - self._pockets_stamp >= POCKETS_EVERY_S:
            self.pockets, self._pockets_stamp = Pockets(planning, self.robot_radius_m, self.block_m), stamp_s
        regions = open_frontiers(regions, self.pockets)
        if goal is not None and near_frontier(regions, goal, reach_cells):
            return True
        return frontier_left(regions, self.min_cells, travel_cost(), visited)


class ClockWatch:
    """Whether the observations' stamps still advance, for an explorer whose settings count seconds (``timed``:
    a finish delay or a progress timeout); see the module docstring.

    Attributes:
        stalled: the stamps have stood still for :data:`STALLED_CLOCK_STEPS` steps or more (reset by the first that
            advances).
    """

    def __init__(self, timed: bool):
        self.timed = bool(timed)
        self.stalled = False
        self._same = 0
        self._last: Optional[float] = None

    def watch(self, stamp_s: float, finish_after_s: float) -> None:
        """One step's stamp (seconds); warns (:class:`RuntimeWarning`) when the stamps start standing still."""
        self._same = self._same + 1 if self._last is not None and stamp_s == self._last else 0
        self._last = stamp_s
        stalled = self.timed and self._same >= STALLED_CLOCK_STEPS
        if stalled and not self.stalled:
            warnings.warn(f"the observations' stamps have not advanced for {self._same} steps (all {stamp_s} s): "
                          f"the finish delay ({finish_after_s} s) and the progress timeout never elapse on a clock "
                          f"that stands still (simulated time before /clock runs, or a sensor driver without a "
                          f"clock?)", RuntimeWarning, stacklevel=5)
        self.stalled = stalled
