"""One exploration episode: scan, update the map, find frontiers, keep or choose a goal, drive, repeat.

Step ``t`` of an episode, with the robot at cell ``p_t``:

1. **scan**: line-of-sight LiDAR from ``p_t`` into the :class:`~superex_deploy.explore.mapper.Mapper`;
2. **map_update**: the optional NLOS hook adds carved free cells and an evidence channel; the observed map is
   rebuilt;
3. **frontiers**: frontier regions of the observed map (regions below ``frontier_min_cells`` are offered
   only when the larger ones give no goal);
4. **path / scoring / prediction**: a locked goal is kept until it is reached (within ``goal_reached_m`` *and*
   in line of sight on the observed map, see :func:`_reached`), the planner lets it go (``Planner.keep_goal``),
   or its path is blocked by a newly seen wall and no other path reaches it (MapEx's locked frontier); otherwise
   the planner chooses a new goal from the Dijkstra cost-to-go among the frontiers offered in tiers
   (:func:`_choose`), calling the predictor lazily (once per step at most);
5. the robot advances ``step_cells`` cells along the path; ``p_{t+1}`` is where it stops.

The log at index ``t`` describes the scan taken at ``p_t``: the pose, the coverage after that scan, and the
metres driven before it. The episode stops when the step budget is spent or when the planner finds no goal
in any tier (no reachable frontier left that was not reached before); the last logged step is then the one that
found nothing. Everything is deterministic for a seed; the seed feeds only the planner's random generator.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Optional, Protocol

import numpy as np

from superex_deploy.explore.frontiers import find_frontiers
from superex_deploy.explore.mapper import LidarConfig, Mapper
from superex_deploy.explore.metrics import evaluation_area, map_iou
from superex_deploy.explore.motion import MotionConfig, PlanningMap, advance, path_is_clear, planning_map
from superex_deploy.explore.types import FREE, Frontier, MapPredictor, Planner, PlanningContext, Prediction
from superex_deploy.geometry import line_of_sight
from superex_deploy.maps import OccupancyGrid

__all__ = ["STAGES", "NlosHook", "ExplorationConfig", "EpisodeState", "EpisodeResult", "run_episode"]

STAGES = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")
"""The stages of a step whose wall-clock time is logged (seconds per step). Metric evaluation (map IoU) is
logged apart, as ``evaluation_s``: it is not part of the robot's loop."""


class NlosHook(Protocol):
    """Optional NLOS sensing inside the loop (the SPAD simulation and processing plug in here).

    Called once per step after the line-of-sight scan with the ground truth, the robot cell and the current
    observed map (int8 ``[H, W]``, line of sight plus earlier carving). Returns ``(carved, evidence)``:
    ``carved`` bool ``[H, W]`` cells proven free by this step's NLOS processing; ``evidence`` float32
    ``[H, W]`` map-frame evidence handed to the predictor as its ``extra`` input, or None.
    """

    def __call__(self, grid: OccupancyGrid, pose_rc: tuple[int, int], observed: np.ndarray
                 ) -> tuple[np.ndarray, Optional[np.ndarray]]: ...


