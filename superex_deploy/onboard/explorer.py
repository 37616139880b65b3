"""The onboard exploration loop: observations in, commands out, nothing but what the robot measures.

:meth:`Explorer.step`, with the robot at cell ``p_t``:

1. **scan**: the line-of-sight ranges are integrated into the explorer's own map (free along each ray, occupied at
   its return; :func:`superex_deploy.geometry.mark_ranges`; invalid readings, REP 117's NaN and too-close ranges,
   are skipped: see :class:`~superex_deploy.messages.LaserScan`);
2. **map_update**: the SPAD frame, if any, is processed (:class:`~superex_deploy.onboard.spad_processing.SpadProcessing`):
   carved free cells join the map, the back-projection evidence is kept for the predictor;
3. **frontiers**: frontier regions of the map (regions below ``frontier_min_cells`` are offered only when the
   larger ones give no goal);
4. **path / scoring / prediction**: a locked goal is kept until it is reached (within ``goal_reached_m`` *and* in
   line of sight on the map, see :func:`_reached`), the planner lets it go (``Planner.keep_goal``), or its path is
   blocked by a newly seen wall and no other path reaches it (MapEx's locked frontier); otherwise the planner
   chooses a new goal from the Dijkstra cost-to-go among the frontiers offered in tiers (:func:`_choose`), calling
   the predictor lazily (once per step at most).

How the predictor runs is configured, not fixed (issue #16): inside the asking step or in a worker thread
(:class:`PredictionSchedule`), on the whole map or on a crop around what changed since the last prediction, and only
when enough changed (:class:`~superex_deploy.onboard.prediction_reuse.PredictionReuse`).

The returned :class:`~superex_deploy.messages.Command` holds the goal and the path from the robot's cell; the robot
drives along it and sends the next observation from wherever it stopped. Exploration is **finished** when the map
holds known cells and no goal is left in any tier; while the map is still empty (every reading so far was invalid)
a step answers no goal and not finished, since the next scan may see something. The explorer is deterministic for a
seed (the seed feeds only the planner's generator).
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.onboard.frontiers import find_frontiers
from superex_deploy.onboard.mapper import Mapper
from superex_deploy.onboard.motion import MotionConfig, PlanningMap, path_is_clear, planning_map
from superex_deploy.onboard.prediction_reuse import PredictionReuse, ReusingPredictor, merge_with_map
from superex_deploy.onboard.types import (FREE, OCCUPIED, UNKNOWN, Frontier, MapPredictor, Planner, PlanningContext,
                                          Prediction)
from superex_deploy.geometry import line_of_sight
from superex_deploy.messages import Command, MapFrame, Observation
from superex_deploy.onboard.spad_processing import SpadProcessing

__all__ = ["STAGES", "ExplorerConfig", "Explorer", "PredictionSchedule", "PredictionReuse", "merge_with_map"]

STAGES = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")
"""The stages of a step whose wall-clock time :attr:`Command.timings_s` reports (seconds)."""


@dataclass(frozen=True)
class PredictionSchedule:
    """When the explorer runs its map predictor.

    Attributes:
        asynchronous: False (default): inside the step whose planner asks for it; the step waits for the whole
            ensemble (up to ~0.9 s on 2 cores on the largest eval map). True: in a worker thread, never inside a
            step; planners read the newest finished prediction, with the cells known since overwritten by the
            current map (:func:`merge_with_map`).
        every_steps: with ``asynchronous``: 0 runs free (a new prediction of the newest map starts as soon as the
            last one finished; fast, but the steps at which predictions land depend on the machine, so episodes are
            not reproducible). ``N >= 1`` is the deterministic mode for benchmarks and tests: the map of every
            step ``k N`` is predicted, and the result is applied at step ``k N + apply_after_steps``, waiting for it
            there if it is not done; episodes are reproducible on any machine.
        apply_after_steps: the deterministic delay (``1 <= apply_after_steps <= every_steps``).
        wait_first: with ``asynchronous``: the first step waits for the prediction of its own map (the robot
            stands at its start; without it the planners and the first evaluations see no prediction at all until
            one lands: -29 % IoU at 10 % coverage on the train floors with ``every_steps=5``).
    """

    asynchronous: bool = False
    every_steps: int = 10
    apply_after_steps: int = 1
    wait_first: bool = False

    def __post_init__(self) -> None:
        for name in ("every_steps", "apply_after_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        for name in ("asynchronous", "wait_first"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.every_steps and not 1 <= self.apply_after_steps <= self.every_steps:
            raise ValueError(f"apply_after_steps must lie in 1..every_steps = {self.every_steps}, got "
                             f"{self.apply_after_steps}")


@dataclass(frozen=True)
class ExplorerConfig:
    """Onboard exploration parameters.

    Attributes:
        motion: robot radius, proximity cost, goal tolerance (``step_cells`` is how far the robot is expected to
            drive per step; the explorer follows wherever it actually stops).
        frontier_min_cells: frontier regions with fewer cells are offered to the planner only when no larger
            region gives a goal (MapEx drops them: 10). Dropping them outright stopped 2 of the 40 benchmark
            episodes at their first step, in rooms whose open door, seen edge-on, showed fewer frontier cells.
        prediction: when the predictor runs (:class:`PredictionSchedule`).
        reuse: what the explorer keeps of its last prediction
            (:class:`~superex_deploy.onboard.prediction_reuse.PredictionReuse`: re-predict only when the map
            changed enough, and only a crop around the change).
    """

    motion: MotionConfig = field(default_factory=MotionConfig)
    frontier_min_cells: int = 10
    prediction: PredictionSchedule = field(default_factory=PredictionSchedule)
    reuse: PredictionReuse = field(default_factory=PredictionReuse)

    def __post_init__(self) -> None:
        if not isinstance(self.motion, MotionConfig):
            raise ValueError(f"motion must be a MotionConfig, got {type(self.motion).__name__}")
        if not isinstance(self.prediction, PredictionSchedule):
            raise ValueError(f"prediction must be a PredictionSchedule, got {type(self.prediction).__name__}")
        if not isinstance(self.reuse, PredictionReuse):
            raise ValueError(f"reuse must be a PredictionReuse, got {type(self.reuse).__name__}")
        if int(self.frontier_min_cells) < 1:
            raise ValueError(f"frontier_min_cells must be >= 1, got {self.frontier_min_cells}")


class _LazyPrediction:
    """The predictor's output for one map: computed on the first call, then cached, with the seconds it took.

    A planner's request (``__call__``) lets a :class:`ReusingPredictor` keep the result as its new last
    prediction; :meth:`look` (an evaluation between requests) computes it without leaving a trace."""

    def __init__(self, predictor, observed: np.ndarray, evidence: Optional[np.ndarray]):
        self._predictor, self._observed, self._evidence = predictor, observed, evidence
        self.value: Optional[Prediction] = None
        self.seconds = 0.0

    def __call__(self) -> Prediction:
        return self._compute(commit=True)

    def look(self) -> Prediction:
        return self._compute(commit=False)

    def _compute(self, commit: bool) -> Prediction:
        if self.value is None:
            started = time.perf_counter()
            if isinstance(self._predictor, ReusingPredictor):
                self.value = self._predictor.predict(self._observed, self._evidence, commit=commit)
            else:
                self.value = self._predictor.predict(self._observed, self._evidence)
            self.seconds = time.perf_counter() - started
        return self.value


class _StalePrediction:
    """What a planner reads in asynchronous mode: the newest finished prediction merged with this step's map
    (computed on the first call, then cached), or the map itself (unknown = free) before any prediction landed."""

    def __init__(self, newest: Optional[Prediction], observed: np.ndarray):
        self._newest, self._observed = newest, observed
        self.value: Optional[Prediction] = None
        self.seconds = 0.0

    def __call__(self) -> Prediction:
        if self.value is None:
            started = time.perf_counter()
            if self._newest is None:
                mean = (self._observed == OCCUPIED).astype(np.float32)
                self.value = Prediction(mean=mean, variance=np.zeros_like(mean))
            else:
                self.value = merge_with_map(self._newest, self._observed)
            self.seconds = time.perf_counter() - started
        return self.value

    look = __call__


def _reached(not_free: np.ndarray, pose: tuple[int, int], cell: tuple[int, int], reach_cells: float) -> bool:
    """Whether the robot at ``pose`` has reached the goal ``cell``: within the goal tolerance *and* in line of
    sight on the map (``not_free``: bool ``[H, W]``, every cell not known free).

    Distance alone (MapEx's rule) counted a frontier as reached from behind the corner of the wall that hides
    it: on eval map 50010539 the robot stopped 1 m short of a frontier in the next room, never saw it, and
    shuttled between two such frontiers for 900 steps (28.9 % coverage for every planner). Seeing the goal cell
    means the sensor has looked at the frontier from that side."""
    if np.hypot(cell[0] - pose[0], cell[1] - pose[1]) > reach_cells:
        return False
    return line_of_sight(not_free, pose, cell)


def _near_visited(cell: tuple[int, int], visited: set[tuple[int, int]]) -> bool:
    """Whether ``cell`` is a reached goal or one of its 8 neighbours: a frontier whose goal cell was reached
    and that is still there cannot be resolved from where the robot can stand (unknown cells seen only edge-on,
    the inside of a thick wall), and would be offered again as soon as the robot left."""
    return any((cell[0] + dr, cell[1] + dc) in visited for dr in (-1, 0, 1) for dc in (-1, 0, 1))


def _choose(offer: Callable[[tuple[Frontier, ...]], Optional[tuple[int, int]]], observed: np.ndarray,
            frontiers: tuple[Frontier, ...], min_cells: int, not_free: np.ndarray, pose: tuple[int, int],
            reach_cells: float, visited: set[tuple[int, int]]) -> tuple[Optional[tuple[int, int]], float]:
    """Offer the frontiers to the planner in three tiers; returns the goal (or None: nothing is left) and the
    distance within which it counts as reached.

    1. Regions of at least ``min_cells`` cells that do not count as reached already (:func:`_reached`: MapEx's
       validity rule, since offering one would lock the robot onto a goal it never leaves) and whose goal cell
       the robot has not reached before (:func:`_near_visited`).
    2. The same for smaller regions: a doorway seen edge-on can show fewer frontier cells than the minimum, and
       a robot must not stop in a room with an open door.
    3. Regions that count as reached from where the robot stands but were never visited: their goal cell is in
       sight within the tolerance while the unknown behind them is not (seen through a door at a steep angle).
       The robot then drives onto the goal cell itself (tolerance 0) instead of declaring the map explored.
    """
    small: Optional[tuple[Frontier, ...]] = None
    if not frontiers:
        small = find_frontiers(observed, 1)
        if not small:
            return None, reach_cells
    unvisited = [f for f in frontiers if not _near_visited(f.cell_rc, visited)]
    candidates = tuple(f for f in unvisited if not _reached(not_free, pose, f.cell_rc, reach_cells))
    # The planner is asked even when every region was filtered out: UPEN's tree can still find a goal.
    chosen = offer(candidates) if frontiers else None
    if chosen is not None:
        return chosen, reach_cells
    if small is None:
        small = tuple(f for f in find_frontiers(observed, 1) if len(f.cells) < min_cells) if min_cells > 1 else ()
    small_unvisited = [f for f in small if not _near_visited(f.cell_rc, visited)]
    candidates = tuple(f for f in small_unvisited if not _reached(not_free, pose, f.cell_rc, reach_cells))
    chosen = offer(candidates) if small else None
    if chosen is not None:
        return chosen, reach_cells
    close = tuple(f for f in unvisited + small_unvisited if _reached(not_free, pose, f.cell_rc, reach_cells))
    chosen = offer(close) if close else None
    return chosen, 0.0


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

    Attributes:
        frame, planner, predictor, spad_processing, cfg: as given.
        mapper: the explorer's map (:class:`~superex_deploy.onboard.mapper.Mapper`; read it, do not modify it).
        observed: int8 ``[H, W]`` the map after the latest step (UNKNOWN / FREE / OCCUPIED; carved cells FREE).
        frontiers: the latest step's frontier regions.
        goal: the locked goal cell, or None (:meth:`drop_goal` lets it go).
        path: cells from the robot to the goal.
        steps: observations processed so far.
        finished: whether the latest step found the exploration finished (see above).
        reusing: the :class:`~superex_deploy.onboard.prediction_reuse.ReusingPredictor` that wraps the predictor
            when ``cfg.reuse`` keeps anything (its counters say how often the network ran), else None.
    """

    def __init__(self, frame: MapFrame, planner: Planner, predictor: MapPredictor,
                 spad_processing: Optional[SpadProcessing] = None, cfg: ExplorerConfig = ExplorerConfig(),
                 seed: int = 0):
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
        self.frame, self.planner, self.predictor, self.cfg = frame, planner, predictor, cfg
        self.spad_processing = spad_processing
        # What the steps call: the predictor itself, or the wrapper that keeps its last prediction.
        self.reusing: Optional[ReusingPredictor] = (ReusingPredictor(predictor, cfg.reuse, frame.resolution_m)
                                                    if cfg.reuse.reuses else None)
        self._predictor: MapPredictor = self.reusing if self.reusing is not None else predictor
        self.mapper = Mapper(frame.shape)
        self.observed = self.mapper.observed()
        self.frontiers: tuple[Frontier, ...] = ()
        self.goal: Optional[tuple[int, int]] = None
        self.path: list[tuple[int, int]] = []
        self.steps = 0
        self.finished = False
        self._stepping = threading.Lock()  # held by the running step(): one caller at a time
        self._rng = np.random.default_rng(seed)
        self._reach_cells = cfg.motion.goal_reached_m / frame.resolution_m
        self._radius_cells = cfg.motion.robot_radius_m / frame.resolution_m
        self._goal_tolerance = self._reach_cells
        self._goal_step = -1
        self._visited: set[tuple[int, int]] = set()
        self._prediction: Optional[_LazyPrediction] = None
        self._latest: Optional[Prediction] = None
        self._latest_step = -1
        schedule = cfg.prediction
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="superex-predict") if schedule.asynchronous else None
        self._pending: Optional[Future] = None
        self._no_evidence: Optional[np.ndarray] = None
        self._pending_step = -1
        planner.reset()
        if spad_processing is not None:
            spad_processing.reset()

    @property
    def visited_goals(self) -> frozenset:
        """Goal cells reached so far whose frontier did not resolve (they are not offered again)."""
        return frozenset(self._visited)

    def frontier_candidates(self, pose_rc) -> tuple[Frontier, ...]:
        """The latest map's frontier regions, of every size, that :meth:`step` would offer a planner with the robot
        at cell ``pose_rc`` (row, col): those not counted as reached already (:func:`_reached`) and whose goal cell
        is no goal reached before nor next to one (:func:`_near_visited`), in ``find_frontiers`` order; ``()``
        before the first observation. :meth:`step` offers the regions of ``cfg.frontier_min_cells`` cells or more
        first, the smaller ones only when those give no goal. For a goal chosen outside the explorer (a learning
        agent): a goal among these is one the explorer does not let go of at once.

        Raises:
            ValueError: a cell outside the map.
        """
        pose = (int(pose_rc[0]), int(pose_rc[1]))
        if not (0 <= pose[0] < self.frame.shape[0] and 0 <= pose[1] < self.frame.shape[1]):
            raise ValueError(f"robot cell {pose} lies outside the map of shape {self.frame.shape}")
        not_free = self.observed != FREE
        return tuple(f for f in find_frontiers(self.observed, 1) if not _near_visited(f.cell_rc, self._visited)
                     and not _reached(not_free, pose, f.cell_rc, self._reach_cells))

    def drop_goal(self) -> None:
        """Let go of the locked goal and its path: the next :meth:`step` asks the planner again (the goal does not
        count as reached). For a goal chosen outside the explorer: give the choice to the planner, then call this."""
        self.goal, self.path = None, []

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` the NLOS evidence the predictor reads: None without SPAD processing, zeros with it
        until the first SPAD frame arrives (a predictor that reads evidence then sees none)."""
        if self.spad_processing is None:
            return None
        if self.spad_processing.evidence is None:
            if self._no_evidence is None:  # made once: read-only zeros until the first frame
                self._no_evidence = np.zeros(self.frame.shape, np.float32)
                self._no_evidence.flags.writeable = False
            return self._no_evidence
        return self.spad_processing.evidence

    def predict(self) -> Prediction:
        """What the planners read at the latest step: synchronously, the prediction of that step's map (computed
        once per step; a planner that asked already paid); asynchronously, the newest finished prediction merged
        with that map. For evaluation: it does not change what :class:`Command` reports.

        Raises:
            RuntimeError: before the first observation.
        """
        if self._prediction is None:
            raise RuntimeError("no observation yet: call step() first")
        return self._prediction.look()

    def close(self) -> None:
        """Stop the prediction worker (asynchronous mode); the explorer cannot step afterwards."""
        if self._worker is not None:
            self._worker.shutdown(wait=True, cancel_futures=True)
            self._worker = None
        self._closed = True

    def __enter__(self) -> "Explorer":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def _run_prediction(self, observed: np.ndarray, evidence: Optional[np.ndarray]) -> Prediction:
        return self._predictor.predict(observed, evidence)

    def _schedule_predictions(self, observed: np.ndarray, t: int) -> float:
        """Asynchronous mode: take a finished prediction (in the deterministic mode: wait for the one due at this
        step) and start the next; returns the seconds this step waited."""
        schedule, waited = self.cfg.prediction, 0.0
        if self._pending is not None:
            due = schedule.every_steps and t >= self._pending_step + schedule.apply_after_steps
            if due or (not schedule.every_steps and self._pending.done()):
                clock = time.perf_counter()
                pending, self._pending = self._pending, None  # a failed prediction is raised once, not every step
                self._latest, self._latest_step = pending.result(), self._pending_step
                waited = time.perf_counter() - clock
        start = t % schedule.every_steps == 0 if schedule.every_steps else True
        if self._pending is None and start:
            evidence = None if self.evidence is None else self.evidence.copy()
            self._pending = self._worker.submit(self._run_prediction, observed.copy(), evidence)
            self._pending_step = t
            if t == 0 and schedule.wait_first:
                clock = time.perf_counter()
                pending, self._pending = self._pending, None
                self._latest, self._latest_step = pending.result(), 0
                waited += time.perf_counter() - clock
        return waited

    @property
    def step_prediction(self) -> Optional[Prediction]:
        """The latest step's prediction if anything has computed it, else None (never computes)."""
        return None if self._prediction is None else self._prediction.value

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
        if not self._stepping.acquire(blocking=False):
            raise RuntimeError("Explorer.step() is already running (called from another thread): an explorer takes "
                               "one caller at a time; serialise the calls or use one explorer per thread")
        try:
            return self._step(obs)
        finally:
            self._stepping.release()

    def _step(self, obs: Observation) -> Command:
        if getattr(self, "_closed", False):
            raise RuntimeError("this explorer was closed")
        pose = self._pose_cell(obs)
        timings = dict.fromkeys(STAGES, 0.0)
        t = self.steps

        clock = time.perf_counter()
        self.mapper.integrate_scan(self.frame, obs.pose, obs.scan)
        timings["scan"] = time.perf_counter() - clock

        clock = time.perf_counter()
        if self.spad_processing is not None and obs.spad is not None:
            carved, _ = self.spad_processing(obs.spad, self.frame, obs.pose, self.mapper.known())
            self.mapper.merge_carved(carved)
        observed = self.mapper.observed()
        timings["map_update"] = time.perf_counter() - clock

        clock = time.perf_counter()
        frontiers = find_frontiers(observed, self.cfg.frontier_min_cells)
        timings["frontiers"] = time.perf_counter() - clock

        waited = 0.0
        if self._worker is not None:
            waited = self._schedule_predictions(observed, t)
            prediction = _StalePrediction(self._latest, observed)
        else:
            prediction = _LazyPrediction(self._predictor, observed, self.evidence)
        self.observed, self.frontiers, self._prediction = observed, frontiers, prediction
        self.steps += 1
        if np.any(observed != UNKNOWN):
            new_goal = self._plan(observed, frontiers, pose, prediction, t, timings)
        else:  # nothing measured yet (every reading invalid): no goal, and not finished
            new_goal, self.finished = False, False
        timings["prediction"] += waited
        if self._worker is None and prediction.value is not None:
            self._latest, self._latest_step = prediction.value, t
        path_rc = np.asarray(self.path, np.int64).reshape(-1, 2)
        return Command(stamp_s=obs.stamp_s,
                       goal_xy=None if self.goal is None else self.frame.centre_xy(self.goal),
                       goal_rc=self.goal, path_xy=self.frame.centres_xy(path_rc), path_rc=path_rc,
                       finished=self.finished, new_goal=new_goal, prediction=self._latest,
                       prediction_step=self._latest_step, step=t, timings_s=timings)

    def _plan(self, observed: np.ndarray, frontiers: tuple[Frontier, ...], pose: tuple[int, int],
              prediction: _LazyPrediction, t: int, timings: dict) -> bool:
        """Keep or choose the goal and its path; returns whether a new goal was chosen."""
        res, motion = self.frame.resolution_m, self.cfg.motion
        clock = time.perf_counter()
        plan: Optional[PlanningMap] = None
        not_free = observed != FREE
        goal = self.goal
        path = self.path[self.path.index(pose):] if pose in self.path else []
        if goal is not None and _reached(not_free, pose, goal, self._goal_tolerance):
            self._visited.add(goal)
            goal, path = None, []
        if goal is not None and not self.planner.keep_goal(observed, pose, goal, t - self._goal_step):
            goal, path = None, []
        if goal is not None and (not path or not path_is_clear(observed, path[1:], self._radius_cells)):
            # Blocked by a newly seen wall, or the robot did not stop on its path: plan again to the same goal.
            plan = planning_map(observed, pose, res, motion)
            path = plan.path_to(goal)
            if not path:
                goal = None
        timings["path"] = time.perf_counter() - clock
        self.goal, self.path = goal, path
        if goal is not None:
            return False

        clock = time.perf_counter()
        plan = plan or planning_map(observed, pose, res, motion)
        timings["path"] += time.perf_counter() - clock

        def offer(regions: tuple[Frontier, ...]) -> Optional[tuple[int, int]]:
            return self.planner.choose_goal(PlanningContext(
                observed=observed, pose_rc=pose, frontiers=regions, travel_cost=plan.travel_cost,
                traversable=plan.traversable, resolution_m=res, predict=prediction, rng=self._rng))

        clock = time.perf_counter()
        chosen, self._goal_tolerance = _choose(offer, observed, frontiers, self.cfg.frontier_min_cells, not_free,
                                               pose, self._reach_cells, self._visited)
        timings["scoring"] = time.perf_counter() - clock - prediction.seconds
        timings["prediction"] = prediction.seconds
        self.finished = chosen is None
        if chosen is None:
            return False
        clock = time.perf_counter()
        goal = (int(chosen[0]), int(chosen[1]))
        path = plan.path_to(goal)
        timings["path"] += time.perf_counter() - clock
        if not path:
            raise RuntimeError(f"planner {self.planner.name!r} chose goal {goal}, which no path reaches from "
                               f"{pose}; a planner must return a cell of finite travel cost")
        self.goal, self.path, self._goal_step = goal, path, t
        return True

