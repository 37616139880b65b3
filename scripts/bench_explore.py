"""Benchmark exploration episodes: per-step time per stage and whole-episode time per planner.

Runs one episode per (map, planner) from start pose 0 with the honest ``ObservedAsPrediction`` predictor and
reports, per stage (scan, map update, frontiers, prediction, scoring, path), the mean time per step over the
whole episode and over its first and last 100 steps (a stage whose cost grew with the step count shows up
there), plus the whole-episode wall time (metric evaluation included). Prints a markdown table and writes JSON.

    .venv/bin/python scripts/bench_explore.py --steps 1000 --out benchmarks/explore/bench_explore.json
"""

from __future__ import annotations

import argparse
import platform
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import run_benchmark_episode, write_json
from superex_deploy.evaluation.episodes import STAGES
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.maps import load_map, start_poses
from superex_deploy.pipeline import PROFILES

WINDOW = 100


def _ms(values: np.ndarray) -> float:
    return float(values.mean() * 1e3) if len(values) else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", default="50052750,50010535_PLAN1", help="comma-separated bundled eval maps")
    parser.add_argument("--planners", default="nearest,hector,upen,mapex", help="comma-separated planner names")
    parser.add_argument("--steps", type=int, default=1000, help="step budget per episode")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/explore/bench_explore.json"), help="JSON output")
    args = parser.parse_args()
    maps = [m.strip() for m in args.maps.split(",") if m.strip()]
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    planner_objects = {name: make_planner(name) for name in planners}  # unknown names fail before any work

    # Load every compiled kernel once, so the first timed episode does not pay for it.
    warm = load_map("50052749")
    for name in planners:
        run_benchmark_episode(warm, start_poses(warm.name)[0], name, ObservedAsPrediction(), steps=3,
                              profile=PROFILES["full"])

    rows = []
    for map_name in maps:
        grid = load_map(map_name)
        for name in planners:
            result, _, wall = run_benchmark_episode(grid, start_poses(map_name)[0], planner_objects[name],
                                                    ObservedAsPrediction(), steps=args.steps, seed=0,
                                                    profile=PROFILES["full"])
            per_step = sum(result.timings_s[s] for s in STAGES)
            rows.append({
                "map": map_name, "shape": list(grid.shape), "planner": name, "steps": result.steps,
                "finished": result.finished, "episode_s": wall,
                "stage_ms": {s: _ms(result.timings_s[s]) for s in STAGES},
                "stage_first100_ms": {s: _ms(result.timings_s[s][:WINDOW]) for s in STAGES},
                "stage_last100_ms": {s: _ms(result.timings_s[s][-WINDOW:]) for s in STAGES},
                "step_ms": _ms(per_step),
                "first100_ms": _ms(per_step[:WINDOW]),
                "last100_ms": _ms(per_step[-WINDOW:]),
                "evaluation_ms": _ms(result.evaluation_s),
                "goals": len(result.goals),
                "final_coverage": float(result.coverage[-1]),
                "path_length_m": float(result.path_length_m[-1]),
            })
            print(f"{map_name} {name}: {wall:.1f} s", flush=True)

    header = ("| map | planner | steps | episode s | " + " | ".join(f"{s} ms" for s in STAGES)
              + " | ms/step first 100 | ms/step last 100 | goals | coverage |")
    lines = [header, "|---|---|---:|---:|" + "---:|" * (len(STAGES) + 4)]
    for r in rows:
        stages = " | ".join(f"{r['stage_ms'][s]:.2f}" for s in STAGES)
        lines.append(f"| {r['map']} | {r['planner']} | {r['steps']} | {r['episode_s']:.1f} | {stages} | "
                     f"{r['first100_ms']:.2f} | {r['last100_ms']:.2f} | {r['goals']} | {r['final_coverage']:.3f} |")
    stage_lines = ["| map | planner | " + " | ".join(f"{s} first/last 100 ms" for s in STAGES) + " |",
                   "|---|---|" + "---:|" * len(STAGES)]
    for r in rows:
        cells = " | ".join(f"{r['stage_first100_ms'][s]:.2f} / {r['stage_last100_ms'][s]:.2f}" for s in STAGES)
        stage_lines.append(f"| {r['map']} | {r['planner']} | {cells} |")
    print("\n".join(lines))
    print()
    print("\n".join(stage_lines))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, {"machine": platform.platform(), "processor": platform.processor(), "steps": args.steps,
                          "rows": rows}, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
