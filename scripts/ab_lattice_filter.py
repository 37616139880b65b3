"""The lattice filter's effect on exploration, on held-out train floors: a named pipeline with its LaMa ensemble's
lattice filter on (as it ships, ``LamaEnsemble(lattice_filter=True)``) against the same pipeline with the members'
raw outputs (``with_lattice_filter(False)``), paired by scenario.

The filter (``superex_deploy.onboard.prediction.inference.lattice``) removes the period-8 grid the LaMa members
draw far from known space. Re-run on the 40 eval scenarios at 500 steps it left SuperEx where it was and made MapEx
on LaMa-LOS 1.1 % slower (``benchmarks/eval_headline_500/``); MapEx scores frontiers by the ensemble's variance,
which the lattice inflates or the filter removes. That was measured on eval, so nothing may be decided from it: this
script measures the same question on the held-out train floors (:func:`superex_deploy.evaluation.heldout_scenarios`,
the buildings the models never trained on; never ``eval/``).

The measure is the first-half AUC of coverage counting carved cells; each episode runs ``steps // 2`` steps, all
that measure reads (an episode does not depend on its budget). One JSON per episode in ``OUT/episodes/ARM/`` (a
rerun skips those there); ``OUT/lattice.md`` and ``OUT/lattice.json`` from the pairs finished so far. ``--arm`` runs
one arm (two processes on one ``--out``).

    NUMBA_NUM_THREADS=1 PYTHONPATH=. SUPEREX_MODELS=exported .venv/bin/python scripts/ab_lattice_filter.py \\
        --pipeline mapex_lama_los --scenarios 17 --steps 500 --out benchmarks/lattice/train_mapex_lama_los
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ARMS = ("filter", "raw")
"""The filter as it ships, and the members' raw outputs."""


def _episode_path(out: Path, arm: str, scenario) -> Path:
    return out / "episodes" / arm / f"{scenario.map_name}_{scenario.start_index}.json"


def run_arm(scenario, arm: str, pipeline_name: str, steps: int, seed: int = 0) -> dict:
    """One episode of the named pipeline on ``scenario`` with the filter on (``filter``) or off (``raw``); its
    JSON summary (no poses, no per-step times) with ``arm``, ``start_index``, ``seconds``, ``pipeline``."""
    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import PIPELINES, PROFILES, make_predictor, make_sensing

    if arm not in ARMS:
        raise ValueError(f"arm must be one of {ARMS}, got {arm!r}")
    pipeline = PIPELINES[pipeline_name]
    profile = PROFILES[pipeline.profile]
    predictor = make_predictor(pipeline.predictor, profile=profile)
    if not hasattr(predictor, "with_lattice_filter"):
        raise ValueError(f"pipeline {pipeline_name}'s predictor {pipeline.predictor} is no LaMa ensemble")
    predictor = predictor.with_lattice_filter(arm == "filter")
    sensing = make_sensing(pipeline.predictor, pipeline.spad, seed, profile=profile)
    clock = time.perf_counter()
    run = run_benchmark_episode(load_map(scenario.map_name), scenario.start_rc, make_planner(pipeline.planner),
                                predictor, steps=steps, seed=seed, cfg=profile.episode_config(iou_every=0),
                                profile=profile, sensing=sensing)
    summary = run.result.to_json()
    for key in ("poses", "timings_s", "evaluation_s", "simulation_s"):
        summary.pop(key)
    summary.update(start_index=scenario.start_index, arm=arm, pipeline=pipeline_name,
                   seconds=time.perf_counter() - clock)
    return summary


