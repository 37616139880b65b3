"""Cost of the onboard ``Explorer.step`` per stage, against the ground-truth episode loop it replaced.

The new loop splits each step into what the robot runs (``Explorer.step``: integrate the measured ranges, process
the SPAD frame, frontiers, prediction, scoring, path) and what only the simulator runs (ray casting on the truth,
the SPAD simulation, driving). The old loop (commit 4253e2c) did both in one: its ``scan`` stage cast the rays
on the truth, its ``map_update`` simulated the SPAD scan. Both loops run the same episodes in one process each per
episode, alternating, so that the shared machine's load falls on both alike.

    git worktree add /tmp/superex_legacy 4253e2c
    NUMBA_NUM_THREADS=1 python scripts/bench_onboard.py --legacy-tree /tmp/superex_legacy --out benchmarks/onboard

Writes ``OUT/onboard.json`` and ``OUT/onboard.md``.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {  # name -> (planner, predictor, spad)
    "superex_pipeline": ("superex", "lama_bp", True),
    "mapex_observed": ("mapex", "observed", False),
}
SCENARIOS = (("50015847", 0), ("50052750", 0), ("50010539", 2), ("50045230", 1))


def _worker(map_name: str, start_index: int, setting: str, steps: int) -> dict:
    """One episode in this process (either package layout); per-step stage times in seconds."""
    import superex_deploy

    # Decide by the files: an editable install's import hook would otherwise fill the legacy tree's gaps from this one.
    if (Path(superex_deploy.__file__).parent / "sim").is_dir():
        from functools import partial

        from superex_deploy import pipeline
        from superex_deploy.onboard.planning.planners import make_planner
        from superex_deploy.evaluation.episodes import run_episode
        from superex_deploy.sim.exploration import ExplorationConfig

        # The unskipped pipeline (the full profile), as the legacy loop ran it.
        make_predictor = partial(pipeline.make_predictor, profile=pipeline.PROFILES["full"])
        make_sensing = partial(pipeline.make_sensing, profile=pipeline.PROFILES["full"])
    else:  # the legacy layout of commit 4253e2c
        legacy = "superex_deploy.explore"
        episode_module = __import__(f"{legacy}.episode", fromlist=["run_episode"])
        ExplorationConfig, run_episode = episode_module.ExplorationConfig, episode_module.run_episode
        make_planner = __import__(f"{legacy}.planners", fromlist=["make_planner"]).make_planner
        from superex_deploy.commands.explore import make_predictor, make_sensing
    from superex_deploy.maps import load_map, start_poses

    planner, predictor, spad = SETTINGS[setting]
    grid = load_map(map_name)
    start = start_poses(map_name)[start_index]
    # The SPAD sensing's keyword: ``sensing``, ``nlos`` in trees before the package was regrouped.
    keyword = "sensing" if "sensing" in inspect.signature(run_episode).parameters else "nlos"
    warm = run_episode(grid, start, make_planner(planner), make_predictor(predictor, grid), steps=3,
                       cfg=ExplorationConfig(iou_every=0), **{keyword: make_sensing(predictor, spad, 0)})
    del warm  # compiled kernels and loaded sessions: the measured episode starts warm
    clock = time.perf_counter()
    result = run_episode(grid, start, make_planner(planner), make_predictor(predictor, grid), steps=steps,
                         cfg=ExplorationConfig(iou_every=0), **{keyword: make_sensing(predictor, spad, 0)})
    wall = time.perf_counter() - clock
    timings = {stage: values.tolist() for stage, values in result.timings_s.items()}
    simulation = getattr(result, "simulation_s", None)
    return {"timings_s": timings, "simulation_s": None if simulation is None else simulation.tolist(),
            "goals": [list(g) for g in result.goals], "coverage": float(result.coverage[-1]), "wall_s": wall,
            "steps": result.steps}


def _run(tree: Path, map_name: str, start_index: int, setting: str, steps: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", map_name, str(start_index), setting,
               str(steps)]
    out = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tree, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _stats(values) -> dict:
    values = np.asarray(values, float) * 1e3
    return {"mean_ms": float(values.mean()), "p50_ms": float(np.percentile(values, 50)),
            "p90_ms": float(np.percentile(values, 90)), "p99_ms": float(np.percentile(values, 99)),
            "max_ms": float(values.max())}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worker", nargs=4, metavar=("MAP", "START", "SETTING", "STEPS"), help=argparse.SUPPRESS)
    parser.add_argument("--legacy-tree", type=Path, required=False, help="checkout of commit 4253e2c")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "onboard")
    args = parser.parse_args()
    if args.worker:
        map_name, start, setting, steps = args.worker
        print(json.dumps(_worker(map_name, int(start), setting, int(steps))))
        return 0
    if args.legacy_tree is None or not (args.legacy_tree / "superex_deploy" / "explore" / "episode.py").exists():
        raise SystemExit("--legacy-tree must be a checkout of commit 4253e2c (git worktree add DIR 4253e2c)")
    rows = []
    for setting in SETTINGS:
        for map_name, start in SCENARIOS:
            order = ("new", "legacy") if len(rows) % 2 == 0 else ("legacy", "new")
            runs = {}
            for which in order:
                runs[which] = _run(ROOT if which == "new" else args.legacy_tree, map_name, start, setting, args.steps)
            new, legacy = runs["new"], runs["legacy"]
            stages = list(new["timings_s"])
            explorer_step = np.sum([new["timings_s"][s] for s in stages], axis=0)
            legacy_step = np.sum([legacy["timings_s"][s] for s in stages], axis=0)
            simulation = np.asarray(new["simulation_s"])
            rows.append({"setting": setting, "map": map_name, "start": start, "steps": new["steps"],
                         "same_goals": new["goals"] == legacy["goals"],
                         "same_coverage": new["coverage"] == legacy["coverage"],
                         "explorer_step": _stats(explorer_step), "simulation": _stats(simulation),
                         "new_total": _stats(explorer_step + simulation), "legacy_step": _stats(legacy_step),
                         "explorer_stages": {s: _stats(new["timings_s"][s]) for s in stages},
                         "legacy_stages": {s: _stats(legacy["timings_s"][s]) for s in stages},
                         "wall_s": {"new": new["wall_s"], "legacy": legacy["wall_s"]}})
            print(f"{setting} {map_name} s{start}: explorer {rows[-1]['explorer_step']['mean_ms']:.1f} ms/step "
                  f"(+ simulation {rows[-1]['simulation']['mean_ms']:.1f}) vs legacy "
                  f"{rows[-1]['legacy_step']['mean_ms']:.1f}; same goals {rows[-1]['same_goals']}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "onboard.json").write_text(json.dumps({"steps": args.steps, "rows": rows}, indent=1))
    lines = ["| setting | scenario | same goals | explorer step mean / p50 / p99 ms | simulation mean ms | new total "
             "mean ms | legacy step mean / p50 / p99 ms | new / legacy (mean) |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        e, s, n, old = row["explorer_step"], row["simulation"], row["new_total"], row["legacy_step"]
        lines.append(f"| {row['setting']} | {row['map']} s{row['start']} | {row['same_goals']} | {e['mean_ms']:.1f} / "
                     f"{e['p50_ms']:.1f} / {e['p99_ms']:.1f} | {s['mean_ms']:.1f} | {n['mean_ms']:.1f} | "
                     f"{old['mean_ms']:.1f} / {old['p50_ms']:.1f} / {old['p99_ms']:.1f} | "
                     f"{n['mean_ms'] / old['mean_ms']:.2f} |")
    stage_lines = ["", "Per stage, mean ms over the scenarios' steps (explorer / legacy; legacy `scan` cast rays on the "
                   "truth, legacy `map_update` simulated the SPAD scan):", "",
                   "| setting | " + " | ".join(stages) + " |", "|---|" + "---|" * len(stages)]
    for setting in SETTINGS:
        picked = [r for r in rows if r["setting"] == setting]
        cells = [f"{np.mean([r['explorer_stages'][s]['mean_ms'] for r in picked]):.2f} / "
                 f"{np.mean([r['legacy_stages'][s]['mean_ms'] for r in picked]):.2f}" for s in stages]
        stage_lines.append(f"| {setting} | " + " | ".join(cells) + " |")
    text = "\n".join(lines + stage_lines) + "\n"
    (args.out / "onboard.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
