"""The explorer's configuration (:class:`ExplorerConfig`): the parts of the onboard loop a user chooses, composed of
each part's own frozen config (motion, prediction schedule and reuse, occupancy, scan matching, map growth)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import cells_at_least, check_real
from superex_deploy.onboard.mapping.growth import MapGrowth
from superex_deploy.onboard.mapping.log_odds import OccupancyConfig
from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
from superex_deploy.onboard.planning.bounds import ExplorationBounds
from superex_deploy.onboard.planning.goal_policy import GoalPolicy
from superex_deploy.onboard.planning.motion import MotionConfig
from superex_deploy.onboard.prediction.reuse import PredictionReuse
from superex_deploy.onboard.prediction.schedule import PredictionSchedule

__all__ = ["ExplorerConfig", "check_parts"]


_PARTS = (("goal_policy", GoalPolicy, "a", True, False), ("growth", MapGrowth, "a", True, True),
          ("occupancy", OccupancyConfig, "an", True, False), ("scan_matching", ScanMatchingConfig, "a", True, False),
          ("motion", MotionConfig, "a", False, False), ("prediction", PredictionSchedule, "a", False, False),
          ("reuse", PredictionReuse, "a", False, False))
"""(field, its config class, the article of its name, a dict of its fields accepted, None accepted)."""


@dataclass(frozen=True)
class ExplorerConfig(JsonConfig):
    """Onboard exploration parameters.

    Attributes:
        motion: robot radius, proximity cost, goal tolerance (``step_m`` is how far the robot is expected to
            drive per step; the explorer follows wherever it actually stops).
        frontier_min_m: a frontier region's size in metres is its cells times the cell size; regions smaller than
            this (:meth:`frontier_min_cells` cells) are offered to the planner only when no larger region gives a
            goal (MapEx drops them: 10 cells of 0.1 m, 1 m). They are kept as a last tier because a room whose
            open door is seen edge-on shows fewer frontier cells, and dropping them would stop such an episode at
            its first step (docs/benchmarks/exploration.md).
        prediction: when the predictor runs (:class:`PredictionSchedule`).
        reuse: what the explorer keeps of its last prediction
            (:class:`~superex_deploy.onboard.prediction.reuse.PredictionReuse`: re-predict only when the map
            changed enough, and only a crop around the change).
        occupancy: the map's log-odds parameters and the SLAM map's thresholds
            (:class:`~superex_deploy.onboard.mapping.log_odds.OccupancyConfig`; a dict of its fields is accepted, as a
            recording's metadata holds it).
        growth: None (the default): the grid is the frame the explorer was built with, and what lies beyond it is
            dropped; a :class:`~superex_deploy.onboard.mapping.growth.MapGrowth`: the grid grows as scans, SPAD
            frames or SLAM maps reach beyond it (a robot entering a building of unknown size; start from a small
            frame around the start, e.g. :meth:`~superex_deploy.messages.MapFrame` of 10 m). Cells in commands
            (``goal_rc``, ``path_rc``) are then the grid's of that step (:attr:`Explorer.frame`); the map-frame
            fields (``goal_xy``, ``path_xy``) never move.
        finish_after_s: how long (seconds, on the observations' clock) no reachable frontier region of at least
            ``finish_frontier_m`` must have been left before a step says ``finished`` (explore_lite's progress
            timeout); never while one is left. The default, 5 s, is what a robot needs: a SLAM map published every
            few seconds, or a doorway closed by one noisy scan, reopens a frontier before exploration is declared
            over. 0: at the first step without one (the simulated benchmarks: :meth:`for_simulation`).
        finish_frontier_m: the smallest frontier region (its cells times the cell size, metres) that keeps a run
            alive: smaller regions are still offered as goals (the last tiers) while the finish timer runs, but a
            wall's face cell flickering through the unknown band of the log-odds map makes a region of one cell,
            which would otherwise restart the timer for ever. 0: any goal keeps the run alive, and a goal found
            in any tier does (the rule of the simulated benchmarks, whose maps never flicker).
        scan_matching: the correlative scan-to-map matcher
            (:class:`~superex_deploy.onboard.mapping.scan_matching.ScanMatchingConfig`, on by default; it acts only on an
            observation that carries a pose covariance and a scan: the scan, the SPAD frame and the planning then
            start from the corrected pose when the match passes its acceptance rule).
        bounds: None (the default): explore everything reachable; an
            :class:`~superex_deploy.onboard.planning.bounds.ExplorationBounds` (a polygon in map-frame metres; a
            sequence of ``(x, y)`` points or a dict of its fields is accepted): frontiers outside it are ignored and
            exploration is finished when no reachable frontier is left inside it. The first observation's position
            must lie inside (else the step raises ``ValueError``).
        return_to_start: once exploration is finished, drive back to the first observation's position before
            saying ``finished`` (:mod:`~superex_deploy.onboard.status`; commands say ``status="returning"``).
        goal_policy: when a goal is blacklisted and when a better goal replaces it
            (:class:`~superex_deploy.onboard.planning.goal_policy.GoalPolicy`; a dict of its fields is accepted).
    """

    motion: MotionConfig = field(default_factory=MotionConfig)
    frontier_min_m: float = 1.0
    prediction: PredictionSchedule = field(default_factory=PredictionSchedule)
    reuse: PredictionReuse = field(default_factory=PredictionReuse)
    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    scan_matching: ScanMatchingConfig = field(default_factory=ScanMatchingConfig)
    finish_after_s: float = 5.0
    finish_frontier_m: float = 0.5
    growth: Optional[MapGrowth] = None
    bounds: Optional[ExplorationBounds] = None
    return_to_start: bool = False
    goal_policy: GoalPolicy = field(default_factory=GoalPolicy)

    def __post_init__(self) -> None:
        if isinstance(self.bounds, dict):
            object.__setattr__(self, "bounds", ExplorationBounds(**self.bounds))
        elif self.bounds is not None and not isinstance(self.bounds, ExplorationBounds):
            object.__setattr__(self, "bounds", ExplorationBounds(self.bounds))
        if not isinstance(self.return_to_start, bool):
            raise ValueError(f"return_to_start must be true or false, got {self.return_to_start!r}")
        # The composed parts; those a recording's metadata holds as dicts are built from them.
        for name, kind, article, from_dict, optional in _PARTS:
            value = getattr(self, name)
            if from_dict and isinstance(value, dict):
                value = kind(**value)
                object.__setattr__(self, name, value)
            if not isinstance(value, kind) and not (optional and value is None):
                raise ValueError(f"{name} must be {article} {kind.__name__}{' or None' if optional else ''}, got "
                                 f"{type(value).__name__}")
        if isinstance(self.finish_after_s, bool) or not isinstance(self.finish_after_s, (int, float)) \
                or not (np.isfinite(self.finish_after_s) and self.finish_after_s >= 0.0):
            raise ValueError(f"finish_after_s must be a finite number of seconds >= 0, got {self.finish_after_s!r}")
        object.__setattr__(self, "frontier_min_m", check_real("frontier_min_m", self.frontier_min_m, 0.0,
                                                              low_open=True))
        object.__setattr__(self, "finish_frontier_m", check_real("finish_frontier_m", self.finish_frontier_m, 0.0))
        if self.bounds is not None:
            self.bounds.check_holds(self.motion.robot_radius_m)

    def for_simulation(self) -> "ExplorerConfig":
        """This configuration with the rules of the simulated benchmarks (:class:`~superex_deploy.sim.exploration.
        ExplorationConfig`'s default and every profile's episode configuration): ``finished`` at the first step
        without a goal (``finish_after_s`` and ``finish_frontier_m`` 0), a locked goal kept until it is reached
        (``goal_policy.drop_resolved_m`` None: MapEx's locked frontier) and given up once reached
        (``goal_policy.confirm_visit_m`` None). There the pose is exact and the map is
        made of exact scans every step: a frontier never flickers and a map is never stale, and the paper's
        benchmark rows were measured so."""
        return replace(self, finish_after_s=0.0, finish_frontier_m=0.0,
                       goal_policy=replace(self.goal_policy, drop_resolved_m=None, confirm_visit_m=None))

    @property
    def simulated_rules(self) -> bool:
        """Whether ``finished`` follows the simulated benchmarks' rule (``finish_frontier_m`` 0: any goal keeps the
        run alive)."""
        return self.finish_frontier_m == 0.0

    def finish_frontier_cells(self, resolution_m: float) -> int:
        """The fewest cells of a frontier region that keeps a run alive on a grid of ``resolution_m`` metres per cell
        (``finish_frontier_m``; 0 when that is 0: any goal keeps it alive)."""
        if self.finish_frontier_m == 0.0:
            return 0
        return max(1, cells_at_least(self.finish_frontier_m, check_real("resolution_m", resolution_m, 0.0,
                                                                        low_open=True)))

    def frontier_min_cells(self, resolution_m: float) -> int:
        """The fewest cells of a frontier region offered in the first tier on a grid of ``resolution_m`` metres per
        cell: those that reach ``frontier_min_m`` (10 at 0.1 m, 20 at 0.05 m, 40 at 0.025 m), at least one."""
        return max(1, cells_at_least(self.frontier_min_m, check_real("resolution_m", resolution_m, 0.0,
                                                                     low_open=True)))

    def footprint_cells(self, pose_covariance, resolution_m: float) -> Optional[float]:
        """The radius (cells of ``resolution_m`` metres) of the footprint cleared at the robot, the robot's body
        being free space (:meth:`~superex_deploy.onboard.mapping.mapper.Mapper.clear_footprint`; None: clearing
        off): the robot radius less ``footprint_margin_sigmas`` position sigmas of ``pose_covariance`` (a
        :class:`~superex_deploy.messages.PoseCovariance`, or None: an exact pose)."""
        if not self.occupancy.footprint_clearing:
            return None
        radius_m = self.motion.robot_radius_m
        if pose_covariance is not None:
            radius_m -= self.occupancy.footprint_margin_sigmas * pose_covariance.sigma_xy_m
        return max(radius_m, 0.0) / resolution_m


def check_parts(frame, planner, predictor, spad_processing, cfg) -> None:
    """Refuse the parts of an :class:`~superex_deploy.onboard.explorer.Explorer` of the wrong kind, naming the first.

    Raises:
        ValueError: ``frame`` not a :class:`~superex_deploy.messages.MapFrame`, ``planner`` not a
            :class:`~superex_deploy.onboard.types.Planner`, ``predictor`` without ``predict``, ``spad_processing``
            neither None nor a :class:`~superex_deploy.onboard.nlos.processing.SpadProcessing`, ``cfg`` not an
            :class:`ExplorerConfig`.
    """
    from superex_deploy.messages import MapFrame
    from superex_deploy.onboard.nlos.processing import SpadProcessing
    from superex_deploy.onboard.types import Planner

    if not isinstance(frame, MapFrame):
        raise ValueError(f"frame must be a MapFrame, got {type(frame).__name__}")
    if not isinstance(planner, Planner):
        raise ValueError(f"planner must be a Planner instance (see planners.make_planner), got "
                         f"{type(planner).__name__}")
    if not callable(getattr(predictor, "predict", None)):
        raise ValueError(f"predictor must have a predict(observed, extra) method, got {type(predictor).__name__}")
    if spad_processing is not None and not isinstance(spad_processing, SpadProcessing):
        raise ValueError(f"spad_processing must be a SpadProcessing or None, got {type(spad_processing).__name__}")
    if not isinstance(cfg, ExplorerConfig):
        raise ValueError(f"cfg must be an ExplorerConfig, got {type(cfg).__name__}")
