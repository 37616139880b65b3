"""One benchmark episode from names, run in a worker process: what ``superex benchmark`` and its paper suite
(:mod:`superex_deploy.commands.paper_benchmark`) hand to :func:`superex_deploy.parallel.run_tasks`."""

from __future__ import annotations

__all__ = ["run_scenario"]


def run_scenario(task: tuple) -> dict:
    """One benchmark episode in a worker process; returns its JSON summary (no poses, no per-step timings).

    ``task``: ``(map, start index, start cell, planner, planner options, predictor, spad, steps, seed[, episode
    config overrides[, profile name]])``; the overrides default to an IoU evaluation every 50 steps, the profile to
    ``full`` (the paper suite's)."""
    from superex_deploy.pipeline import PROFILES, make_predictor, make_sensing
    from superex_deploy.sim.episode import ExplorationConfig, run_episode
    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.maps import load_map

    map_name, start_index, start, planner_name, options, predictor_name, spad, steps, seed = task[:9]
    iou_cfg = task[9] if len(task) > 9 else {"iou_every": 50}
    profile = PROFILES[task[10] if len(task) > 10 else "full"]
    grid = load_map(map_name)
    result = run_episode(grid, start, make_planner(planner_name, **options),
                         make_predictor(predictor_name, grid, profile=profile), steps=steps, seed=seed,
                         cfg=ExplorationConfig(prediction=profile.schedule, reuse=profile.reuse, **iou_cfg),
                         nlos=make_sensing(predictor_name, spad, seed, profile=profile))
    summary = result.to_json()
    summary["start_index"] = start_index
    summary["profile"] = task[10] if len(task) > 10 else "full"
    summary.pop("poses")
    summary.pop("timings_s")
    return summary