@dataclass(frozen=True)
class ExplorationConfig:
    """Episode parameters.

    Attributes:
        lidar: the line-of-sight LiDAR.
        motion: robot radius, proximity cost, step length, goal tolerance.
        frontier_min_cells: frontier regions with fewer cells are offered to the planner only when no larger
            region gives a goal (MapEx drops them: 10). Dropping them outright stopped 2 of the 40 benchmark
            episodes at their first step, in rooms whose open door, seen edge-on, showed fewer frontier cells.
        iou_every: evaluate the prediction's map IoU every this many steps, and at the last step (0: never).
        iou_dense_until: above this coverage (with carving) the IoU is evaluated only every ``10 * iou_every``
            steps: the benchmark's IoU metrics read the low-coverage part of the curve (up to 30 %), and each
            evaluation runs the predictor.
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    frontier_min_cells: int = 10
    iou_every: int = 25
    iou_dense_until: float = 1.0

    def __post_init__(self) -> None:
        if int(self.frontier_min_cells) < 1:
            raise ValueError(f"frontier_min_cells must be >= 1, got {self.frontier_min_cells}")
        if int(self.iou_every) < 0:
            raise ValueError(f"iou_every must be >= 0, got {self.iou_every}")


@dataclass
class EpisodeState:
    """What ``on_step`` callbacks (progress bars, GIF frames) see after the planning of step ``step``.

    Attributes:
        step: step index.
        pose: robot cell where this step's scan was taken.
        mapper: the episode's mapper (read it, do not modify it).
        observed: int8 ``[H, W]`` observed map after this step's scan.
        frontiers: this step's frontier regions.
        goal: the locked goal cell, or None.
        path: cells from ``pose`` to ``goal`` that the robot follows (empty without a goal).
        prediction: the prediction if one was computed this step, else None.
        coverage: line-of-sight coverage after this step's scan.
    """

    step: int
    pose: tuple[int, int]
    mapper: Mapper
    observed: np.ndarray
    frontiers: tuple[Frontier, ...]
    goal: Optional[tuple[int, int]]
    path: list
    prediction: Optional[Prediction]
    coverage: float


@dataclass
class EpisodeResult:
    """Log of an episode of ``T`` steps (``T`` <= the step budget).

    Attributes:
        map_name, planner, predictor, seed, start_rc: what ran.
        poses: int64 ``[T, 2]`` robot cell at each step's scan.
        coverage: float64 ``[T]`` known fraction of the valid area after each scan, line of sight only.
        coverage_with_carving: float64 ``[T]`` the same counting NLOS-carved cells.
        path_length_m: float64 ``[T]`` metres driven before each scan (0 at step 0).
        timings_s: stage (see :data:`STAGES`) -> float64 ``[T]`` seconds spent in it per step.
        evaluation_s: float64 ``[T]`` seconds spent on metric evaluation per step (not part of the loop).
        iou_steps, iou, iou_coverage: steps where the map IoU was evaluated, its value, and the coverage (with
            carving) there.
        goal_steps, goals: the steps where a new goal was chosen, and the goal cells.
        finished: True when the planner found no goal before the budget ran out.
        config: the :class:`ExplorationConfig` as a dict.
        final_observed: int8 ``[H, W]`` observed map at the end.
        final_carved: bool ``[H, W]`` carved cells at the end.
        final_prediction: the last prediction computed (for the final figure), or None.
    """

    map_name: str
    planner: str
    predictor: str
    seed: int
    start_rc: tuple[int, int]
    poses: np.ndarray
    coverage: np.ndarray
    coverage_with_carving: np.ndarray
    path_length_m: np.ndarray
    timings_s: dict
    evaluation_s: np.ndarray
    iou_steps: list
    iou: list
    iou_coverage: list
    goal_steps: list
    goals: list
    finished: bool
    config: dict
    final_observed: np.ndarray
    final_carved: np.ndarray
    final_prediction: Optional[Prediction]

    @property
    def steps(self) -> int:
        """Number of logged steps ``T``."""
        return int(len(self.coverage))

    def to_json(self) -> dict:
        """JSON-ready dict: the per-step series, IoU log, goals, mean stage times and the config."""
        timings = {stage: np.round(values, 6).tolist() for stage, values in self.timings_s.items()}
        return {
            "map": self.map_name, "planner": self.planner, "predictor": self.predictor, "seed": self.seed,
            "start_rc": list(self.start_rc), "steps": self.steps, "finished": self.finished,
            "final_coverage": float(self.coverage[-1]) if self.steps else 0.0,
            "final_coverage_with_carving": float(self.coverage_with_carving[-1]) if self.steps else 0.0,
            "coverage": np.round(self.coverage, 6).tolist(),
            "coverage_with_carving": np.round(self.coverage_with_carving, 6).tolist(),
            "path_length_m": np.round(self.path_length_m, 4).tolist(),
            "poses": self.poses.tolist(),
            "goals": {"steps": list(self.goal_steps), "cells": [list(goal) for goal in self.goals]},
            "iou": {"steps": list(self.iou_steps), "iou": list(self.iou), "coverage": list(self.iou_coverage)},
            "timings_s": timings,
            "evaluation_s": np.round(self.evaluation_s, 6).tolist(),
            "mean_step_s": {stage: float(np.mean(values)) if len(values) else 0.0
                            for stage, values in self.timings_s.items()},
            "config": self.config,
        }


class _LazyPrediction:
    """The predictor's output for one observed map: computed on the first call, then cached. The time is
    charged to the ``prediction`` stage when the planner asks, to evaluation otherwise."""

    def __init__(self, predictor: MapPredictor, observed: np.ndarray, evidence: Optional[np.ndarray]):
        self._predictor, self._observed, self._evidence = predictor, observed, evidence
        self.value: Optional[Prediction] = None
        self.seconds = 0.0

    def __call__(self) -> Prediction:
        if self.value is None:
            started = time.perf_counter()
            self.value = self._predictor.predict(self._observed, self._evidence)
            self.seconds = time.perf_counter() - started
        return self.value


def _reached(not_free: np.ndarray, pose: tuple[int, int], cell: tuple[int, int], reach_cells: float) -> bool:
    """Whether the robot at ``pose`` has reached the goal ``cell``: within the goal tolerance *and* in line of
    sight on the observed map (``not_free``: bool ``[H, W]``, every cell not known free).

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


