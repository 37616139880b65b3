"""One exploration episode: scan, map, pick a frontier goal, drive towards it, repeat."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Optional, Protocol

import numpy as np

from superex_deploy.explore.frontiers import find_frontiers
from superex_deploy.explore.mapper import LidarConfig, Mapper
from superex_deploy.explore.metrics import map_iou
from superex_deploy.explore.motion import MotionConfig, planning_map
from superex_deploy.explore.types import FREE, OCCUPIED, MapPredictor, Planner, PlanningContext, Prediction
from superex_deploy.maps import OccupancyGrid

__all__ = ["ExplorationConfig", "EpisodeResult", "NlosHook", "run_episode", "STAGES"]

STAGES = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")


class NlosHook(Protocol):
    """Optional NLOS sensing in the loop: returns carved free cells (bool ``[H, W]``) and an evidence channel
    (float32 ``[H, W]`` in the map frame, or None) for the predictor."""

    def __call__(self, grid: OccupancyGrid, pose_rc: tuple[int, int], observed: np.ndarray
                 ) -> tuple[np.ndarray, Optional[np.ndarray]]: ...


@dataclass(frozen=True)
class ExplorationConfig:
    """Episode parameters.

    Attributes:
        lidar: line-of-sight LiDAR.
        motion: robot motion and path planning.
        frontier_min_cells: frontier regions smaller than this are ignored (MapEx: 10).
        iou_every: evaluate the prediction's map IoU every this many steps (0: never).
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    frontier_min_cells: int = 10
    iou_every: int = 25


