"""``superex benchmark``: every start pose of a set of maps x planners, in parallel processes.

``--suite paper`` runs the paper's table instead: the named rows of :data:`~superex_deploy.sim.suite.PAPER_ROWS`
(planner x predictor x sensing) on the 40 eval scenarios, each row written to ``OUT/rows/ROW.json`` as soon as it
is done (a rerun skips the rows already there), then the summary paired by scenario against MapEx on LaMa-LOS:
``results.md``, ``results.json``, ``coverage.png``, ``iou_vs_coverage.png``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from superex_deploy.commands.explore import add_planner_option, planner_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--maps", default="eval", help="'eval', or comma-separated bundled eval map names")
    parser.add_argument("--planners", default="nearest,hector,upen,mapex")
    add_planner_option(parser)
    parser.add_argument("--predictor", default="observed", choices=("observed", "oracle", "lama_los", "lama_bp"),
                        help="lama_los: the line-of-sight LaMa ensemble in exported/ (MapEx's predictor); "
                             "lama_bp: the ensemble that also reads the Pix2Pix-filtered back-projection (needs "
                             "--spad)")
    parser.add_argument("--spad", action="store_true",
                        help="simulate the SPAD LiDAR every step: NLOS carving and back-projection evidence")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 1)))
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--suite", choices=("paper",), default=None,
                        help="paper: the paper's rows (see --rows), IoU every 10 steps up to 35 %% coverage, "
                             "paired against MapEx on LaMa-LOS; --planners / --predictor / --spad are ignored")
    parser.add_argument("--rows", default="all",
                        help="with --suite paper: comma-separated row names, or 'all'")


def run_scenario(task: tuple) -> dict:
    """One benchmark episode in a worker process; returns its JSON summary (no poses, no per-step timings).

    ``task``: ``(map, start index, start cell, planner, planner options, predictor, spad, steps, seed[, episode
    config overrides])``; the overrides default to an IoU evaluation every 50 steps."""
    from superex_deploy.pipeline import make_predictor, make_sensing
    from superex_deploy.sim.episode import ExplorationConfig, run_episode
    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.maps import load_map

    map_name, start_index, start, planner_name, options, predictor_name, spad, steps, seed = task[:9]
    iou_cfg = task[9] if len(task) > 9 else {"iou_every": 50}
    grid = load_map(map_name)
    result = run_episode(grid, start, make_planner(planner_name, **options), make_predictor(predictor_name, grid),
                         steps=steps,
                         seed=seed, cfg=ExplorationConfig(**iou_cfg),
                         nlos=make_sensing(predictor_name, spad, seed))
    summary = result.to_json()
    summary["start_index"] = start_index
    summary.pop("poses")
    summary.pop("timings_s")
    return summary


def run(args: argparse.Namespace) -> int:
    if args.suite == "paper":
        from superex_deploy.commands.paper_benchmark import run_paper

        return run_paper(args)
    from tqdm import tqdm

    from superex_deploy.sim.metrics import results_markdown, summarise
    from superex_deploy.onboard.planners import PLANNERS, make_planner
    from superex_deploy.maps import list_maps, start_poses
    from superex_deploy.parallel import process_pool
    from superex_deploy.render import save_benchmark_plots

    names = list_maps("eval") if args.maps == "eval" else [m.strip() for m in args.maps.split(",") if m.strip()]
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    unknown = [p for p in planners if p not in PLANNERS]
    if unknown:
        raise ValueError(f"unknown planner(s) {unknown}; choose from {', '.join(sorted(PLANNERS))}")
    if args.jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
    if args.predictor == "lama_bp" and not args.spad:
        raise ValueError("--predictor lama_bp reads the SPAD evidence: add --spad")
    options = planner_options(args.planner_option)
    for planner in planners:  # a bad option fails here, not in a worker
        make_planner(planner, **options)
    tasks = [(name, k, pose, planner, options, args.predictor, args.spad, args.steps, args.seed)
             for name in names for k, pose in enumerate(start_poses(name)) for planner in planners]
    args.out.mkdir(parents=True, exist_ok=True)
    with process_pool(args.jobs) as pool:
        results = list(tqdm(pool.map(run_scenario, tasks), total=len(tasks), desc="episodes", unit="episode"))
    checkpoints = tuple(s for s in (100, 250, 500, 1000) if s <= args.steps) or (args.steps,)
    table = summarise(results, checkpoints)
    (args.out / "results.json").write_text(json.dumps({"episodes": results, "summary": table,
                                                       "planner_options": options}))
    table_text = results_markdown(table)
    settings = "".join(f", {k}={v}" for k, v in options.items())
    (args.out / "results.md").write_text(
        f"Predictor: {args.predictor}{', SPAD sensing' if args.spad else ''}{settings}; {len(names)} maps, "
        f"{len(tasks) // max(len(planners), 1)} scenarios, {args.steps} steps, seed {args.seed}. Mean ± standard "
        f"deviation over scenarios; coverage in percent of the valid area (carved: counting NLOS-carved cells), "
        f"coverage_auc: mean coverage over the steps.\n\n"
        f"{table_text}")
    save_benchmark_plots(args.out, results)
    print(table_text)
    print(f"wrote {args.out / 'results.md'}, results.json, coverage.png, iou_vs_coverage.png")
    return 0
