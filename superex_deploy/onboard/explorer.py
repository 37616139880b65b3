"""The onboard exploration loop: observations in, commands out, nothing but what the robot measures.

:meth:`Explorer.step`, with the robot at cell ``p_t``:

1. **scan**: the scan is integrated into the log-odds map (:mod:`~superex_deploy.onboard.mapping.mapper`; invalid
   readings skipped), or a SLAM map replaces the line-of-sight layer; a growing map first moves to a grid that
   holds what the step can touch (:mod:`~superex_deploy.onboard.mapping.growth`);
2. **map_update**: a SPAD frame is processed (:class:`~superex_deploy.onboard.nlos.processing.SpadProcessing`,
   margins widened by the pose covariance, the map's walls supporting the carving's wall normals): carved cells join
   the map as evidence towards free, the back-projection evidence is kept for the predictor;
3. **frontiers**: frontier regions of the map (those shorter than ``frontier_min_m`` only as a last tier);
4. **path / scoring / prediction**: a locked goal is kept until reached (within ``goal_reached_m`` and in line of
   sight, :func:`~superex_deploy.onboard.planning.goal_choice.goal_reached`), let go by the planner, or blocked with
   no other path (MapEx's locked frontier); otherwise the planner chooses among the frontiers offered in tiers
   (:func:`~superex_deploy.onboard.planning.goal_choice.choose_goal`) from the Dijkstra cost-to-go, calling the
   predictor lazily. Cells free only by carving count for coverage and the prediction, and for planning only as
   ``MotionConfig.drive_carved`` allows (by default while the pose is exact). Steps 3-4 run on blocks of the map on
   one finer than ``MotionConfig.planning_cell_m`` (:mod:`~superex_deploy.onboard.planning.coarse`).

The predictor runs inline, in a worker thread or on a simulated clock (:class:`PredictionSchedule`), on the map or a
crop (:class:`~superex_deploy.onboard.prediction.reuse.PredictionReuse`), so that a step fits the sensor's frame
on a small CPU; the numba threads follow the cores given
(:class:`~superex_deploy.onboard.prediction.inference.ThreadBudget`).

The :class:`~superex_deploy.messages.Command` holds the goal, the path and a status (:mod:`.status`: bounds,
blacklist, return to the start). Exploration is **finished** when the map holds known cells and nothing has kept it
alive for ``finish_after_s`` seconds (:mod:`.finishing`: a reachable frontier worth the name; with
``return_to_start``, once back at the start); while the map is empty a step answers no goal and not finished. A seed makes it deterministic (it feeds the planner's generator).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Optional

import numpy as np

from superex_deploy.onboard.config import ExplorerConfig, check_parts
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.finishing import ClockWatch, FinishRule
from superex_deploy.onboard.mapping.growth import Regrid, regrid_for
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.mapping.blocks import coarsen_observed
from superex_deploy.onboard.planning.coarse import CoarsePrediction, PlanningGrid
from superex_deploy.onboard.locked_goal import LockedGoal
from superex_deploy.onboard.planning.motion import PlanningMap, check_wall_reach, planning_map
from superex_deploy.onboard.planning.bounds import reachable_goals
from superex_deploy.onboard.planning.goal_choice import choose_goal, unreached
from superex_deploy.onboard.prediction.reuse import PredictionReuse, merge_with_map
from superex_deploy.onboard.prediction.schedule import LazyPrediction, PredictionSchedule, set_numba_threads
from superex_deploy.onboard.prediction.stepping import StepPredictions
from superex_deploy.onboard.mapping.scan_matching import ScanMatch, ScanMatcher
from superex_deploy.onboard.types import (FREE, UNKNOWN, Frontier, MapPredictor, Planner, PlanningContext,
                                          Prediction)
from superex_deploy.onboard.status import NO_MEASUREMENT, Mission
from superex_deploy.messages import DONE, EXPLORING, RETURNING, WAITING_FOR_SCAN, Command, MapFrame, Observation
from superex_deploy.onboard.nlos.processing import SpadProcessing

__all__ = ["STAGES", "ExplorerConfig", "Explorer", "PredictionSchedule", "PredictionReuse", "merge_with_map"]

STAGES = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")
"""The stages of a step whose wall-clock time :attr:`Command.timings_s` reports (seconds)."""



class Explorer:
    """Chooses where to go next from the robot's measurements alone.

    Build one per episode; feed it one :class:`~superex_deploy.messages.Observation` per step and drive along the
    :class:`~superex_deploy.messages.Command` it returns, until one says ``finished`` (the map holds known cells and
    no reachable frontier is left; no goal while the map is still empty is not finished). One caller at a time: a
    :meth:`step` called while another runs (another thread) raises ``RuntimeError`` instead of interleaving them.

    Args:
        frame: the grid the explorer keeps its map in (shape, resolution, origin).
        planner: a :class:`~superex_deploy.onboard.types.Planner` (``planners.make_planner(name)``); reset here.
        predictor: a :class:`~superex_deploy.onboard.types.MapPredictor` (observed, lama_los, lama_bp, ...).
        spad_processing: SPAD processing for observations that carry a SPAD frame; None: SPAD frames are ignored.
        cfg: onboard parameters.
        seed: seed of the generator handed to the planner.
        cores: the cores the explorer may use (None: the process's affinity): its steps run on ``budget.control_threads``
            numba threads, its worker on ``budget.worker_threads`` (``pipeline.make_predictor(..., cores=...)``).

    Attributes:
        frame, planner, predictor, spad_processing, cfg: as given.
        mapper: the explorer's map (:class:`~superex_deploy.onboard.mapping.mapper.Mapper`; read it, do not modify it).
        observed: int8 ``[H, W]`` the map after the latest step (UNKNOWN / FREE / OCCUPIED; carved cells FREE).
        planning_grid: the blocks the planning runs on
            (:class:`~superex_deploy.onboard.planning.coarse.PlanningGrid`: the map's own cells unless the map is
            finer than ``cfg.motion.planning_cell_m``); ``frontiers``, ``goal`` and ``path`` are in its blocks.
        planning_observed: int8 the map the latest step planned on, on those blocks (read it, do not modify it).
        frontiers: the latest step's frontier regions (of the map the planning read: without carved-only cells
            when those may not be driven on, see the module docstring).
        goal, path: the locked goal block (None: none) and the blocks to it (:mod:`.locked_goal`); the command's
            ``goal_rc`` is the goal's free cell nearest its centre, its ``path_rc`` the cells through the path.
        pose_estimate: the pose the latest step integrated and planned from (the observation's, or the scan
            matcher's correction of it; None before the first step).
        scan_match: the latest step's :class:`~superex_deploy.onboard.mapping.scan_matching.ScanMatch`, or None (no
            covariance, or a SLAM map).
        steps: observations processed so far.
        finished: whether the latest step found the exploration finished (see above; with ``cfg.return_to_start``
            only once back at the start).
        status: the latest command's status (:data:`~superex_deploy.messages.STATUSES`).
        mission: the :class:`~superex_deploy.onboard.status.Mission`: bounds, blacklist, return to the start.
        reusing: the :class:`~superex_deploy.onboard.prediction.reuse.ReusingPredictor` that wraps the predictor
            when ``cfg.reuse`` keeps anything (its counters say how often the network ran), else None.
        step_predictor: what the steps call: ``reusing``, else the predictor at the map's scale.
        budget: the :class:`~superex_deploy.onboard.prediction.inference.ThreadBudget` of ``cores``.
        frontier_min_cells: the first tier's smallest frontier region on this grid (cells; ``cfg.frontier_min_m``).
        scheduled: the :class:`~superex_deploy.onboard.prediction.schedule.ScheduledPredictions` that runs the
            predictor when the schedule is not ``inline`` (its ``blocking_waits`` count the steps that waited for an
            unfinished prediction), else None.
    """

    def __init__(self, frame: MapFrame, planner: Planner, predictor: MapPredictor,
                 spad_processing: Optional[SpadProcessing] = None, cfg: ExplorerConfig = ExplorerConfig(),
                 seed: int = 0, cores: Optional[int] = None):
        check_parts(frame, planner, predictor, spad_processing, cfg)
        self.planning_grid = PlanningGrid.for_map(frame.shape, frame.resolution_m, cfg.motion.planning_cell_m)
        self._blocks_frame = self.planning_grid.frame_of(frame)  # the blocks as a map frame (the mission's)
        block_m = self.planning_grid.block_m
        check_wall_reach(cfg.motion, block_m)  # a planning grid too fine for the motion settings: refused now
        self.frame, self.planner, self.predictor, self.cfg = frame, planner, predictor, cfg
        self.spad_processing = spad_processing
        # A learned model runs at the resolution it was trained at (the map pooled or repeated to it, its answer
        # brought back): a grid it cannot serve is refused here, before the first step.
        self._predictions = StepPredictions(self, predictor, cfg, frame.resolution_m, cores)
        if spad_processing is not None:
            spad_processing.check_resolution(frame.resolution_m)
        self.mapper = Mapper(frame.shape, cfg.occupancy)
        self.scan_matcher = ScanMatcher(cfg.scan_matching)
        self.pose_estimate = None
        self.scan_match: Optional[ScanMatch] = None
        self.observed = self.mapper.observed()
        self.planning_observed = coarsen_observed(self.observed, self.planning_grid.factor)
        self.frontiers: tuple[Frontier, ...] = ()
        self.steps = 0
        self.finished = False
        self.mission = Mission(cfg)
        self.status = WAITING_FOR_SCAN
        self._stepping = threading.Lock()  # held by the running step(): one caller at a time
        self._rng = np.random.default_rng(seed)
        self.frontier_min_cells = cfg.frontier_min_cells(block_m)
        self.finish_cells = cfg.finish_frontier_cells(block_m)  # 0: the simulated rule (any goal keeps it alive)
        self.finish_rule = FinishRule(self.finish_cells, cfg.motion.robot_radius_m, block_m)
        self.clock = ClockWatch(cfg.finish_after_s > 0 or cfg.goal_policy.no_progress_s is not None)
        resolved = cfg.goal_policy.drop_resolved_m
        self._resolved_cells = None if resolved is None else resolved / block_m
        self._robot_rules = resolved is not None or cfg.goal_policy.confirm_visit_m is not None or bool(
            self.finish_cells)  # the rules that read every frontier region of a step
        self._regions: tuple[Frontier, ...] = ()  # the step's frontier regions of every size, as offered
        self._plan_map: Optional[PlanningMap] = None  # the step's cost-to-go, where the step computed one
        self._last_grid = None  # the SLAM map of the step before: a step whose map is the same one is not fresh
        self._fresh = True  # the step's map holds a measurement of this step (its scan, or a new SLAM map)
        self._reach_cells = cfg.motion.goal_reached_m / block_m
        self._radius_cells = cfg.motion.robot_radius_m / block_m
        self._locked = LockedGoal(self._reach_cells, self._radius_cells)
        self._pose_exact = True  # the latest observation carried no pose covariance
        self._stamps: list[float] = []  # the observations' stamps, per step: the prediction's age in seconds
        self._closed = False
        planner.reset()
        if spad_processing is not None:
            spad_processing.reset()

    reusing = property(lambda self: self._predictions.reusing, doc="See the class docstring.")
    step_predictor = property(lambda self: self._predictions.step_predictor, doc="See the class docstring.")
    budget = property(lambda self: self._predictions.budget, doc="See the class docstring.")
    scheduled = property(lambda self: self._predictions.scheduled, doc="See the class docstring.")

    @property
    def goal(self) -> Optional[tuple[int, int]]:
        """The locked goal block, or None (:meth:`drop_goal` lets it go)."""
        return self._locked.goal

    @property
    def path(self) -> list[tuple[int, int]]:
        """Blocks from the robot to the goal."""
        return self._locked.path

    @property
    def visited_goals(self) -> frozenset:
        """Goal cells reached so far whose frontier did not resolve (they are not offered again)."""
        return frozenset(self._locked.visited)

    def frontier_candidates(self, pose_rc) -> tuple[Frontier, ...]:
        """The frontier regions (in :attr:`planning_grid` blocks), of every size, :meth:`step` would offer a planner
        with the robot at map cell ``pose_rc``: not reached already (:func:`~.planning.goal_choice.goal_reached`),
        their goal no goal reached before nor next to one, in ``find_frontiers`` order (``()`` before the first
        observation). For a goal chosen outside the explorer (a learning agent): one of these is kept.

        Raises:
            ValueError: a cell outside the map.
        """
        pose = (int(pose_rc[0]), int(pose_rc[1]))
        if not (0 <= pose[0] < self.frame.shape[0] and 0 <= pose[1] < self.frame.shape[1]):
            raise ValueError(f"robot cell {pose} lies outside the map of shape {self.frame.shape}")
        regions = self.mission.admit(find_frontiers(self.planning_observed, 1), self._blocks_frame,
                                     self._stamps[-1] if self._stamps else 0.0)
        return unreached(regions, self.planning_observed != FREE, self.planning_grid.block(pose), self._reach_cells,
                         self._locked.visited)

    def return_to_start(self) -> None:
        """Stop exploring and drive back to the start from the next step on (an operator's command:
        :meth:`~superex_deploy.onboard.status.Mission.go_home`)."""
        if self.mission.go_home():
            self._locked.release()
            self.finished = False

    def set_bounds(self, bounds) -> None:
        """Bound the exploration from the next step on (an operator's polygon, or None:
        :meth:`~superex_deploy.onboard.status.Mission.set_bounds`); the locked goal is let go when outside.

        Raises:
            ValueError: a polygon :class:`ExplorerConfig` refuses, or one that does not hold the robot.
        """
        self.cfg = self.mission.set_bounds(bounds, self.pose_estimate)
        if self.goal is not None and self.cfg.bounds is not None and not self.cfg.bounds.contains_xy(
                [self._blocks_frame.centre_xy(self.goal)])[0]:
            self._locked.release()

    def drop_goal(self) -> None:
        """Let go of the locked goal and its path: the next :meth:`step` asks the planner again (the goal does not
        count as reached). For a goal chosen outside the explorer: give the choice to the planner, then call this."""
        self._locked.release()

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` the NLOS evidence the predictor reads: None without SPAD processing, zeros with it
        until the first SPAD frame arrives (:meth:`~.prediction.stepping.StepPredictions.evidence`)."""
        return self._predictions.evidence(self.spad_processing, self.frame.shape)

    def predict(self) -> Prediction:
        """What the planners read at the latest step: inline, the prediction of that step's map (computed
        once per step; a planner that asked already paid); otherwise, the newest applied prediction merged
        with that map. For evaluation: it does not change what :class:`Command` reports.

        Raises:
            RuntimeError: before the first observation.
        """
        return self._predictions.look()

    def close(self) -> None:
        """Stop the prediction worker; a later :meth:`step` raises ``RuntimeError("this explorer was closed")``.
        From another thread while a step runs (a ROS shutdown callback), it waits for that step. Idempotent."""
        self._closed = True  # a step that has not started yet refuses
        with self._stepping:  # a step that has started finishes first
            self._predictions.close()

    def follow_recorded_predictions(self, prediction_steps) -> None:
        """For a replay: apply at step ``t`` the prediction of the map of step ``prediction_steps[t]`` (a recording's
        ``prediction_step`` per command), computed inline, instead of the schedule's own timing, so that a
        ``free`` run (whose predictions landed when the robot's CPU finished them) replays exactly. Call it before
        the first step.

        Raises:
            ValueError: an inline schedule (its predictions are the steps' own), or steps outside ``-1..t``.
            RuntimeError: after the first step.
        """
        self._predictions.follow(prediction_steps, self.steps)

    def __enter__(self) -> "Explorer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    step_prediction = property(lambda self: None if self._predictions.current is None else
                               self._predictions.current.value,
                               doc="The latest step's prediction if anything has computed it, else None (never "
                                   "computes).")

    def _pose_cell(self, obs: Observation) -> tuple[int, int]:
        return self.frame.locate(obs.pose.x, obs.pose.y)[1]

    def step(self, obs: Observation) -> Command:
        """Integrate one observation and return where to go (``finished``: see :class:`Explorer`).

        Raises:
            ValueError: not an Observation, a pose outside the map, a SPAD frame that does not match the sensor
                model.
            RuntimeError: another call of ``step`` is running (one caller at a time), the explorer was closed, or
                the planner returned a goal that no path reaches (a planner bug).
        """
        if not isinstance(obs, Observation):
            raise ValueError(f"step() takes an Observation, got {type(obs).__name__}")
        if self._closed:
            raise RuntimeError("this explorer was closed")
        if not self._stepping.acquire(blocking=False):
            if self._closed:  # close() holds the lock while it waits for a running step and stops the worker
                raise RuntimeError("this explorer was closed")
            raise RuntimeError("Explorer.step() is already running (called from another thread): an explorer takes "
                               "one caller at a time; serialise the calls or use one explorer per thread")
        import numba

        callers_threads = numba.get_num_threads()
        try:
            set_numba_threads(self.budget.control_threads)
            return self._step(obs)
        finally:
            numba.set_num_threads(callers_threads)
            self._stepping.release()

    def _step(self, obs: Observation) -> Command:
        if self._closed:
            raise RuntimeError("this explorer was closed")
        # Every check comes before anything is integrated: a refused observation leaves the explorer as it was.
        regrid = regrid_for(self.frame, obs, self.spad_processing, self.cfg.growth, self.planning_grid.factor) \
            if self.cfg.growth is not None else None
        if regrid is None:
            pose = self._pose_cell(obs)
        if self._stamps and obs.stamp_s < self._stamps[-1]:
            raise ValueError(f"observation stamps must not go backwards: {obs.stamp_s} s after {self._stamps[-1]} s "
                             f"(a reset simulation clock or a looping bag starts a new exploration: build a new "
                             f"Explorer)")
        if self.spad_processing is not None and obs.spad is not None:
            self.spad_processing.check_frame(obs.spad)
        self.mission.begin(obs.pose.x, obs.pose.y)  # bounds that do not hold the start are refused here
        regrid_wait = 0.0
        if regrid is not None:
            self._regrid(regrid)
            pose = self._pose_cell(obs)
            regrid_wait = self._predictions.regrid_wait_s
        self._pose_exact = obs.pose_covariance is None
        self.clock.watch(obs.stamp_s, self.cfg.finish_after_s)
        self._fresh = obs.occupancy_grid is None or not obs.occupancy_grid.same_map(self._last_grid)
        self._last_grid = obs.occupancy_grid
        timings = dict.fromkeys(STAGES, 0.0)
        t = self.steps

        clock = time.perf_counter()
        footprint = self.cfg.footprint_cells(obs.pose_covariance, self.frame.resolution_m)
        integrated, self.scan_match = self.mapper.integrate_observation(self.frame, obs, footprint, self.scan_matcher)
        if self.scan_match is not None and self.scan_match.accepted:  # the SPAD frame and the plan start from it too
            obs = dataclasses.replace(obs, pose=integrated)
            pose = self._pose_cell(obs)
        self.pose_estimate = obs.pose
        timings["scan"] = time.perf_counter() - clock

        clock = time.perf_counter()
        if self.spad_processing is not None and obs.spad is not None:
            walls = self.mapper.seen_wall if self.spad_processing.reads_map_walls else None
            carved, _ = self.spad_processing(obs.spad, self.frame, obs.pose, self.mapper.known(),
                                             pose_covariance=obs.pose_covariance, map_walls=walls)
            self.mapper.merge_carved(carved)
        observed = self.mapper.observed()
        # The map the planning reads, on the planning grid: carved-only cells are free in it only when they may be
        # driven on.
        drive_carved = self._pose_exact if self.cfg.motion.drive_carved is None else self.cfg.motion.drive_carved
        grid = self.planning_grid
        if grid.factor > 1:
            planning = self.mapper.blocks(grid.factor, include_carved=drive_carved)
        else:
            planning = observed if drive_carved else self.mapper.observed(include_carved=False)
        timings["map_update"] = time.perf_counter() - clock

        clock = time.perf_counter()
        pose_cell, pose = pose, grid.block(pose)
        every = find_frontiers(planning, 1)  # the first tier's are those of frontier_min_cells or more
        frontiers = self.mission.admit(tuple(f for f in every if f.size >= self.frontier_min_cells),
                                       self._blocks_frame, obs.stamp_s)
        self._regions = self.mission.admit(every, self._blocks_frame, obs.stamp_s) if self._robot_rules else ()
        self._plan_map = None
        timings["frontiers"] = time.perf_counter() - clock

        self._stamps.append(obs.stamp_s)
        prediction, waited = self._predictions.begin(t, observed, self.evidence)
        self.observed, self.frontiers = observed, frontiers
        self.planning_observed = planning
        self.steps += 1
        if np.any(observed != UNKNOWN):
            new_goal = self._decide(planning, frontiers, pose,
                                    prediction if grid.factor == 1 else CoarsePrediction(prediction, grid.factor), t,
                                    timings, obs.stamp_s)
        else:  # nothing measured yet (every reading invalid): no goal, and not finished
            new_goal, self.finished, self.mission.no_goal_since = False, False, None
            self.status, self.mission.reason = WAITING_FOR_SCAN, NO_MEASUREMENT
        timings["prediction"] += waited + regrid_wait  # a growth waits for a prediction in progress
        self._predictions.end(t)
        fine = None if grid.factor == 1 or self.goal is None else (  # the map the blocks were made of
            observed if drive_carved else self.mapper.observed(include_carved=False))
        goal_rc, path_rc = grid.on_map(pose_cell, self.goal, self.path, fine)
        latest, latest_step = self._predictions.latest, self._predictions.latest_step
        return Command(stamp_s=obs.stamp_s,
                       goal_xy=None if goal_rc is None else self.frame.centre_xy(goal_rc),
                       goal_rc=goal_rc, path_xy=self.frame.centres_xy(path_rc), path_rc=path_rc,
                       finished=self.finished, new_goal=new_goal, prediction=latest, prediction_step=latest_step,
                       step=t, timings_s=timings, prediction_age_steps=None if latest is None else t - latest_step,
                       prediction_age_s=None if latest is None else obs.stamp_s - self._stamps[latest_step],
                       status=self.status, reason=self.mission.reason)

    def _regrid(self, regrid: Regrid) -> None:
        """Move every per-cell state to the larger grid ``regrid``: the map's layers, the SPAD evidence, the
        predictions kept and in progress, the goal, its path and the goals reached."""
        self._predictions.regrid(regrid)  # the worker first: it may wait for a prediction in progress
        for part in (self.mapper, self.spad_processing):
            if part is not None:
                part.regrid(regrid)
        self.observed = regrid.embed(self.observed, UNKNOWN)
        self.planning_grid, move = self.planning_grid.grown(regrid)  # the same blocks, shifted by whole blocks
        self._blocks_frame = self.planning_grid.frame_of(regrid.frame)
        self.planning_observed = coarsen_observed(self.observed, self.planning_grid.factor)
        self._locked.regrid(move)
        self.frontiers = ()
        self.frame = regrid.frame

    def _decide(self, planning: np.ndarray, frontiers: tuple[Frontier, ...], pose: tuple[int, int],
                prediction: LazyPrediction, t: int, timings: dict, stamp_s: float) -> bool:
        """A step with a map: its goal, path, ``finished`` and status (:mod:`~.status`); whether the goal is new."""
        mission, new_goal = self.mission, False
        if mission.phase == EXPLORING:
            new_goal = self._plan(planning, frontiers, pose, prediction, t, timings, stamp_s)
            if new_goal:  # its progress is timed from now
                mission.tracker.chosen(self._blocks_frame.centre_xy(self.goal), stamp_s)
            alive = self.finish_rule.alive(self.mission.admit(self._regions, self._blocks_frame, stamp_s), planning,
                                           self.goal, self._reach_cells, self._locked.visited,
                                           lambda: self._travel_cost(planning, pose), stamp_s)
            self.finished = mission.settle(alive, stamp_s)
            if self.finished:  # a goal on a region too small to keep the run alive is let go with it
                self._locked.release()
            mission.reason = "" if self.goal is not None else mission.why_no_goal(
                planning, self._blocks_frame, stamp_s, max(self.finish_cells, 1),
                None if self._plan_map is None else self._plan_map.travel_cost,
                self.finish_rule.pockets if self.finish_cells else None)
            if self.finished and self.cfg.return_to_start:
                self._locked.release()
                self.finished = False
                mission.phase = RETURNING
        if mission.phase == RETURNING:
            goal, path = mission.home(planning, pose, self._blocks_frame, self.path, self._reach_cells,
                                      self._radius_cells, stamp_s)
            new_goal = goal is not None and goal != self.goal
            self._locked.goal, self._locked.path = goal, path
            self.finished = mission.phase == DONE
        elif mission.phase == DONE:
            self._locked.release()
            self.finished = True
        self.status = mission.status(self.goal is not None, self.finished)
        return new_goal

    def _travel_cost(self, planning: np.ndarray, pose: tuple[int, int]) -> np.ndarray:
        """The step's cost-to-go from the robot (the one the planning computed, else computed now)."""
        if self._plan_map is None:
            self._plan_map = planning_map(planning, pose, self.planning_grid.block_m, self.cfg.motion)
        return self._plan_map.travel_cost

    def _plan(self, observed: np.ndarray, frontiers: tuple[Frontier, ...], pose: tuple[int, int],
              prediction: LazyPrediction, t: int, timings: dict, stamp_s: float) -> bool:
        """Keep or choose the goal and its path (and let a better one replace it:
        :class:`~.planning.goal_policy.GoalPolicy`); returns whether a new goal was chosen."""
        res, motion = self.planning_grid.block_m, self.cfg.motion
        clock = time.perf_counter()
        not_free = observed != FREE
        wait, plan = self._locked.keep(
            observed, not_free, pose, t, fresh=self._fresh, planner=self.planner, goal_policy=self.cfg.goal_policy,
            regions=self._regions, resolved_cells=self._resolved_cells, resolution_m=res, motion=motion,
            gives_up=lambda goal, path: self.mission.gives_up(self._blocks_frame.centre_xy(goal), path, res, stamp_s))
        timings["path"] = time.perf_counter() - clock
        if wait:  # at a reached goal on a stale SLAM map: no choice until a fresh one
            return False
        goal = self.goal
        margin = self.cfg.goal_policy.commit_margin
        if goal is not None and margin is None:
            return False

        clock = time.perf_counter()
        plan = self._plan_map = plan or planning_map(observed, pose, res, motion)
        timings["path"] += time.perf_counter() - clock

        def context(regions: tuple[Frontier, ...]) -> PlanningContext:
            regions = reachable_goals(regions, plan.travel_cost)  # a region the bounds cut keeps a reachable goal
            return PlanningContext(observed=observed, pose_rc=pose, frontiers=regions, travel_cost=plan.travel_cost,
                                   traversable=plan.traversable, resolution_m=res, predict=prediction, rng=self._rng)

        clock = time.perf_counter()
        chosen, tolerance = choose_goal(lambda regions: self.planner.choose_goal(context(regions)), observed,
                                        frontiers, self.frontier_min_cells, not_free, pose, self._reach_cells,
                                        self._locked.visited,
                                        lambda regions: self.mission.admit(regions, self._blocks_frame, stamp_s))
        if goal is not None:  # a commit margin: the planner's choice replaces the goal only when clearly better
            scores = None if chosen is None or tuple(chosen) == goal else \
                self.planner.goal_scores(context(()), [goal, chosen])
            if scores is None or not scores[1] > (1.0 + margin) * scores[0]:
                chosen = None
        timings["scoring"] = time.perf_counter() - clock - prediction.seconds
        timings["prediction"] = prediction.seconds
        if chosen is None:
            return False
        clock = time.perf_counter()
        goal = (int(chosen[0]), int(chosen[1]))
        path = plan.path_to(goal)
        timings["path"] += time.perf_counter() - clock
        if not path:
            raise RuntimeError(f"planner {self.planner.name!r} chose goal {goal}, which no path reaches from "
                               f"{pose}; a planner must return a cell of finite travel cost")
        self._locked.lock(goal, path, tolerance, t)
        return True

