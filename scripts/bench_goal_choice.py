"""What a goal choice costs, per planner, before and after the exact speed-ups of its scoring.

The speed-ups (the superex planner's frontiers scored in one compiled pass) are described in
docs/benchmarks/realtime.md, "Goal choices".

Two stages:

* ``--record``: explore train floors (:func:`superex_deploy.evaluation.train_scenarios`, held-out buildings) with each planner
  and its predictor (``superex``: LaMa-BP + SPAD, realtime profile; ``mapex``: LaMa-LOS, the ``full`` profile it
  resolves to; ``nearest``: observed), and save the explorer's inputs at every goal choice (the planning map's
  inputs, each ``choose_goal`` call's frontiers and the prediction it read) under ``--contexts`` (not committed).
* ``--bench`` (default): replay every recorded goal choice in isolation: the planning map (wall distance and
  Dijkstra from the robot) then the planner's ``choose_goal`` on each tier it was asked, once with the reference
  code (``tests/naive.py``: the implementation before the speed-ups, kept callable) and once with the current
  code, alternated (the order flips every repeat), ``--repeats`` times; a goal choice's time is its fastest
  repeat. Reports per planner the median / p90 / max ms per goal choice before and after, the same for the
  planning map and the scoring alone, and the share of goal choices whose chosen goal is the same (exact
  changes: 100 %).

    PYTHONPATH=$PWD SUPEREX_MODELS=$PWD/exported python scripts/bench_goal_choice.py --record --steps 300
    PYTHONPATH=$PWD SUPEREX_MODELS=$PWD/exported python scripts/bench_goal_choice.py --bench

Writes ``OUT/goal_choice.json`` and ``OUT/goal_choice.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Optional

import numpy as np

from superex_deploy.evaluation import write_json, write_text

ROOT = Path(__file__).resolve().parents[1]

PIPELINE_OF = {"superex": "superex", "mapex": "mapex_lama_los", "nearest": "nearest"}
"""Planner -> the named pipeline (``superex_deploy.pipeline.PIPELINES``) whose predictor, SPAD sensing and profile
its goal choices are recorded under."""


class _Recorder:
    """Wraps a planner: saves every ``choose_goal`` call's inputs, then delegates."""

    def __init__(self, planner, folder: Path, tag: str, reads_prediction: bool):
        self.planner, self.folder, self.tag, self.reads_prediction = planner, folder, tag, reads_prediction
        self.name, self.reads_variance = planner.name, planner.reads_variance
        self.calls, self.choices = 0, 0
        self._observed = None  # the tiers of one goal choice read the same map array

    def reset(self):
        self.planner.reset()

    def keep_goal(self, *args):
        return self.planner.keep_goal(*args)

    def choose_goal(self, ctx):
        if ctx.observed is not self._observed:
            self._observed = ctx.observed
            self.choices += 1
        frontiers = ctx.frontiers
        cells = [f.cells for f in frontiers]
        record = {"observed": ctx.observed, "pose_rc": np.array(ctx.pose_rc, np.int64),
                  "resolution_m": np.float64(ctx.resolution_m), "choice": np.int64(self.choices),
                  "goal_rc": np.array([f.cell_rc for f in frontiers], np.int64).reshape(-1, 2),
                  "frontier_offsets": np.cumsum([0] + [len(c) for c in cells]).astype(np.int64),
                  "frontier_cells": (np.concatenate(cells) if cells else np.zeros((0, 2))).astype(np.int32)}
        if self.reads_prediction and frontiers:
            prediction = ctx.predict()
            record["mean"], record["variance"] = prediction.mean, prediction.variance
        chosen = self.planner.choose_goal(ctx)
        record["chosen"] = np.array(chosen if chosen is not None else (-1, -1), np.int64)
        np.savez_compressed(self.folder / f"{self.tag}_{self.calls:04d}.npz", **record)
        self.calls += 1
        return chosen


def record(planners: list[str], n_maps: int, steps: int, folder: Path) -> None:
    """Explore ``n_maps`` held-out train floors for ``steps`` steps with each planner, saving every goal choice's
    inputs under ``folder/PLANNER/``."""
    from superex_deploy.evaluation import train_scenarios

    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.types import Planner
    from superex_deploy.pipeline import PIPELINES, PROFILES

    Planner.register(_Recorder)
    for name in planners:
        pipeline = PIPELINES[PIPELINE_OF[name]]
        predictor_name, spad, profile = pipeline.predictor, pipeline.spad, PROFILES[pipeline.profile]
        out = folder / name
        out.mkdir(parents=True, exist_ok=True)
        for map_name, start in train_scenarios(n_maps, 1, 40000, heldout=True):
            clock = time.perf_counter()
            recorder = _Recorder(make_planner(name), out, map_name, name != "nearest")
            run_benchmark_episode(map_name, start, recorder, predictor_name, steps=steps, seed=0,
                                  cfg=profile.episode_config(iou_every=0), profile=profile, spad=spad)
            print(f"recorded {name} {map_name}: {recorder.calls} calls, {time.perf_counter() - clock:.0f} s",
                  flush=True)


