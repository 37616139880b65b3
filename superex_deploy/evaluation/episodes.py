"""One simulated exploration episode: the world observes, the explorer decides, the world drives; repeat.

Step ``t``: :meth:`World.observe <superex_deploy.sim.world.World.observe>` scans from the robot's cell ``p_t``
(line-of-sight ranges and, with SPAD sensing, a SPAD frame); :meth:`Explorer.step
<superex_deploy.onboard.explorer.Explorer.step>` integrates them into its own map and keeps or chooses a goal (see
:mod:`superex_deploy.onboard.explorer` for its stages); the metrics (:mod:`superex_deploy.evaluation.metrics`)
are read against the truth; :meth:`World.apply <superex_deploy.sim.world.World.apply>` advances the robot ``step_m``
metres of cells along the commanded path, to ``p_{t+1}``.

The log at index ``t`` describes the scan taken at ``p_t``: the pose, the coverage after that scan, and the
metres driven before it. The episode stops when the step budget is spent or when the explorer finds no goal in any
tier; the last logged step is then the one that found nothing. Everything is deterministic for a seed; the seed
feeds only the planner's random generator (the SPAD noise has its own, :attr:`SpadSensing.seed`).

:func:`run_benchmark_episode` is the same episode from names: what every script's worker calls, so a planner,
predictor and sensing are built the same way everywhere (:func:`superex_deploy.pipeline.make_predictor` /
:func:`~superex_deploy.pipeline.make_sensing` under one real-time profile) and each script keeps only its own
question (what it measures from the result). Every explorer of an episode is built by
:func:`superex_deploy.pipeline.build_explorer`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Optional, Union

import numpy as np

from superex_deploy.evaluation.metrics import evaluation_area, explorer_map_errors, map_iou
from superex_deploy.maps import OccupancyGrid, load_map
from superex_deploy.maps import coverage as coverage_of
from superex_deploy.onboard.explorer import STAGES, Explorer
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.types import Frontier, MapPredictor, Planner, Prediction
from superex_deploy.pipeline import (PROFILES, RealtimeProfile, build_explorer, make_predictor, make_sensing,
                                     resolve_profile)
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.sim.world import World, WorldConfig

__all__ = ["STAGES", "EpisodeState", "EpisodeResult", "make_world_and_explorer", "run_episode", "EpisodeRun",
           "run_benchmark_episode"]


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
        evaluation_s: float64 ``[T]`` seconds spent on metric evaluation per step (not part of the robot's loop).
        simulation_s: float64 ``[T]`` seconds the world spent per step simulating the sensors and the motion (not
            part of the robot's loop either).
        iou_steps, iou, iou_coverage: steps where the map IoU was evaluated, its value, and the coverage (with
            carving) there.
        goal_steps, goals: the steps where a new goal was chosen, and the goal cells.
        finished: True when the planner found no goal before the budget ran out.
        config: the :class:`ExplorationConfig` as a dict (``lidar``, ``explorer``: ``motion``,
            ``frontier_min_m``, ``prediction``, ``reuse``; ``iou_every``, ``iou_dense_until``; ``noise`` where
            on).
        final_observed: int8 ``[H, W]`` observed map at the end.
        final_carved: bool ``[H, W]`` carved cells at the end.
        final_prediction: the last prediction computed (for the final figure), or None.
        collisions: moves a wall stopped (:attr:`World.collisions <superex_deploy.sim.world.World.collisions>`).
        true_walls_carved: true wall cells the explorer carved at any step (each counted once).
        true_walls_held_free: true wall cells the explorer's final map holds free (seen or carved).
        true_walls_seen: true wall cells the explorer's final map holds known (free or occupied).
        true_walls_missing: the held-free true wall cells with no wall of the final map among their 8 neighbours
            (:class:`~superex_deploy.evaluation.metrics.MapErrors`).
        explorer_map_iou: wall-class IoU of the explorer's own final map (seen walls) against the truth, over
            the evaluation area (:func:`~superex_deploy.evaluation.metrics.evaluation_area`).
        explorer_map_iou_within_cell: the same IoU forgiving a wall held one cell off (diagonals included).
        true_poses, believed_poses: float64 ``[T, 3]`` ``(x, y, yaw)`` (metres, radians) of the robot's true pose
            and of the pose its observation carried, at each step's scan.
        status, reason: the last command's :attr:`~superex_deploy.messages.Command.status` and ``reason``.
        coverage_in_bounds: float64 ``[T]`` known fraction of the valid area inside the explorer's exploration
            bounds (``ExplorerConfig.bounds``; cells whose centre lies inside) after each scan, line of sight only;
            None without bounds.
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
    simulation_s: np.ndarray
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
    collisions: int = 0
    true_walls_carved: int = 0
    true_walls_held_free: int = 0
    explorer_map_iou: float = float("nan")
    true_walls_seen: int = 0
    true_walls_missing: int = 0
    explorer_map_iou_within_cell: float = float("nan")
    true_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    believed_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    status: str = ""
    reason: str = ""
    coverage_in_bounds: Optional[np.ndarray] = None

    @property
    def steps(self) -> int:
        """Number of logged steps ``T``."""
        return int(len(self.coverage))

    def to_json(self) -> dict:
        """JSON-ready dict: the per-step series, IoU log, goals, mean stage times, the config, and the errors of
        the explorer's map against the truth (``collisions``, ``true_walls_held_free``, ``true_walls_carved``,
        ``map_iou``: :attr:`explorer_map_iou`, ``true_walls_seen``, ``true_walls_missing``,
        ``map_iou_within_cell``), the last command's ``status`` and ``reason``, and with bounds
        ``coverage_in_bounds`` and ``final_coverage_in_bounds``."""
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
            "simulation_s": np.round(self.simulation_s, 6).tolist(),
            "mean_step_s": {stage: float(np.mean(values)) if len(values) else 0.0
                            for stage, values in self.timings_s.items()},
            "config": self.config,
            "collisions": int(self.collisions), "true_walls_held_free": int(self.true_walls_held_free),
            "true_walls_carved": int(self.true_walls_carved), "map_iou": float(self.explorer_map_iou),
            "true_walls_seen": int(self.true_walls_seen), "true_walls_missing": int(self.true_walls_missing),
            "map_iou_within_cell": float(self.explorer_map_iou_within_cell),
            "status": self.status, "reason": self.reason,
            **({} if self.coverage_in_bounds is None else {
                "coverage_in_bounds": np.round(self.coverage_in_bounds, 6).tolist(),
                "final_coverage_in_bounds": float(self.coverage_in_bounds[-1]) if self.steps else 0.0}),
        }


def _check_inputs(grid: OccupancyGrid, steps: int, cfg: ExplorationConfig, sensing) -> int:
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    if isinstance(steps, bool) or int(steps) != steps or int(steps) < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if not isinstance(cfg, ExplorationConfig):
        raise ValueError(f"cfg must be an ExplorationConfig, got {type(cfg).__name__}")
    if sensing is not None and not isinstance(sensing, SpadSensing):
        raise ValueError(f"sensing must be a SpadSensing or None, got {type(sensing).__name__}")
    return int(steps)


def make_world_and_explorer(grid: OccupancyGrid, start_rc, planner: Optional[Planner] = None,
                            predictor: Optional[MapPredictor] = None, seed: int = 0,
                            cfg: ExplorationConfig = ExplorationConfig(), sensing: Optional[SpadSensing] = None,
                            explorer: Optional[Explorer] = None) -> tuple[World, Explorer]:
    """The two halves of an episode: the :class:`World` on ``grid`` with the robot at ``start_rc``, and the
    explorer on the world's map frame: ``explorer`` where given, else a fresh :class:`Explorer` of ``planner`` and
    ``predictor`` built by :func:`superex_deploy.pipeline.build_explorer` (its checks; ``cfg.explorer`` as it is,
    the sensing's SPAD processing) (see :func:`run_episode` for the arguments).

    Raises:
        ValueError: both or neither of ``explorer`` and (``planner``, ``predictor``); a planner that is not a
            Planner instance, a predictor name (instances only here), what :func:`build_explorer
            <superex_deploy.pipeline.build_explorer>` refuses; an explorer on another frame,
            with another configuration than ``cfg.explorer``, or whose SPAD processing is not ``sensing``'s;
            exploration bounds (``cfg.explorer.bounds``) that do not contain the start.
    """
    given = (planner is not None, predictor is not None)
    if given != ((True, True) if explorer is None else (False, False)):
        raise ValueError("give either an explorer or a planner and a predictor")
    world = World(grid, start_rc, WorldConfig(lidar=cfg.lidar, spad=None if sensing is None else sensing.spad,
                                              step_m=cfg.explorer.motion.step_m,
                                              seed=0 if sensing is None else sensing.seed,
                                              noise=cfg.noise))
    if cfg.explorer.bounds is not None:  # refused here, before the explorer is built
        cfg.explorer.bounds.check_contains(world.pose.x, world.pose.y)
    if explorer is None:
        # Instances only (the episode's documented inputs): build_explorer would build a named one.
        if not isinstance(planner, Planner):
            raise ValueError(f"planner must be a Planner instance, got {type(planner).__name__}")
        if isinstance(predictor, str):
            raise ValueError(f"predictor must be a MapPredictor with predict(), got the name {predictor!r}")
        return world, build_explorer(world.frame, planner, predictor, spad=False if sensing is None else
                                     sensing.processing(), cfg=cfg.explorer, seed=seed)
    if not isinstance(explorer, Explorer):
        raise ValueError(f"explorer must be an Explorer, got {type(explorer).__name__}")
    if explorer.frame != world.frame:
        raise ValueError(f"the explorer's map frame {explorer.frame} is not the world's {world.frame}")
    if explorer.cfg != cfg.explorer:
        raise ValueError("the explorer's configuration is not cfg.explorer (the episode records cfg)")
    if explorer.spad_processing is not (None if sensing is None else sensing._processing):
        raise ValueError("the explorer's SPAD processing must be the sensing's (sensing.processing()), or None "
                         "without sensing")
    return world, explorer


def run_episode(grid: OccupancyGrid, start_rc, planner: Optional[Planner] = None,
                predictor: Optional[MapPredictor] = None, steps: int = 1000, seed: int = 0,
                cfg: ExplorationConfig = ExplorationConfig(), sensing: Optional[SpadSensing] = None,
                on_step: Optional[Callable[[EpisodeState], None]] = None,
                on_observation: Optional[Callable] = None, explorer: Optional[Explorer] = None) -> EpisodeResult:
    """Explore ``grid`` from ``start_rc`` for up to ``steps`` steps (see the module docstring).

    Args:
        grid: the ground-truth map (the world's; the explorer never sees it).
        start_rc: start cell (row, col): inside the map and its valid area, not a wall.
        planner: a :class:`~superex_deploy.onboard.types.Planner` instance (``planners.make_planner(name)``).
        predictor: a :class:`~superex_deploy.onboard.types.MapPredictor`.
        steps: step budget (>= 1).
        seed: seed of the generator handed to the planner.
        cfg: episode parameters.
        sensing: optional SPAD sensing (simulated in the world, processed by the explorer).
        on_step: optional callback, called once per step with the :class:`EpisodeState`.
        on_observation: optional callback ``(observation, command, explorer)`` once per step, right after the
            explorer's step (recording).
        explorer: a fresh explorer on the grid's frame instead of ``planner`` and ``predictor``
            (:func:`superex_deploy.pipeline.build_explorer` with ``cfg=cfg.explorer`` and
            ``spad=sensing.processing()``); the episode closes it.

    Returns:
        The :class:`EpisodeResult`.

    Raises:
        ValueError: a start off the map, inside a wall or outside the valid area, a non-positive step budget, a
            planner that is not a Planner, a predictor without ``predict``.
        RuntimeError: the planner returned a goal that no path reaches (a planner bug).
    """
    steps = _check_inputs(grid, steps, cfg, sensing)
    try:
        world, explorer = make_world_and_explorer(grid, start_rc, planner, predictor, seed, cfg, sensing, explorer)
    except BaseException:
        if explorer is not None:
            explorer.close()
        raise
    planner, predictor = explorer.planner, explorer.predictor
    iou_area = evaluation_area(grid) if cfg.iou_every else None
    try:
        return _loop(grid, planner, predictor, seed, cfg, world, explorer, steps, iou_area, on_step, on_observation)
    finally:
        explorer.close()


def _loop(grid, planner, predictor, seed, cfg, world, explorer, steps, iou_area, on_step, on_observation
          ) -> EpisodeResult:
    timings = {stage: np.zeros(steps) for stage in STAGES}
    evaluation_s, simulation_s = np.zeros(steps), np.zeros(steps)
    poses = np.zeros((steps, 2), np.int64)
    true_poses, believed_poses = np.zeros((steps, 3)), np.zeros((steps, 3))
    walls_carved = np.zeros(grid.shape, bool)
    coverage, coverage_carved, path_length = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    bounds = cfg.explorer.bounds
    region = None if bounds is None else grid.valid & bounds.mask(world.frame)
    coverage_in = np.zeros(steps)
    iou_steps: list[int] = []
    iou_values: list[float] = []
    iou_coverage: list[float] = []
    goal_steps: list[int] = []
    goals: list[tuple[int, int]] = []
    last_prediction: Optional[Prediction] = None
    finished = False
    logged = steps
    start = world.pose_rc
    command = None

    for t in range(steps):
        clock = time.perf_counter()
        observation = world.observe()
        simulation_s[t] = time.perf_counter() - clock
        poses[t] = world.pose_rc
        path_length[t] = world.driven_m
        truth, belief = world.pose, observation.pose
        true_poses[t], believed_poses[t] = (truth.x, truth.y, truth.yaw), (belief.x, belief.y, belief.yaw)

        command = explorer.step(observation)
        for stage in STAGES:
            timings[stage][t] = command.timings_s[stage]
        if on_observation is not None:
            on_observation(observation, command, explorer)
        coverage[t] = world.coverage(explorer.mapper.known(include_carved=False))
        coverage_carved[t] = world.coverage(explorer.mapper.known(include_carved=True))
        if region is not None:
            coverage_in[t] = coverage_of(explorer.mapper.known(include_carved=False), region)
        if command.new_goal:
            goal_steps.append(t)
            goals.append(command.goal_rc)
        finished = command.finished
        clock = time.perf_counter()
        walls_carved |= explorer.mapper.carved & grid.occupied
        evaluation_s[t] += time.perf_counter() - clock

        every = cfg.iou_every if coverage_carved[t] <= cfg.iou_dense_until else 10 * cfg.iou_every
        if cfg.iou_every and (t % every == 0 or t == steps - 1 or finished):
            clock = time.perf_counter()
            evaluated = explorer.predict()
            iou_steps.append(t)
            iou_values.append(map_iou(evaluated.mean, grid, area=iou_area))
            iou_coverage.append(float(coverage_carved[t]))
            evaluation_s[t] += time.perf_counter() - clock
        if explorer.step_prediction is not None:
            last_prediction = explorer.step_prediction
        if on_step is not None:
            on_step(EpisodeState(step=t, pose=world.pose_rc, mapper=explorer.mapper, observed=explorer.observed,
                                 frontiers=tuple(explorer.planning_grid.fine_frontier(f) for f in explorer.frontiers),
                                 goal=command.goal_rc, path=[tuple(cell) for cell in command.path_rc.tolist()],
                                 prediction=explorer.step_prediction, coverage=float(coverage[t])))
        if finished:
            logged = t + 1
            break
        clock = time.perf_counter()
        if world.pose_error is not None:
            # The controller drives from the pose the explorer planned from (its scan-matched correction of the
            # localisation's estimate, fed back as a map -> odom correction is): the path is read relative to it.
            world.belief = explorer.pose_estimate
        world.apply(command)
        simulation_s[t] += time.perf_counter() - clock

    final_observed = explorer.mapper.observed()
    errors = explorer_map_errors(final_observed, grid, iou_area)
    return EpisodeResult(
        map_name=grid.name, planner=planner.name, predictor=getattr(predictor, "name", type(predictor).__name__),
        seed=int(seed), start_rc=start, poses=poses[:logged], coverage=coverage[:logged],
        coverage_with_carving=coverage_carved[:logged], path_length_m=path_length[:logged],
        timings_s={stage: values[:logged] for stage, values in timings.items()},
        evaluation_s=evaluation_s[:logged], simulation_s=simulation_s[:logged], iou_steps=iou_steps,
        iou=iou_values, iou_coverage=iou_coverage, goal_steps=goal_steps, goals=goals, finished=finished,
        config=cfg.to_json(), final_observed=final_observed, final_carved=explorer.mapper.carved.copy(),
        final_prediction=last_prediction, collisions=world.collisions,
        true_walls_carved=int(np.count_nonzero(walls_carved)), true_walls_held_free=errors.held_free,
        explorer_map_iou=errors.map_iou, true_walls_seen=errors.seen, true_walls_missing=errors.missing,
        explorer_map_iou_within_cell=errors.map_iou_within_cell, true_poses=true_poses[:logged],
        believed_poses=believed_poses[:logged], status=command.status, reason=command.reason,
        coverage_in_bounds=None if region is None else coverage_in[:logged])


class EpisodeRun(NamedTuple):
    """An episode's result, the floor it ran on, and its wall-clock seconds (the episode alone: building the
    planner, predictor and sensing excluded)."""

    result: EpisodeResult
    grid: OccupancyGrid
    seconds: float


def run_benchmark_episode(floor: Union[str, OccupancyGrid], start_rc, planner, predictor="observed", *,
                          steps: int, planner_options: Optional[dict] = None, seed: int = 0,
                          cfg: Optional[ExplorationConfig] = None, profile: Optional[RealtimeProfile] = None,
                          spad: bool = False, sensing=None, cores: Optional[int] = None,
                          on_step: Optional[Callable] = None,
                          on_observation: Optional[Callable] = None) -> EpisodeRun:
    """Explore ``floor`` from ``start_rc`` for ``steps`` steps (:func:`run_episode`).

    Args:
        floor: a bundled map's name (loaded with :func:`~superex_deploy.maps.load_map`) or a grid (an altered
            floor).
        start_rc: the start cell ``(row, col)``.
        planner: a planner name (:func:`~superex_deploy.onboard.planning.planners.make_planner`, with
            ``planner_options``) or a planner object.
        predictor: a predictor name (:func:`~superex_deploy.pipeline.make_predictor` on the floor under
            ``profile``) or a predictor object.
        steps: step budget.
        seed: the episode's seed (and the SPAD noise's when the sensing is made here).
        cfg: the episode's config; by default the profile's (:meth:`RealtimeProfile.episode_config
            <superex_deploy.pipeline.RealtimeProfile.episode_config>`, on the simulated clock).
        profile: the real-time profile the predictor, the sensing and the default ``cfg`` are made under; None: the
            default profile where the planner can use it, else ``full``
            (:func:`~superex_deploy.pipeline.resolve_profile`). ``PROFILES["full"]`` with ``cfg`` left out is the
            unskipped pipeline (``ExplorationConfig()``).
        spad: the SPAD sensing of a named ``predictor`` (:func:`~superex_deploy.pipeline.make_sensing`, None
            without ``spad``); ignored when ``sensing`` is given.
        sensing: the episode's SPAD sensing object, instead of making one.
        cores: the cores a named predictor's sessions get (:func:`~superex_deploy.pipeline.make_predictor`).
        on_step, on_observation: passed to ``run_episode``.

    Raises:
        ValueError: ``spad`` with a predictor object and no ``sensing`` (the sensing is made for a predictor name).
    """
    grid = load_map(floor) if isinstance(floor, str) else floor
    if isinstance(planner, str):
        planner = make_planner(planner, **(planner_options or {}))
    if profile is None:
        name = predictor if isinstance(predictor, str) else getattr(predictor, "name", type(predictor).__name__)
        profile = PROFILES[resolve_profile(None, planner, name)]
    if isinstance(predictor, str):
        name, predictor = predictor, make_predictor(predictor, grid, profile=profile, cores=cores)
        if sensing is None:
            sensing = make_sensing(name, spad, seed, profile=profile)
    elif spad and sensing is None:
        raise ValueError("spad=True makes the sensing for a named predictor: pass sensing= with a predictor object")
    clock = time.perf_counter()
    result = run_episode(grid, tuple(start_rc), planner, predictor, steps=steps, seed=seed,
                         cfg=profile.episode_config() if cfg is None else cfg, sensing=sensing, on_step=on_step,
                         on_observation=on_observation)
    return EpisodeRun(result, grid, time.perf_counter() - clock)
