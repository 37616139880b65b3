"""One step's exchange: the :class:`Observation` the robot sends and the :class:`Command` the explorer answers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from superex_deploy.messages.frame import Pose2D
from superex_deploy.messages.limits import check_stamp
from superex_deploy.messages.occupancy import OccupancyGridMessage, PoseCovariance
from superex_deploy.messages.sensors import LaserScan, SpadFrame

__all__ = ["Observation", "Command", "STATUSES", "WAITING_FOR_SCAN", "EXPLORING", "NO_REACHABLE_FRONTIER",
           "RETURNING", "DONE"]

WAITING_FOR_SCAN = "waiting_for_scan"
"""No observation so far held a valid measurement: the map is empty, no goal, not finished."""
EXPLORING = "exploring"
"""A frontier goal is set."""
NO_REACHABLE_FRONTIER = "no_reachable_frontier"
"""No frontier goal, but ``finish_after_s`` has not elapsed yet: the map may still reopen."""
RETURNING = "returning"
"""Exploration is over and the robot drives back to its start (``return_to_start``)."""
DONE = "done"
"""Finished: nothing is left to explore (and, with ``return_to_start``, the robot is back or cannot get back)."""
STATUSES = (WAITING_FOR_SCAN, EXPLORING, NO_REACHABLE_FRONTIER, RETURNING, DONE)
"""Every value of :attr:`Command.status`."""


@dataclass(frozen=True, eq=False)
class Observation:
    """What the robot measures at one step: everything :meth:`superex_deploy.onboard.Explorer.step` receives.

    Attributes:
        stamp_s: time stamp (seconds; see :func:`check_stamp`: finite, in ``[0, MAX_STAMP_S]``).
        pose: the robot's pose in the map frame (where both scans were taken): the localisation's estimate.
        scan: the line-of-sight scan, or None when ``occupancy_grid`` is given (a map from SLAM replaces it).
        spad: the SPAD frame, or None (no NLOS sensing this step).
        pose_covariance: the pose estimate's uncertainty (``geometry_msgs/PoseWithCovariance``), or None: the pose
            is taken as exact.
        occupancy_grid: the map published by SLAM or a costmap (``nav_msgs/OccupancyGrid``), or None. When given,
            the explorer takes its line-of-sight map from it instead of integrating ``scan``; SPAD frames are still
            processed on top of it.
    """

    stamp_s: float
    pose: Pose2D
    scan: Optional[LaserScan]
    spad: Optional[SpadFrame] = None
    pose_covariance: Optional[PoseCovariance] = None
    occupancy_grid: Optional[OccupancyGridMessage] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stamp_s", check_stamp("stamp_s", self.stamp_s))
        if not isinstance(self.pose, Pose2D):
            raise ValueError(f"pose must be a Pose2D, got {type(self.pose).__name__}")
        if self.scan is None and self.occupancy_grid is None:
            raise ValueError("scan must be a LaserScan (or None when an occupancy_grid is given), got None")
        if self.scan is not None and not isinstance(self.scan, LaserScan):
            raise ValueError(f"scan must be a LaserScan, got {type(self.scan).__name__}")
        if self.pose_covariance is not None and not isinstance(self.pose_covariance, PoseCovariance):
            raise ValueError(f"pose_covariance must be a PoseCovariance or None, got "
                             f"{type(self.pose_covariance).__name__}")
        if self.occupancy_grid is not None and not isinstance(self.occupancy_grid, OccupancyGridMessage):
            raise ValueError(f"occupancy_grid must be an OccupancyGridMessage or None, got "
                             f"{type(self.occupancy_grid).__name__}")
        if self.spad is not None and not isinstance(self.spad, SpadFrame):
            raise ValueError(f"spad must be a SpadFrame or None, got {type(self.spad).__name__}")


@dataclass(frozen=True, eq=False)
class Command:
    """What the explorer answers to one observation.

    Attributes:
        stamp_s: the observation's time stamp (seconds).
        goal_xy: map-frame goal (metres), or None (no goal: see ``finished``).
        goal_rc: the goal cell ``(row, col)``, or None.
        path_xy: float64 ``[N, 2]`` map-frame waypoints (metres) from the robot's cell to the goal (cell centres;
            empty without a goal).
        path_rc: int64 ``[N, 2]`` the same waypoints as cells.
        finished: True when the explorer's map holds known cells and no reachable frontier has been left for
            the explorer's ``finish_after_s`` seconds of the observations' clock (0 by default: at once): the
            exploration is over. False while a goal is set, and also without a goal while the map is still empty
            (no observation so far had a valid reading): the next observation may see something. With
            ``return_to_start``, True only once the robot is back at its start (or the start cannot be reached):
            ``status`` is then ``"done"``.
        new_goal: True when the goal was chosen at this step.
        prediction: the newest predicted map (see :class:`superex_deploy.onboard.types.Prediction`), or None when
            the planner has not needed one yet.
        prediction_step: the step whose map the prediction was made from, or -1.
        step: the explorer's step counter (0 for the first observation).
        timings_s: seconds spent per stage of this step (see :data:`superex_deploy.onboard.explorer.STAGES`).
        prediction_age_steps: steps since the map the prediction was made from (``step - prediction_step``: 0
            when it is this step's own), or None without a prediction.
        prediction_age_s: seconds since that map, between the observations' time stamps (``stamp_s`` minus the
            stamp of step ``prediction_step``), or None without a prediction. With a never-waiting schedule this is
            how stale the map the planner read is, on the robot's clock.
        status: what the robot should do, one of :data:`STATUSES`: ``"waiting_for_scan"`` (nothing valid measured
            yet), ``"exploring"`` (drive to the goal), ``"no_reachable_frontier"`` (no goal yet: wait, the map may
            reopen), ``"returning"`` (drive to the goal: the start pose), ``"done"`` (stop; ``finished`` is True).
        reason: why no goal was given (``"no valid measurement yet"``, ``"no frontier left"``, ``"no frontier inside
            the bounds"``, ``"every frontier blacklisted"``, ``"no frontier reachable"``, ``"back at the start"``,
            ``"start unreachable"``); empty while a goal is given.
    """

    stamp_s: float
    goal_xy: Optional[tuple[float, float]]
    goal_rc: Optional[tuple[int, int]]
    path_xy: np.ndarray
    path_rc: np.ndarray
    finished: bool
    new_goal: bool
    prediction: Optional[object] = None
    prediction_step: int = -1
    step: int = 0
    timings_s: dict = field(default_factory=dict)
    prediction_age_steps: Optional[int] = None
    prediction_age_s: Optional[float] = None
    status: str = EXPLORING
    reason: str = ""
