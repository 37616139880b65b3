"""Benchmark exploration episodes: per-step time per stage and whole-episode time per planner.

Runs one episode per (map, planner) from start pose 0 with the honest ``ObservedAsPrediction`` predictor, and
reports the mean time per step of each stage (scan, map update, frontiers, prediction, scoring, path), the
whole-episode wall time, and the mean step time over the first and the last 100 steps (a stage whose cost grew
with the step count would show up there). Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from superex_deploy.explore.episode import STAGES, run_episode
from superex_deploy.explore.planners import make_planner
from superex_deploy.explore.prediction import ObservedAsPrediction
from superex_deploy.maps import load_map, start_poses


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", default="50052750,50010535_PLAN1")
    parser.add_argument("--planners", default="nearest,hector,upen,mapex")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=Path("bench_explore.json"))
    args = parser.parse_args()
    warm = load_map("50052749")
    run_episode(warm, start_poses(warm.name)[0], make_planner("mapex"), ObservedAsPrediction(), steps=5)
    rows = []
    for name in args.maps.split(","):
        grid = load_map(name)
        for planner in args.planners.split(","):
            start = time.perf_counter()
            result = run_episode(grid, start_poses(name)[0], make_planner(planner), ObservedAsPrediction(),
                                 steps=args.steps, seed=0)
            wall = time.perf_counter() - start
            per_step = sum(result.timings_s[s] for s in STAGES)
            rows.append({
                "map": name, "planner": planner, "steps": len(result.coverage), "episode_s": wall,
                "stage_ms": {s: float(result.timings_s[s].mean() * 1e3) for s in STAGES},
                "first100_ms": float(per_step[:100].mean() * 1e3),
                "last100_ms": float(per_step[-100:].mean() * 1e3),
                "final_coverage": float(result.coverage[-1]) if len(result.coverage) else 0.0,
            })
    header = "| map | planner | steps | episode s | " + " | ".join(f"{s} ms" for s in STAGES) \
        + " | first 100 ms/step | last 100 ms/step | coverage |"
    print(header)
    print("|---|---|---:|---:|" + "---:|" * (len(STAGES) + 3))
    for r in rows:
        stages = " | ".join(f"{r['stage_ms'][s]:.2f}" for s in STAGES)
        print(f"| {r['map']} | {r['planner']} | {r['steps']} | {r['episode_s']:.1f} | {stages} | "
              f"{r['first100_ms']:.2f} | {r['last100_ms']:.2f} | {r['final_coverage']:.3f} |")
    args.out.write_text(json.dumps(rows, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
