"""Does letting a clearly better goal replace the kept one help? ``GoalPolicy.commit_margin`` on held-out train floors.

By default the explorer keeps a goal until it is reached, blocked or let go by the planner (MapEx's locked
frontier: ``commit_margin=None``). With a margin the planner is asked every step and its new choice replaces the
kept goal when it scores more than ``1 + margin`` times as much (:mod:`superex_deploy.onboard.planning.goal_policy`).
Each held-out train scenario (:func:`superex_deploy.evaluation.heldout_scenarios`: floors of buildings the learned
models never trained on; never the eval floors) is explored with the SuperEx planner on LaMa-BP with SPAD sensing,
under the default real-time profile on the simulated clock, once per margin; the table gives the mean first-half
coverage AUC (with carving) and its paired difference to the default with a 95 % bootstrap interval, the path
driven and the goals chosen.

    PYTHONPATH=$PWD python scripts/bench_goal_policy.py --scenarios 8 --steps 300 --jobs 2 --out benchmarks/goal_policy

Writes ``OUT/goal_policy.json`` and ``OUT/goal_policy.md``; ``OUT/episodes.jsonl`` is the resumable journal (not
committed).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Optional

import numpy as np

MARGINS = (None, 0.0, 0.1, 0.25)
PIPELINE = "superex"
"""The named pipeline every episode runs (``superex_deploy.pipeline.PIPELINES``), its goal policy's margin varied."""


def run_one(task: tuple) -> dict:
    """One episode: ``(map, start index, start cell, margin, steps)``; returns what the report reads."""
    from dataclasses import replace

    from superex_deploy.maps import load_map
    from superex_deploy.messages import MapFrame
    from superex_deploy.onboard.planning.goal_policy import GoalPolicy
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import PIPELINES, build_explorer, check_profile, make_sensing
    from superex_deploy.evaluation.episodes import run_episode

    name, start_index, start, margin, steps = task
    grid = load_map(name)
    pipeline = PIPELINES[PIPELINE]
    planner = make_planner(pipeline.planner)
    profile = check_profile(pipeline.profile, planner, pipeline.predictor)
    cfg = profile.episode_config(iou_every=0)
    cfg = replace(cfg, explorer=replace(cfg.explorer, goal_policy=GoalPolicy(commit_margin=margin)))
    sensing = make_sensing(pipeline.predictor, pipeline.spad, 0, profile=profile)
    explorer = build_explorer(MapFrame(grid.shape, grid.resolution_m), planner, pipeline.predictor,
                              profile=pipeline.profile, spad=sensing.processing(), seed=0, cfg=cfg.explorer, grid=grid)
    result = run_episode(grid, tuple(start), explorer=explorer, steps=steps, seed=0, cfg=cfg, sensing=sensing)
    return {"map": name, "start_index": start_index, "margin": margin, "steps": steps,
            "episode_steps": result.steps, "finished": result.finished,
            "coverage_with_carving": np.round(result.coverage_with_carving, 6).tolist(),
            "path_m": float(result.path_length_m[-1]) if result.steps else 0.0, "goals": len(result.goal_steps),
            "step_s": float(np.mean(sum(result.timings_s.values()))) if result.steps else 0.0}


def _label(margin: Optional[float]) -> str:
    return "None (default)" if margin is None else f"{margin:g}"


def report(out: Path, episodes: list[dict], steps: int) -> dict:
    from superex_deploy.evaluation import bootstrap_interval, first_half_auc, markdown_table
    from superex_deploy.pipeline import PIPELINES

    pipeline = PIPELINES[PIPELINE]
    by = {}
    for e in episodes:
        by.setdefault((e["map"], e["start_index"]), {})[e["margin"]] = e
    pairs = [v for v in by.values() if all(m in v for m in MARGINS)]
    auc = {m: np.array([100 * first_half_auc(p[m]["coverage_with_carving"], steps) for p in pairs]) for m in MARGINS}
    rows, result = [], {"scenarios": len(pairs), "steps": steps, "planner": pipeline.planner,
                        "predictor": pipeline.predictor, "spad": pipeline.spad, "settings": {}}
    for m in MARGINS:
        diff = auc[m] - auc[None]
        low, high = bootstrap_interval(diff) if m is not None else (0.0, 0.0)
        path = np.mean([p[m]["path_m"] for p in pairs])
        goals = np.mean([p[m]["goals"] for p in pairs])
        step_ms = 1000 * np.mean([p[m]["step_s"] for p in pairs])
        better = int(np.sum(diff > 0))
        rows.append([_label(m), f"{auc[m].mean():.2f}",
                     "-" if m is None else f"{diff.mean():+.2f} [{low:+.2f}, {high:+.2f}]",
                     "-" if m is None else f"{better} / {int(np.sum(diff < 0))}", f"{path:.1f}", f"{goals:.1f}",
                     f"{step_ms:.0f}"])
        result["settings"][_label(m)] = {"commit_margin": m, "first_half_auc": float(auc[m].mean()),
                                         "difference": float(diff.mean()), "interval": [low, high],
                                         "better_worse": [better, int(np.sum(diff < 0))], "path_m": float(path),
                                         "goals": float(goals), "step_ms": float(step_ms),
                                         "per_scenario_auc": auc[m].round(4).tolist()}
    lines = ["# Goal commitment: `GoalPolicy.commit_margin`", "",
             f"{len(pairs)} held-out train scenarios (`heldout_scenarios`), {steps} steps, the "
             f"`{pipeline.planner}` planner on `{pipeline.predictor}` with SPAD sensing, the default profile on the "
             "simulated clock. First-half AUC: mean "
             "coverage with carving over the first half of the steps (%); paired difference to the default with a 95 % "
             "bootstrap interval; better / worse: scenarios whose AUC rose / fell. Step time: mean explorer step "
             "on this project's 2-core sandbox (read it relatively).", "",
             *markdown_table(["commit_margin", "first-half AUC (%)", "paired difference [95 %]", "better / worse",
                              "path (m)", "goals", "step (ms)"], rows), "",
             "`scripts/bench_goal_policy.py` wrote this file; `goal_policy.json` holds the per-scenario values."]
    (out / "goal_policy.md").write_text("\n".join(lines) + "\n")
    (out / "goal_policy.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", type=int, default=8, help="held-out train scenarios (one start per floor)")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/goal_policy"))
    args = parser.parse_args()

    from superex_deploy.evaluation import heldout_scenarios
    from superex_deploy.parallel import run_tasks

    args.out.mkdir(parents=True, exist_ok=True)
    tasks = [(s.map_name, s.start_index, list(s.start_rc), m, args.steps) for s in heldout_scenarios(args.scenarios)
             for m in MARGINS]
    keys = [f"{t[0]}:{t[1]}:{_label(t[3])}:{t[4]}" for t in tasks]
    episodes = run_tasks(run_one, tasks, keys, args.jobs, args.out / "episodes.jsonl", progress="goal policy")
    print((args.out / "goal_policy.md").read_text() if report(args.out, episodes, args.steps) else "")


if __name__ == "__main__":
    main()