def _check_inputs(grid: OccupancyGrid, start_rc, planner: Planner, predictor: MapPredictor, steps: int,
                  cfg: ExplorationConfig, nlos) -> tuple[tuple[int, int], int]:
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    start = grid.check_pose(start_rc)
    if isinstance(steps, bool) or int(steps) != steps or int(steps) < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if not isinstance(planner, Planner):
        raise ValueError(f"planner must be a Planner instance (see planners.make_planner), got "
                         f"{type(planner).__name__}")
    if not callable(getattr(predictor, "predict", None)):
        raise ValueError(f"predictor must have a predict(observed, extra) method, got {type(predictor).__name__}")
    if not isinstance(cfg, ExplorationConfig):
        raise ValueError(f"cfg must be an ExplorationConfig, got {type(cfg).__name__}")
    if nlos is not None and not callable(nlos):
        raise ValueError(f"nlos must be callable (see NlosHook), got {type(nlos).__name__}")
    return start, int(steps)


def _check_nlos_output(output, shape: tuple[int, int]) -> tuple[np.ndarray, Optional[np.ndarray]]:
    try:
        carved, evidence = output
    except (TypeError, ValueError):
        raise ValueError("the NLOS hook must return a (carved, evidence) pair") from None
    carved = np.asarray(carved)
    if carved.dtype != np.bool_ or carved.shape != shape:
        raise ValueError(f"the NLOS hook's carved mask must be bool {shape}, got {carved.dtype} {carved.shape}")
    if evidence is not None:
        evidence = np.asarray(evidence)
        if evidence.shape != shape or not np.issubdtype(evidence.dtype, np.floating):
            raise ValueError(f"the NLOS hook's evidence must be a float {shape} array or None, got "
                             f"{evidence.dtype} {evidence.shape}")
    return carved, evidence


