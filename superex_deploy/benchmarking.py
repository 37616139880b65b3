"""One benchmark episode from names, run in a worker process: what ``superex benchmark`` and its paper suite
(:mod:`superex_deploy.commands.paper_benchmark`) hand to :func:`superex_deploy.parallel.run_tasks`."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["ScenarioTask", "run_scenario"]


@dataclass(frozen=True, kw_only=True)
class ScenarioTask:
    """One benchmark episode, by names (picklable: it travels to worker processes and Ray tasks).

    Attributes:
        map_name: bundled map name.
        start_index: index of the start pose among the map's start poses (recorded in the summary).
        start_rc: the start cell (row, col).
        planner: planner name (``planners.make_planner``).
        predictor: predictor name (:data:`superex_deploy.pipeline.PREDICTORS`).
        spad: simulate the SPAD LiDAR every step.
        steps: step budget.
        seed: the planner's seed and the SPAD noise's.
        planner_options: overrides of the planner's config (``--planner-option``).
        iou_every, iou_dense_until: when the map IoU is evaluated (see
            :class:`~superex_deploy.sim.episode.ExplorationConfig`); by default every 50 steps.
        profile: the real-time profile's name (:data:`superex_deploy.pipeline.PROFILES`); by default ``full``
            (the paper suite's).
    """

    map_name: str
    start_index: int
    start_rc: tuple[int, int]
    planner: str
    predictor: str
    spad: bool
    steps: int
    seed: int
    planner_options: dict = field(default_factory=dict)
    iou_every: int = 50
    iou_dense_until: float = 1.0
    profile: str = "full"


def run_scenario(task: ScenarioTask) -> dict:
    """One benchmark episode in a worker process; returns its JSON summary (no poses, no per-step timings), with
    the task's ``start_index`` and ``profile``."""
    from superex_deploy.pipeline import PROFILES, make_predictor, make_sensing
    from superex_deploy.sim.episode import run_episode
    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.maps import load_map

    profile = PROFILES[task.profile]
    grid = load_map(task.map_name)
    result = run_episode(grid, task.start_rc, make_planner(task.planner, **task.planner_options),
                         make_predictor(task.predictor, grid, profile=profile), steps=task.steps, seed=task.seed,
                         cfg=profile.episode_config(iou_every=task.iou_every, iou_dense_until=task.iou_dense_until),
                         sensing=make_sensing(task.predictor, task.spad, task.seed, profile=profile))
    summary = result.to_json()
    summary["start_index"] = task.start_index
    summary["profile"] = task.profile
    summary.pop("poses")
    summary.pop("timings_s")
    return summary
