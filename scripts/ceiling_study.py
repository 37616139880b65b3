"""Ceiling study of planner ideas on the train floors: each idea with the ``oracle`` predictor (the true map)
and with ``observed`` (unknown = free), paired by scenario against MapEx on the observed map.

A planner idea can turn predictions into speed only if its oracle run is clearly faster than its observed run
and than MapEx. Only train floors are used (``eval/`` is for reporting): the maps of at least
``--min-area`` valid cells (the eval floors have 85k-450k), every k-th of them to take ``--maps``, and
``--starts`` start cells each, drawn by :func:`superex_deploy.maps.random_start` from a generator seeded with
the map's name. Prints a table and writes JSON; the first-half coverage AUC is the mean coverage over steps
1..steps/2.

    .venv/bin/python scripts/ceiling_study.py --maps 12 --steps 500 --out benchmarks/ceiling_study.json
"""

from __future__ import annotations

import argparse
import json
import time
import zlib
from pathlib import Path

import numpy as np

from superex_deploy.sim.suite import bootstrap_interval
from superex_deploy.maps import list_maps, load_map, map_building, random_start
from superex_deploy.parallel import process_pool

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
HELDOUT_BUILDINGS = (10, 20, 21, 28, 30)
"""``superex_train.generate.heldout_buildings()`` (asserted in the tests; the deploy side does not import
superex_train)."""


def scenarios(n_maps: int, starts: int, min_area: int, heldout: bool = False) -> list[tuple[str, tuple[int, int]]]:
    """(map, start cell) pairs on the train floors (see the module docstring); ``heldout``: only the floors of
    the buildings the learned models never trained on (``superex_train.generate.heldout_buildings``)."""
    names = [n for n in list_maps("train") if int(load_map(n).valid.sum()) >= min_area]
    if heldout:
        names = [n for n in names if map_building(n) in HELDOUT_BUILDINGS]
    names = names[::max(1, len(names) // n_maps)][:n_maps]
    out = []
    for name in names:
        grid = load_map(name)
        rng = np.random.default_rng(zlib.crc32(name.encode()))
        out += [(name, random_start(grid, rng, 0.5)) for _ in range(starts)]
    return out


def _episode(task: tuple) -> dict:
    from superex_deploy.pipeline import make_predictor
    from superex_deploy.sim.episode import ExplorationConfig, run_episode
    from superex_deploy.onboard.planning.planners import make_planner

    name, start, idea, planner, options, predictor, steps = task
    grid = load_map(name)
    clock = time.perf_counter()
    result = run_episode(grid, start, make_planner(planner, **options), make_predictor(predictor, grid),
                         steps=steps, cfg=ExplorationConfig(iou_every=0))
    coverage = list(result.coverage)
    at = [coverage[min(s, len(coverage)) - 1] for s in range(1, steps + 1)]
    return {"map": name, "start": list(start), "idea": idea, "predictor": predictor,
            "auc_first_half": float(np.mean(at[:max(steps // 2, 1)])), "auc": float(np.mean(at)),
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
    places = scenarios(args.maps, args.starts, args.min_area, args.heldout)
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
    rows = []
    print(f"\n| idea | predictor | first-half AUC | vs {baseline[0]} {baseline[1]} | paired mean [95 % interval] "
          "| better / "
          "worse | AUC whole | scoring ms / goal | goals |\n|---|---|---:|---:|---:|---|---:|---:|---:|")
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
        print(f"| {idea} | {predictor} | {100 * mean:.1f} | {ratio:+.1%} | {100 * row['paired_mean']:+.2f} "
              f"[{100 * low:+.2f}, {100 * high:+.2f}] | {row['better']} / {row['worse']} | {100 * row['auc']:.1f} "
              f"| {row['scoring_ms_per_goal']:.1f} | {row['goals']:.0f} |")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"scenarios": [[n, list(s)] for n, s in places], "steps": args.steps,
                                        "rows": rows, "episodes": results}, indent=1))
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