def _load(path: Path):
    from superex_deploy.onboard.types import Frontier, Prediction

    data = np.load(path)
    offsets = data["frontier_offsets"]
    frontiers = tuple(Frontier(cell_rc=(int(data["goal_rc"][i, 0]), int(data["goal_rc"][i, 1])),
                               cells=data["frontier_cells"][offsets[i]:offsets[i + 1]])
                      for i in range(len(offsets) - 1))
    prediction = Prediction(data["mean"], data["variance"]) if "mean" in data.files else None
    return {"observed": data["observed"], "pose_rc": (int(data["pose_rc"][0]), int(data["pose_rc"][1])),
            "resolution_m": float(data["resolution_m"]), "frontiers": frontiers, "prediction": prediction,
            "choice": int(data["choice"]), "recorded": tuple(int(v) for v in data["chosen"])}


def goal_choices(folder: Path) -> list[list[dict]]:
    """The recorded calls grouped into goal choices (the tiers offered at one step of one episode)."""
    choices: dict = {}
    for path in sorted(folder.glob("*.npz")):
        call = _load(path)
        choices.setdefault((path.name.rsplit("_", 1)[0], call["choice"]), []).append(call)
    return list(choices.values())


def _load_naive():
    """``tests/naive.py`` (the slow twins of the kernels), loaded from its file: the repository's tests are no
    package of the install."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("superex_tests_naive", ROOT / "tests" / "naive.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _Reference:
    """Within it, the planners score with the code before the speed-ups (``tests/naive.py``)."""

    def __enter__(self):
        from superex_deploy.onboard.planning.planners import hector, mapex, superex
        naive = _load_naive()

        self.saved = [(superex.SuperexPlanner, "gains", superex.SuperexPlanner.gains),
                      (mapex, "visible_gains", mapex.visible_gains), (hector, "visible_gains", hector.visible_gains)]
        original_gains = superex.SuperexPlanner.gains

        def gains(planner, ctx, prediction, frontiers):
            if planner.cfg.gain == "path":
                return naive.reference_superex_gains(planner, ctx, prediction, frontiers)
            return original_gains(planner, ctx, prediction, frontiers)

        superex.SuperexPlanner.gains = gains
        mapex.visible_gains = hector.visible_gains = naive.reference_visible_gains
        return self

    def __exit__(self, *exc):
        for owner, name, value in self.saved:
            setattr(owner, name, value)


def _choose(planner_name: str, choice: list[dict]) -> tuple[Optional[tuple[int, int]], float, float]:
    """Replay one goal choice: the planning map, then each recorded tier. Returns the last tier's goal, the
    planning map's and the scoring's seconds."""
    from superex_deploy.onboard.planning.motion import planning_map
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.types import PlanningContext

    first = choice[0]
    clock = time.perf_counter()
    plan = planning_map(first["observed"], first["pose_rc"], first["resolution_m"])
    planning_s = time.perf_counter() - clock
    planner = make_planner(planner_name)
    chosen = None
    clock = time.perf_counter()
    for call in choice:
        prediction = call["prediction"]
        ctx = PlanningContext(observed=call["observed"], pose_rc=call["pose_rc"], frontiers=call["frontiers"],
                              travel_cost=plan.travel_cost, traversable=plan.traversable,
                              resolution_m=call["resolution_m"], predict=lambda: prediction,
                              rng=np.random.default_rng(0))
        chosen = planner.choose_goal(ctx)
    return chosen, planning_s, time.perf_counter() - clock


def _settled_share(call: dict) -> float:
    """The share of the planning map's reachable cells whose cost-to-go is at most the farthest reachable frontier
    cell's (of any region size: the explorer's tiers may offer any): what a Dijkstra stopped once every frontier
    cell is settled would still have to settle (NaN without a reachable frontier cell)."""
    from superex_deploy.onboard.planning.frontiers import frontier_cells
    from superex_deploy.onboard.planning.motion import planning_map

    cost = planning_map(call["observed"], call["pose_rc"], call["resolution_m"]).travel_cost
    reachable = np.isfinite(cost)
    frontier = frontier_cells(call["observed"]) & reachable
    if not frontier.any():
        return float("nan")
    return float(np.count_nonzero(reachable & (cost <= cost[frontier].max())) / np.count_nonzero(reachable))


def bench(planners: list[str], folder: Path, repeats: int, out: Path) -> None:
    rows = {}
    for name in planners:
        choices = goal_choices(folder / name)
        times = {"before": np.full((len(choices), 2), np.inf), "after": np.full((len(choices), 2), np.inf)}
        same, as_recorded = 0, 0
        settled = []  # share of the Dijkstra's reachable cells no farther than the farthest frontier cell
        for i, choice in enumerate(choices):
            settled.append(_settled_share(choice[0]))
            goals = {}
            for repeat in range(repeats + 1):  # the first round compiles and warms, unmeasured
                for variant in (("before", "after") if (i + repeat) % 2 == 0 else ("after", "before")):
                    if variant == "before":
                        with _Reference():
                            goal, planning_s, scoring_s = _choose(name, choice)
                    else:
                        goal, planning_s, scoring_s = _choose(name, choice)
                    goals[variant] = goal
                    if repeat > 0:
                        times[variant][i] = np.minimum(times[variant][i], (planning_s, scoring_s))
            same += goals["before"] == goals["after"]
            as_recorded += goals["after"] == choice[-1]["recorded"]
        row = {"goal_choices": len(choices), "same_goal": same / max(len(choices), 1),
               "same_as_recorded": as_recorded / max(len(choices), 1),
               "frontiers_median": float(np.median([len(c[0]["frontiers"]) for c in choices])),
               "dijkstra_share_needed": {"median": float(np.nanmedian(settled)),
                                         "p10": float(np.nanpercentile(settled, 10))}}
        for variant, values in times.items():
            for stage, column in (("total", values.sum(axis=1)), ("planning_map", values[:, 0]),
                                  ("scoring", values[:, 1])):
                row[f"{variant}_{stage}_ms"] = {"median": float(np.median(column) * 1e3),
                                                "p90": float(np.percentile(column, 90) * 1e3),
                                                "max": float(column.max() * 1e3)}
        rows[name] = row
        print(name, json.dumps(row), flush=True)
    load = os.getloadavg()
    meta = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores",
            "load_average_1_5_15": [round(v, 2) for v in load], "repeats": repeats,
            "numba_threads": os.environ.get("NUMBA_NUM_THREADS", "default"),
            "note": "each goal choice's time is the fastest of its repeats, before / after alternated"}
    write_json(out / "goal_choice.json", {"meta": meta, "planners": rows})
    lines = ["| planner | goal choices | frontiers (median) | stage | before ms: median / p90 / max | "
             "after ms: median / p90 / max | speed-up: median / max | same goal |",
             "|---|---:|---:|---|---:|---:|---:|---:|"]
    for name, row in rows.items():
        for stage in ("total", "planning_map", "scoring"):
            before, after = row[f"before_{stage}_ms"], row[f"after_{stage}_ms"]
            cells = [" / ".join(f"{value[k]:.1f}" for k in ("median", "p90", "max")) for value in (before, after)]
            ratio = " / ".join(f"{before[k] / max(after[k], 1e-9):.1f}x" for k in ("median", "max"))
            lines.append(f"| {name} | {row['goal_choices']} | {row['frontiers_median']:.0f} | {stage} | {cells[0]} | "
                         f"{cells[1]} | {ratio} | {100 * row['same_goal']:.0f} % |")
    header = [f"Machine: {meta['machine']}, shared with other jobs (load average {meta['load_average_1_5_15']} at the "
              f"end); NUMBA_NUM_THREADS={meta['numba_threads']}; each goal choice timed {repeats} times before and "
              "after, alternated, fastest kept. Absolute times are inflated by the load; the ratios and the goals "
              "are what to read.", ""]
    footer = ["", "Share of the Dijkstra's reachable cells a search stopped at the farthest frontier cell would still "
              "settle (median / 10th percentile): " + ", ".join(
                  f"{name} {row['dijkstra_share_needed']['median']:.2f} / {row['dijkstra_share_needed']['p10']:.2f}"
                  for name, row in rows.items()) + ".",
              "", "Goal choices whose goal (after) is the one the recorded episode chose: " + ", ".join(
                  f"{name} {100 * row['same_as_recorded']:.0f} %" for name, row in rows.items()) + "."]
    write_text(out / "goal_choice.md", "\n".join(header + lines + footer) + "\n")
    print("\n".join(lines))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help="record goal choices (else: benchmark them)")
    parser.add_argument("--planners", default="superex,mapex,nearest")
    parser.add_argument("--maps", type=int, default=3, help="held-out train floors per planner (--record)")
    parser.add_argument("--steps", type=int, default=300, help="steps per episode (--record)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per goal choice (--bench)")
    parser.add_argument("--contexts", type=Path, default=ROOT / "runs" / "goal_choice_contexts")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "goal_choice")
    args = parser.parse_args()
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    unknown = [p for p in planners if p not in PIPELINE_OF]
    if unknown:
        raise SystemExit(f"unknown planner(s) {unknown}; choose from {', '.join(PIPELINE_OF)}")
    if args.record:
        record(planners, args.maps, args.steps, args.contexts)
    else:
        bench(planners, args.contexts, args.repeats, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
