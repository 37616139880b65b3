"""What the exploration node reports: its states (the explorer's and the node's own, :data:`NODE_STATES`), its status
at one moment (:class:`NodeStatus`, the fields of ``superex_msgs/ExplorerStatus``) and what one step of
:class:`~superex_deploy.ros.core.ExplorationCore` hands the node to publish (:class:`StepOutputs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from superex_deploy.messages import Command, MapFrame, Observation

__all__ = ["StepOutputs", "NodeStatus", "PAUSED", "WAITING_FOR_INPUT", "NODE_STATES"]

PAUSED = "paused"
"""The operator paused the exploration: no step runs, no goal is sent."""
WAITING_FOR_INPUT = "waiting_for_input"
"""An input the node needs is missing or stale (the reason says which)."""
NODE_STATES = ("waiting_for_scan", "exploring", "no_reachable_frontier", "returning", "done", PAUSED,
               WAITING_FOR_INPUT)
"""Every ``state`` of the status: the explorer's :data:`~superex_deploy.messages.STATUSES` and the node's own two."""


@dataclass(frozen=True)
class StepOutputs:
    """What one step gives the node to publish.

    Attributes:
        command: the explorer's :class:`~superex_deploy.messages.Command`.
        observation: the observation it answered.
        state, reason: the node's state and why (the command's status and reason, or the node's own).
        goal_changed: the goal differs from the last one sent (publish it); a goal that went away is not a change.
        received_s: ``time.perf_counter()`` when the scan was received (the latency's start).
        frame: the explorer's map frame at this step (its grid grows).
    """

    command: Command
    observation: Observation
    state: str
    reason: str
    goal_changed: bool
    received_s: float
    frame: MapFrame


@dataclass
class NodeStatus:
    """The node's status at one moment (``superex_msgs/ExplorerStatus``'s fields, seconds and metres).

    Attributes:
        stamp_s: when (the node's clock).
        state, reason: see :data:`NODE_STATES`.
        finished: the explorer's ``finished`` at its latest step.
        goal_xy: the latest goal sent, or None.
        step: the explorer's steps.
        known_area_m2, free_area_m2: what its map knows, and holds free.
        frontiers: frontier regions at the latest step.
        latency_s: scan received -> goal published at the latest step (NaN before any).
        scan_age_s, map_age_s, tf_age_s, prediction_age_s: ages of the newest inputs and of the prediction (NaN
            where there is none).
        stage_s: seconds per stage of the latest step.
        scans_received, scans_dropped, steps_skipped: counters (dropped: replaced by a newer one before a step read
            them, or refused; skipped: steps not run for want of an input).
    """

    stamp_s: float
    state: str
    reason: str
    finished: bool = False
    goal_xy: Optional[tuple[float, float]] = None
    step: int = 0
    known_area_m2: float = 0.0
    free_area_m2: float = 0.0
    frontiers: int = 0
    latency_s: float = math.nan
    scan_age_s: float = math.nan
    map_age_s: float = math.nan
    tf_age_s: float = math.nan
    prediction_age_s: float = math.nan
    stage_s: dict = field(default_factory=dict)
    scans_received: int = 0
    scans_dropped: int = 0
    steps_skipped: int = 0
