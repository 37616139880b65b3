"""How well the onboard NLOS-gain estimate (:mod:`superex_deploy.onboard.planning.nlos_gain`) stands in for the true
carve gain, goal choice by goal choice, on held-out train floors (issue #44, item 1; never ``eval/``).

Today's planner explores each scenario (the ``superex`` pipeline as it ships, seed 0). At every goal choice, for
every frontier it scores, the study records the line-of-sight gain (today's), the **true** carve gain along the
path (``ceiling_carve_gain.TrueCarveGain``: a noise-free scan simulated on the true grid at each path viewpoint
and carved as the robot carves, union over the path, unknown cells counted) and the **estimate** of each variant
(``union_nlos_gains`` with that variant's :class:`~superex_deploy.onboard.planning.nlos_gain.NlosGainConfig`, on
the observed map and the prediction the planner read). Per variant:

* ``estimate / truth``: the summed estimate over the summed truth (its scale);
* ``rank corr.``: the median over choices (of 3 frontiers or more) of the Spearman correlation between estimate and
  truth across the choice's frontiers;
* ``same goal as the ceiling``: the share of choices where ``(LOS + WEIGHT x estimate) / cost`` picks the frontier
  ``(LOS + WEIGHT x truth) / cost`` picks (the decision the ceiling planner made; ``today`` row: the LOS gain alone).

    NUMBA_NUM_THREADS=1 PYTHONPATH=. SUPEREX_MODELS=exported .venv/bin/python scripts/study_nlos_gain.py \\
        --scenarios 17 --steps 350 --out benchmarks/nlos_gain

Writes ``OUT/study.md`` and ``OUT/study.json``; the per-choice records in ``OUT/choices/`` (one JSON per scenario; a
rerun skips those there).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

VARIANTS = {
    "threshold_0.5": {},
    "threshold_0.3": {"wall_threshold": 0.3},
    "threshold_0.15": {"wall_threshold": 0.15},
    "observed_walls": None,  # the observed walls alone (no prediction): what the map alone says
}
"""Variant name -> NlosGainConfig overrides (None: the default config on the observed walls only)."""


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.stats import spearmanr

    if np.all(a == a[0]) or np.all(b == b[0]):
        return float("nan")
    return float(spearmanr(a, b).statistic)


def record_scenario(scenario, steps: int, seed: int = 0) -> dict:
    """Run today's planner on ``scenario`` and record, at each goal choice, per frontier: travel cost, LOS gain,
    true carve gain and each variant's estimate."""
    from ceiling_carve_gain import PIPELINE, TrueCarveGain

    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.planning.nlos_gain import NlosGainConfig, union_nlos_gains
    from superex_deploy.onboard.planning.planners import SuperexPlanner
    from superex_deploy.pipeline import PIPELINES, PROFILES, make_sensing

    pipeline = PIPELINES[PIPELINE]
    profile = PROFILES[pipeline.profile]
    grid = load_map(scenario.map_name)
    sensing = make_sensing(pipeline.predictor, pipeline.spad, seed, profile=profile)
    truth = TrueCarveGain(grid, sensing.spad, sensing.nlos_cfg)
    choices = []

    class Recorder(SuperexPlanner):
        def gains(self, ctx, prediction, frontiers):
            cells, offsets = self.viewpoints(ctx, frontiers)
            los = np.asarray(self.los_gains(ctx, prediction, cells, offsets), float)
            true = truth.gains(np.asarray(ctx.observed), [tuple(c) for c in cells.tolist()], offsets)
            record = {"step": len(choices), "cost": [float(ctx.travel_cost[f.cell_rc]) for f in frontiers],
                      "los": los.tolist(), "true": true.tolist(), "estimate": {}}
            for name, overrides in VARIANTS.items():
                cfg = NlosGainConfig(**(overrides or {}))
                mean = prediction.mean if overrides is not None else np.zeros_like(prediction.mean)
                record["estimate"][name] = union_nlos_gains(ctx.observed, mean, cells, offsets, cfg,
                                                            ctx.resolution_m).astype(float).tolist()
            choices.append(record)
            return los

    run_benchmark_episode(grid, scenario.start_rc, Recorder(), pipeline.predictor, steps=steps, seed=seed,
                          cfg=profile.episode_config(iou_every=0), profile=profile, sensing=sensing)
    return {"map": scenario.map_name, "start_index": scenario.start_index, "start_rc": list(scenario.start_rc),
            "steps": steps, "choices": choices}


def summarise(records: list[dict], weight: float) -> tuple[dict, str]:
    """Per variant (and ``today``): scale, median rank correlation, agreement with the ceiling's choice."""
    from superex_deploy.evaluation import markdown_table

    rows, result = [], {"weight": weight, "scenarios": len(records),
                        "choices": sum(len(r["choices"]) for r in records), "variants": {}}

    def pick(los, extra, cost):
        return int(np.argmax((los + weight * extra) / np.maximum(cost, 1.0)))

    names = ["today"] + list(VARIANTS)
    for name in names:
        est_sum = true_sum = 0.0
        corr, same, n = [], 0, 0
        for r in records:
            for ch in r["choices"]:
                los, true, cost = (np.array(ch[k], float) for k in ("los", "true", "cost"))
                est = np.zeros_like(los) if name == "today" else np.array(ch["estimate"][name], float)
                target = pick(los, true, cost)
                same += int(pick(los, est, cost) == target)
                n += 1
                if name != "today":
                    est_sum += est.sum()
                    true_sum += true.sum()
                    if len(los) >= 3:
                        corr.append(_spearman(est, true))
        corr = np.array(corr, float)
        median_corr = float(np.nanmedian(corr)) if np.isfinite(corr).any() else None
        scale = est_sum / true_sum if true_sum > 0 else None
        result["variants"][name] = {"scale": scale, "rank_correlation_median": median_corr,
                                    "same_goal_as_ceiling": same / max(n, 1), "choices": n}
        rows.append([name, "-" if scale is None else f"{scale:.2f}",
                     "-" if median_corr is None else f"{median_corr:.2f}", f"{100 * same / max(n, 1):.1f} %"])
    text = [f"{result['choices']} goal choices of today's planner on {len(records)} held-out train scenarios "
            f"(the `superex` pipeline, seed 0); weight {weight:g} in the choice rule.", ""]
    text += markdown_table(["estimate", "estimate / truth", "rank corr. (median)", "same goal as the ceiling"],
                           rows, ["-", "---:", "---:", "---:"])
    return result, "\n".join(text) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=17)
    parser.add_argument("--starts", type=int, default=1)
    parser.add_argument("--steps", type=int, default=350)
    parser.add_argument("--weight", type=float, default=3.0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "nlos_gain")
    args = parser.parse_args(argv)
    if args.scenarios < 1 or args.starts < 1 or args.steps < 2 or not np.isfinite(args.weight):
        parser.error("--scenarios >= 1, --starts >= 1, --steps >= 2 and a finite --weight")

    from tqdm import tqdm

    from superex_deploy.evaluation import heldout_scenarios, read_json, write_json, write_text

    scenarios = heldout_scenarios(args.scenarios, args.starts)
    records = []
    for s in tqdm(scenarios, desc="scenarios", unit="scenario"):
        path = args.out / "choices" / f"{s.map_name}_{s.start_index}.json"
        if not path.is_file():
            write_json(path, record_scenario(s, args.steps))
        records.append(read_json(path))
        result, text = summarise(records, args.weight)
        write_json(args.out / "study.json", result, newline=True)
        write_text(args.out / "study.md", text)
        tqdm.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