@dataclass
class EpisodeResult:
    """Per-step log of an episode.

    Attributes:
        poses: int ``[T, 2]`` robot cell after each step.
        coverage: float ``[T]`` known fraction of the valid area (line of sight only).
        coverage_with_carving: float ``[T]`` the same with NLOS-carved cells.
        path_length_m: float ``[T]`` distance driven so far.
        timings_s: stage -> float ``[T]`` seconds spent per step (see :data:`STAGES`).
        iou_steps / iou / iou_coverage: map IoU of the prediction at those steps and the coverage there.
        goals: the goal cells chosen, in order.
        finished: True when no reachable frontier was left before the step budget ran out.
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
    iou_steps: list
    iou: list
    iou_coverage: list
    goals: list
    finished: bool
    config: dict
    final_observed: np.ndarray
    final_prediction: Optional[Prediction]

    def to_json(self) -> dict:
        """JSON-ready summary with the per-step series."""
        return {
            "map": self.map_name, "planner": self.planner, "predictor": self.predictor, "seed": self.seed,
            "start_rc": list(self.start_rc), "steps": int(len(self.coverage)), "finished": self.finished,
            "coverage": self.coverage.round(6).tolist(),
            "coverage_with_carving": self.coverage_with_carving.round(6).tolist(),
            "path_length_m": self.path_length_m.round(4).tolist(),
            "poses": self.poses.tolist(), "goals": [list(g) for g in self.goals],
            "iou": {"steps": self.iou_steps, "iou": self.iou, "coverage": self.iou_coverage},
            "timings_s": {k: np.round(v, 6).tolist() for k, v in self.timings_s.items()},
            "mean_step_s": {k: float(np.mean(v)) if len(v) else 0.0 for k, v in self.timings_s.items()},
            "config": self.config,
        }


def _path_clear(observed: np.ndarray, path: list, radius_cells: float) -> bool:
    """True while every remaining path cell is known free with no observed wall within the robot radius."""
    cells = np.asarray(path, np.int64)
    if np.any(observed[cells[:, 0], cells[:, 1]] != FREE):
        return False
    reach = int(np.floor(radius_cells))
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if dr * dr + dc * dc > radius_cells * radius_cells:
                continue
            rows = np.clip(cells[:, 0] + dr, 0, observed.shape[0] - 1)
            cols = np.clip(cells[:, 1] + dc, 0, observed.shape[1] - 1)
            if np.any(observed[rows, cols] == OCCUPIED):
                return False
    return True


def run_episode(grid: OccupancyGrid, start_rc, planner: Planner, predictor: MapPredictor, steps: int = 1000,
                seed: int = 0, cfg: ExplorationConfig = ExplorationConfig(), nlos: Optional[NlosHook] = None,
                on_step: Optional[Callable[[int, "EpisodeState"], None]] = None) -> EpisodeResult:
    """Explore ``grid`` from ``start_rc`` for up to ``steps`` steps.

    Each step: scan (line of sight, plus ``nlos`` if given), update the map, find frontiers, keep or choose a
    goal (a goal stays until it is within ``goal_reached_m`` or no longer reachable), and advance
    ``motion.step_cells`` cells along the path. Deterministic for a seed.

    Raises:
        ValueError: start off the map or in a wall, non-positive steps, a planner or predictor of the wrong kind.
    """
    start = grid.check_pose(start_rc)
    if int(steps) < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if not isinstance(planner, Planner):
        raise ValueError(f"planner must be a Planner, got {type(planner).__name__}")
    if not hasattr(predictor, "predict"):
        raise ValueError(f"predictor must have a predict(observed, extra) method, got {type(predictor).__name__}")
    rng = np.random.default_rng(seed)
    res = grid.resolution_m
    mapper = Mapper(grid.shape, cfg.lidar)
    state = EpisodeState(pose=start, mapper=mapper)
    timings = {stage: np.zeros(steps) for stage in STAGES}
    coverage, coverage_carved, path_length = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    poses = np.zeros((steps, 2), np.int64)
    iou_steps, iou_values, iou_coverage, goals = [], [], [], []
    evidence: Optional[np.ndarray] = None
    driven = 0.0
    goal: Optional[tuple[int, int]] = None
    path: list = []
    finished = False
    reach_cells = cfg.motion.goal_reached_m / res
    prediction: Optional[Prediction] = None
    taken = steps
    for t in range(steps):
        clock = time.perf_counter()
        mapper.integrate_scan(grid.occupied, state.pose, res)
        timings["scan"][t] = time.perf_counter() - clock

        clock = time.perf_counter()
        if nlos is not None:
            carved, evidence = nlos(grid, state.pose, mapper.observed())
            mapper.merge_carved(carved)
        observed = mapper.observed()
        timings["map_update"][t] = time.perf_counter() - clock

        clock = time.perf_counter()
        frontiers = find_frontiers(observed, cfg.frontier_min_cells)
        timings["frontiers"][t] = time.perf_counter() - clock

        step_prediction: list = []

        def predict() -> Prediction:
            if not step_prediction:
                started = time.perf_counter()
                step_prediction.append(predictor.predict(observed, evidence))
                timings["prediction"][t] += time.perf_counter() - started
            return step_prediction[0]

        clock = time.perf_counter()
        needs_goal = (goal is None or np.hypot(goal[0] - state.pose[0], goal[1] - state.pose[1]) <= reach_cells
                      or not path)
        plan = None
        if not needs_goal and not _path_clear(observed, path[1:], cfg.motion.robot_radius_m / res):
            plan = planning_map(observed, state.pose, res, cfg.motion)
            path = plan.path_to(goal)
            needs_goal = not path
        timings["path"][t] = time.perf_counter() - clock
        if needs_goal:
            clock = time.perf_counter()
            plan = plan or planning_map(observed, state.pose, res, cfg.motion)
            timings["path"][t] += time.perf_counter() - clock
            ctx = PlanningContext(observed=observed, pose_rc=state.pose, frontiers=frontiers,
                                  travel_cost=plan.travel_cost, traversable=plan.traversable, resolution_m=res,
                                  predict=predict, rng=rng)
            clock = time.perf_counter()
            goal = planner.choose_goal(ctx)
            timings["scoring"][t] = time.perf_counter() - clock - timings["prediction"][t]
            if goal is None:
                finished = True
                taken = t
                break
            goals.append(goal)
            clock = time.perf_counter()
            path = plan.path_to(goal)
            timings["path"][t] += time.perf_counter() - clock
            if not path:
                goal = None
        if path:
            # path[0] is the robot's cell; advance step_cells along it.
            advance = min(cfg.motion.step_cells, len(path) - 1)
            for a, b in zip(path[:advance], path[1:advance + 1]):
                driven += float(np.hypot(b[0] - a[0], b[1] - a[1])) * res
            state.pose = path[advance]
            path = path[advance:]
        poses[t] = state.pose
        coverage[t] = mapper.coverage(grid.valid, include_carved=False)
        coverage_carved[t] = mapper.coverage(grid.valid, include_carved=True)
        path_length[t] = driven
        if cfg.iou_every and (t % cfg.iou_every == 0 or t == steps - 1):
            prediction = predict()
            iou_steps.append(t)
            iou_values.append(map_iou(prediction.mean, grid))
            iou_coverage.append(coverage_carved[t])
        if on_step is not None:
            on_step(t, state)
    final_observed = mapper.observed()
    if prediction is None and cfg.iou_every:
        prediction = predictor.predict(final_observed, evidence)
    return EpisodeResult(
        map_name=grid.name, planner=planner.name, predictor=getattr(predictor, "name", type(predictor).__name__),
        seed=seed, start_rc=start, poses=poses[:taken], coverage=coverage[:taken],
        coverage_with_carving=coverage_carved[:taken], path_length_m=path_length[:taken],
        timings_s={k: v[:taken] for k, v in timings.items()}, iou_steps=iou_steps, iou=iou_values,
        iou_coverage=iou_coverage, goals=goals, finished=finished, config=asdict(cfg),
        final_observed=final_observed, final_prediction=prediction)


@dataclass
class EpisodeState:
    """Mutable state visible to ``on_step`` callbacks (progress bars, GIF frames)."""

    pose: tuple[int, int]
    mapper: Mapper
