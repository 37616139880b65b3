"""Ceiling study of planner ideas on the train floors: each idea with the ``oracle`` predictor (the true map)
and with ``observed`` (unknown = free), paired by scenario against MapEx on the observed map.

A planner idea can turn predictions into speed only if its oracle run is clearly faster than its observed run
and than MapEx. Only train floors are used (``eval/`` is for reporting): the maps of at least
``--min-area`` valid cells (the eval floors have 85k-450k), every k-th of them to take ``--maps``, and
``--starts`` start cells each, drawn by :func:`superex_deploy.maps.random_start` from a generator seeded with
the map's name (:func:`superex_deploy.evaluation.train_scenarios`). Prints a table and writes JSON; the first-half
coverage AUC is the mean coverage over steps 1..steps/2.

    .venv/bin/python scripts/ceiling_study.py --maps 12 --steps 500 --out benchmarks/ceiling_study/ceiling_study_500.json
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import HELDOUT_BUILDINGS  # noqa: F401 (tests/test_generate.py reads it here)
from superex_deploy.evaluation import (bootstrap_interval, coverage_auc, coverage_curve, first_half_auc,
                                       markdown_table, run_benchmark_episode, train_scenarios, write_json)
from superex_deploy.parallel import process_pool
from superex_deploy.pipeline import PROFILES
from superex_deploy.sim.exploration import ExplorationConfig

IDEAS = {
    "mapex": ("mapex", {}),
    "superex": ("superex", {}),
    "superex_goal_gain": ("superex", {"gain": "goal"}),
    "superex_drop_resolved": ("superex", {"drop_resolved_m": 0.3}),
    "superex_wall_0.5": ("superex", {"wall_threshold": 0.5}),
    "superex_wall_0.8": ("superex", {"wall_threshold": 0.8}),
}
"""Name -> (planner, config overrides): MapEx; the superex planner as it ships (pathwise gain, greedy); with
MapEx's gain (the goal's view only); re-choosing once the goal's frontier is resolved (the rollout and tour
choices were retired: docs/benchmarks/better-map.md keeps their measurement)."""

BASELINE = ("mapex", "observed")
scenarios = train_scenarios
"""This study's scenario sets (:func:`superex_deploy.evaluation.train_scenarios`), under the name
tests/test_generate.py checks beside :data:`HELDOUT_BUILDINGS`."""


def _episode(task: tuple) -> dict:
    name, start, idea, planner, options, predictor, steps = task
    clock = time.perf_counter()
    result = run_benchmark_episode(name, start, planner, predictor, planner_options=options, steps=steps,
                                   cfg=ExplorationConfig(iou_every=0), profile=PROFILES["full"]).result
    at = coverage_curve(list(result.coverage), steps)
    return {"map": name, "start": list(start), "idea": idea, "predictor": predictor,
            "auc_first_half": first_half_auc(at, steps), "auc": coverage_auc(at, 1, steps),
            "final": float(at[-1]), "goals": len(result.goals),
            "scoring_ms_per_goal": 1000 * float(result.timings_s["scoring"].sum()) / max(len(result.goals), 1),
            "seconds": time.perf_counter() - clock}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", type=int, default=12)
    parser.add_argument("--starts", type=int, default=2)
    parser.add_argument("--min-area", type=int, default=40000)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--ideas", default="all", help="comma-separated names of IDEAS, or 'all'")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--predictors", default="oracle,observed",
                        help="predictors each idea runs with (lama_los / lama_bp: use --heldout)")
    parser.add_argument("--baseline", default="mapex:observed", help="IDEA:PREDICTOR every run is paired with")
    parser.add_argument("--heldout", action="store_true",
                        help="only the floors of the buildings held out of the models' training")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    ideas = list(IDEAS) if args.ideas == "all" else [i.strip() for i in args.ideas.split(",")]
    if any(i not in IDEAS for i in ideas):
        raise SystemExit(f"unknown idea(s); choose from {list(IDEAS)}")
    places = train_scenarios(args.maps, args.starts, args.min_area, args.heldout)
    baseline = tuple(args.baseline.split(":"))
    predictors = [p.strip() for p in args.predictors.split(",") if p.strip()]
    runs = [baseline] + [(i, p) for i in ideas for p in predictors if (i, p) != baseline]
    tasks = [(name, start, idea, *IDEAS[idea], predictor, args.steps) for idea, predictor in runs
             for name, start in places]
    print(f"{len(places)} scenarios on {len({n for n, _ in places})} train floors, {args.steps} steps, "
          f"{len(tasks)} episodes", flush=True)
    with process_pool(args.jobs) as pool:
        results = list(pool.map(_episode, tasks))
    base = {(r["map"], tuple(r["start"])): r for r in results if (r["idea"], r["predictor"]) == baseline}
    rows, cells = [], []
    for idea, predictor in runs:
        mine = [r for r in results if (r["idea"], r["predictor"]) == (idea, predictor)]
        diff = np.array([r["auc_first_half"] - base[(r["map"], tuple(r["start"]))]["auc_first_half"] for r in mine])
        low, high = bootstrap_interval(diff)
        mean = float(np.mean([r["auc_first_half"] for r in mine]))
        ratio = mean / float(np.mean([b["auc_first_half"] for b in base.values()])) - 1.0
        row = {"idea": idea, "predictor": predictor, "auc_first_half": mean, "ratio": ratio,
               "paired_mean": float(diff.mean()), "low": low, "high": high,
               "better": int((diff > 1e-9).sum()), "worse": int((diff < -1e-9).sum()),
               "auc": float(np.mean([r["auc"] for r in mine])),
               "scoring_ms_per_goal": float(np.median([r["scoring_ms_per_goal"] for r in mine])),
               "goals": float(np.mean([r["goals"] for r in mine]))}
        rows.append(row)
        cells.append([idea, predictor, f"{100 * mean:.1f}", f"{ratio:+.1%}",
                      f"{100 * row['paired_mean']:+.2f} [{100 * low:+.2f}, {100 * high:+.2f}]",
                      f"{row['better']} / {row['worse']}", f"{100 * row['auc']:.1f}",
                      f"{row['scoring_ms_per_goal']:.1f}", f"{row['goals']:.0f}"])
    header = ["idea", "predictor", "first-half AUC", f"vs {baseline[0]} {baseline[1]}", "paired mean [95 % interval]",
              "better / worse", "AUC whole", "scoring ms / goal", "goals"]
    print("\n" + "\n".join(markdown_table(header, cells, ["-", "-", "---:", "---:", "---:", "-", "---:", "---:",
                                                            "---:"])))
    if args.out is not None:
        write_json(args.out, {"scenarios": [[n, list(s)] for n, s in places], "steps": args.steps, "rows": rows,
                              "episodes": results})
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