def summarise(out: Path, scenarios, steps: int, pipeline_name: str) -> Optional[tuple[dict, str]]:
    """``(lattice.json's dict, lattice.md's text)`` of the pairs finished in ``OUT/episodes``; None if none.

    Raises:
        ValueError: an episode of another pipeline, or with fewer steps than the measure reads.
    """
    from superex_deploy.evaluation import markdown_table, read_json
    from superex_deploy.evaluation.metrics import scenario_metrics
    from superex_deploy.evaluation.summary import paired_summary

    pairs = [(s, [read_json(_episode_path(out, arm, s)) for arm in ARMS]) for s in scenarios
             if all(_episode_path(out, arm, s).is_file() for arm in ARMS)]
    if not pairs:
        return None
    rows, per = [], []
    for s, episodes in pairs:
        for e in episodes:
            if e["pipeline"] != pipeline_name:
                raise ValueError(f"{s.map_name} #{s.start_index} {e['arm']} ran {e['pipeline']}, not {pipeline_name}")
            if len(e["coverage_with_carving"]) < steps // 2 and not e["finished"]:
                raise ValueError(f"{s.map_name} #{s.start_index} {e['arm']}: {len(e['coverage_with_carving'])} "
                                 f"steps run, the first half of {steps} reads {steps // 2}")
        a, b = (scenario_metrics(e, steps)["auc_first_half"] for e in episodes)
        per.append({"map": s.map_name, "start_index": s.start_index, "auc_filter": a, "auc_raw": b,
                    "difference": a - b})
        rows.append([f"{s.map_name} #{s.start_index}", f"{100 * a:.2f}", f"{100 * b:.2f}", f"{100 * (a - b):+.2f}"])
    paired = paired_summary([e for _, (_, e) in pairs], [e for _, (e, _) in pairs], steps)["auc_first_half"]
    result = {"pipeline": pipeline_name, "steps": steps, "steps_run": steps // 2, "seed": 0,
              "scenarios_planned": len(scenarios), "scenarios_finished": len(pairs),
              "auc_first_half": {"filter": float(np.mean([p["auc_filter"] for p in per])),
                                 "raw": float(np.mean([p["auc_raw"] for p in per])),
                                 "difference": paired["mean"], "interval": [paired["low"], paired["high"]],
                                 "relative": paired["ratio"], "better": paired["better"], "worse": paired["worse"],
                                 "tied": paired["tied"]},
              "per_scenario": per}
    status = "" if len(pairs) == len(scenarios) else f" **Partial: {len(pairs)} of {len(scenarios)} scenarios.**"
    lines = [f"`{pipeline_name}` with the lattice filter (as it ships) and without it, held-out train floors, the first "
             f"{steps // 2} steps of a {steps}-step budget, seed 0, paired by scenario; first-half AUC counting carved "
             f"cells (percent).{status}", ""]
    lines += markdown_table(["scenario", "AUC filter", "AUC raw", "filter - raw"], rows, ["-", "---:", "---:", "---:"])
    d = result["auc_first_half"]
    lines += ["", f"Paired mean difference (filter - raw): **{100 * d['difference']:+.2f} points** "
                  f"[{100 * d['interval'][0]:+.2f}, {100 * d['interval'][1]:+.2f}] (bootstrap 95 %), "
                  f"**{100 * d['relative']:+.1f} %** relative (AUC {100 * d['raw']:.2f} -> {100 * d['filter']:.2f}); "
                  f"better / worse / tied: {d['better']} / {d['worse']} / {d['tied']} of {len(pairs)}."]
    return result, "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pipeline", default="mapex_lama_los", help="a named pipeline with a LaMa ensemble")
    parser.add_argument("--scenarios", type=int, default=17, help="held-out train floors")
    parser.add_argument("--starts", type=int, default=1, help="seeded starts per floor (the k-th: start index k)")
    parser.add_argument("--steps", type=int, default=500, help="step budget (the episodes run its first half)")
    parser.add_argument("--arm", choices=("both",) + ARMS, default="both")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "lattice" / "train_mapex_lama_los")
    parser.add_argument("--report", action="store_true", help="only write the report from the episodes there")
    args = parser.parse_args(argv)
    if args.scenarios < 1 or args.starts < 1 or args.steps < 2:
        parser.error("--scenarios >= 1, --starts >= 1 and --steps >= 2")

    from tqdm import tqdm

    from superex_deploy.evaluation import heldout_scenarios, write_json, write_text
    from superex_deploy.pipeline import PIPELINES

    if args.pipeline not in PIPELINES:
        parser.error(f"--pipeline must be one of {', '.join(PIPELINES)}")
    scenarios = heldout_scenarios(args.scenarios, args.starts)
    arms = ARMS if args.arm == "both" else (args.arm,)

    def report() -> None:
        summary = summarise(args.out, scenarios, args.steps, args.pipeline)
        if summary is not None:
            write_json(args.out / "lattice.json", summary[0], newline=True)
            write_text(args.out / "lattice.md", summary[1])
            tqdm.write(summary[1])

    if not args.report:
        todo = [(s, arm) for s in scenarios for arm in arms if not _episode_path(args.out, arm, s).is_file()]
        for s, arm in tqdm(todo, desc="episodes", unit="episode"):
            write_json(_episode_path(args.out, arm, s), run_arm(s, arm, args.pipeline, args.steps // 2))
            report()
    report()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