def run_episode(grid: OccupancyGrid, start_rc, planner: Planner, predictor: MapPredictor, steps: int = 1000,
                seed: int = 0, cfg: ExplorationConfig = ExplorationConfig(), nlos: Optional[NlosHook] = None,
                on_step: Optional[Callable[[EpisodeState], None]] = None) -> EpisodeResult:
    """Explore ``grid`` from ``start_rc`` for up to ``steps`` steps (see the module docstring).

    Args:
        grid: the ground-truth map.
        start_rc: start cell (row, col): inside the map, not a wall.
        planner: a :class:`~superex_deploy.explore.types.Planner` instance (``planners.make_planner(name)``).
        predictor: a :class:`~superex_deploy.explore.types.MapPredictor`.
        steps: step budget (>= 1).
        seed: seed of the generator handed to the planner.
        cfg: episode parameters.
        nlos: optional :class:`NlosHook`.
        on_step: optional callback, called once per step with the :class:`EpisodeState`.

    Returns:
        The :class:`EpisodeResult`.

    Raises:
        ValueError: a start off the map or inside a wall, a non-positive step budget, a planner that is not a
            Planner, a predictor without ``predict``, a malformed NLOS result.
        RuntimeError: the planner returned a goal that no path reaches (a planner bug).
    """
    start, steps = _check_inputs(grid, start_rc, planner, predictor, steps, cfg, nlos)
    res = grid.resolution_m
    motion = cfg.motion
    reach_cells = motion.goal_reached_m / res
    radius_cells = motion.robot_radius_m / res
    rng = np.random.default_rng(seed)
    planner.reset()
    mapper = Mapper(grid.shape, cfg.lidar)
    iou_area = evaluation_area(grid) if cfg.iou_every else None

    timings = {stage: np.zeros(steps) for stage in STAGES}
    evaluation_s = np.zeros(steps)
    poses = np.zeros((steps, 2), np.int64)
    coverage, coverage_carved, path_length = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    iou_steps: list[int] = []
    iou_values: list[float] = []
    iou_coverage: list[float] = []
    goal_steps: list[int] = []
    goals: list[tuple[int, int]] = []
    pose, driven = start, 0.0
    goal: Optional[tuple[int, int]] = None
    visited_goals: set[tuple[int, int]] = set()
    goal_tolerance = reach_cells
    path: list[tuple[int, int]] = []
    evidence: Optional[np.ndarray] = None
    last_prediction: Optional[Prediction] = None
    finished = False
    logged = steps

    for t in range(steps):
        clock = time.perf_counter()
        mapper.integrate_scan(grid.occupied, pose, res)
        timings["scan"][t] = time.perf_counter() - clock

        clock = time.perf_counter()
        if nlos is not None:
            carved, evidence = _check_nlos_output(nlos(grid, pose, mapper.observed()), grid.shape)
            mapper.merge_carved(carved)
        observed = mapper.observed()
        timings["map_update"][t] = time.perf_counter() - clock

        clock = time.perf_counter()
        frontiers = find_frontiers(observed, cfg.frontier_min_cells)
        timings["frontiers"][t] = time.perf_counter() - clock

        poses[t] = pose
        coverage[t] = mapper.coverage(grid.valid, include_carved=False)
        coverage_carved[t] = mapper.coverage(grid.valid, include_carved=True)
        path_length[t] = driven
        prediction = _LazyPrediction(predictor, observed, evidence)

        clock = time.perf_counter()
        plan: Optional[PlanningMap] = None
        not_free = observed != FREE
        if goal is not None and _reached(not_free, pose, goal, goal_tolerance):
            visited_goals.add(goal)
            goal, path = None, []
        if goal is not None and not planner.keep_goal(observed, pose, goal, t - goal_steps[-1]):
            goal, path = None, []
        if goal is not None and not path_is_clear(observed, path[1:], radius_cells):
            plan = planning_map(observed, pose, res, motion)
            path = plan.path_to(goal)
            if not path:
                goal = None
        timings["path"][t] = time.perf_counter() - clock

        if goal is None:
            clock = time.perf_counter()
            plan = plan or planning_map(observed, pose, res, motion)
            timings["path"][t] += time.perf_counter() - clock

            def offer(regions: tuple[Frontier, ...]) -> Optional[tuple[int, int]]:
                return planner.choose_goal(PlanningContext(
                    observed=observed, pose_rc=pose, frontiers=regions, travel_cost=plan.travel_cost,
                    traversable=plan.traversable, resolution_m=res, predict=prediction, rng=rng))

            clock = time.perf_counter()
            chosen, goal_tolerance = _choose(offer, observed, frontiers, cfg.frontier_min_cells, not_free, pose,
                                             reach_cells, visited_goals)
            timings["scoring"][t] = time.perf_counter() - clock - prediction.seconds
            timings["prediction"][t] = prediction.seconds
            if chosen is not None:
                clock = time.perf_counter()
                goal = (int(chosen[0]), int(chosen[1]))
                path = plan.path_to(goal)
                timings["path"][t] += time.perf_counter() - clock
                if not path:
                    raise RuntimeError(f"planner {planner.name!r} chose goal {goal}, which no path reaches from "
                                       f"{pose}; a planner must return a cell of finite travel cost")
                goal_steps.append(t)
                goals.append(goal)
            else:
                finished = True

        every = cfg.iou_every if coverage_carved[t] <= cfg.iou_dense_until else 10 * cfg.iou_every
        if cfg.iou_every and (t % every == 0 or t == steps - 1 or finished):
            clock = time.perf_counter()
            evaluated = prediction()
            iou_steps.append(t)
            iou_values.append(map_iou(evaluated.mean, grid, area=iou_area))
            iou_coverage.append(float(coverage_carved[t]))
            evaluation_s[t] = time.perf_counter() - clock
        if prediction.value is not None:
            last_prediction = prediction.value
        if on_step is not None:
            on_step(EpisodeState(step=t, pose=pose, mapper=mapper, observed=observed, frontiers=frontiers,
                                 goal=goal, path=path, prediction=prediction.value, coverage=float(coverage[t])))
        if finished:
            logged = t + 1
            break
        pose, path, metres = advance(path, motion.step_cells, res)
        driven += metres

    final_observed = mapper.observed()
    return EpisodeResult(
        map_name=grid.name, planner=planner.name, predictor=getattr(predictor, "name", type(predictor).__name__),
        seed=int(seed), start_rc=start, poses=poses[:logged], coverage=coverage[:logged],
        coverage_with_carving=coverage_carved[:logged], path_length_m=path_length[:logged],
        timings_s={stage: values[:logged] for stage, values in timings.items()},
        evaluation_s=evaluation_s[:logged], iou_steps=iou_steps, iou=iou_values, iou_coverage=iou_coverage,
        goal_steps=goal_steps, goals=goals, finished=finished, config=asdict(cfg),
        final_observed=final_observed, final_carved=mapper.carved.copy(), final_prediction=last_prediction)
