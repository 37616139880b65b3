"""Step time the control loop waits, synchronous vs asynchronous prediction, SuperEx pipeline (first cut of #16).

Runs the SuperEx pipeline (``superex`` planner, LaMa-BP ensemble, SPAD sensing every step) on the largest eval map
with each prediction schedule, alternating the contenders (one process per episode, numba cache warm, one warm-up
episode first), and reports per setting the explorer's step time (what the control loop waits: map update,
NLOS processing, frontiers, scoring, path, and any wait for a prediction) p50 / p90 / p99 / max / mean, the
first step, and the coverage it costs: first-half coverage AUC and coverage at the last step, against the
synchronous pipeline. The asynchronous settings give the ONNX Runtime sessions one intra-op thread (the worker
then leaves a core to the loop) and no spinning.

    NUMBA_NUM_THREADS=1 python scripts/bench_realtime.py --out benchmarks/realtime

Writes ``OUT/realtime.json`` and ``OUT/realtime.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {  # name -> (asynchronous, every_steps, apply_after_steps, ORT intra-op threads)
    "sync": (False, 0, 1, 2),
    "async_deterministic_10_10": (True, 10, 10, 1),
    "async_free": (True, 0, 1, 1),
}


def _worker(map_name: str, start_index: int, setting: str, steps: int) -> dict:
    from superex_deploy.maps import load_map, start_poses
    from superex_deploy.onboard import PredictionSchedule
    from superex_deploy.onboard.inference import LamaEnsemble, ModelKind, SessionConfig
    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.pipeline import make_sensing
    from superex_deploy.sim.episode import ExplorationConfig, run_episode

    asynchronous, every, after, threads = SETTINGS[setting]
    schedule = PredictionSchedule(asynchronous=asynchronous, every_steps=every, apply_after_steps=after)
    session = SessionConfig(intra_op_threads=threads, allow_spinning=not asynchronous)
    grid = load_map(map_name)
    start = start_poses(map_name)[start_index]

    def episode(n_steps: int):
        return run_episode(grid, start, make_planner("superex"), LamaEnsemble.from_manifest(ModelKind.LAMA_BP,
                                                                                             session=session),
                           steps=n_steps, seed=0, cfg=ExplorationConfig(iou_every=0, prediction=schedule),
                           nlos=make_sensing("lama_bp", True, 0))

    episode(3)  # compiled kernels and loaded sessions: the measured episode starts warm
    clock = time.perf_counter()
    result = episode(steps)
    wall = time.perf_counter() - clock
    step = np.sum([values for values in result.timings_s.values()], axis=0)
    half = max(1, steps // 2)
    coverage = np.concatenate([result.coverage, np.full(max(0, steps - result.steps), result.coverage[-1])])
    return {"step_s": step.tolist(), "auc_first_half": float(coverage[:half].mean()),
            "final_coverage": float(coverage[-1]), "wall_s": wall,
            "stages_mean_ms": {k: float(v.mean() * 1e3) for k, v in result.timings_s.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--map", default="50015847")
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "realtime")
    args = parser.parse_args()
    if args.worker:
        map_name, start, setting, steps = args.worker
        print(json.dumps(_worker(map_name, int(start), setting, int(steps))))
        return 0
    runs = {name: [] for name in SETTINGS}
    names = list(SETTINGS)
    for repeat in range(args.repeats):
        for name in (names if repeat % 2 == 0 else names[::-1]):
            out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", args.map,
                                  str(args.start), name, str(args.steps)], capture_output=True, text=True, check=True,
                                 cwd=ROOT)
            runs[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
            print(f"{name}: mean step {1e3 * np.mean(runs[name][-1]['step_s']):.1f} ms", flush=True)
    rows = {}
    for name, results in runs.items():
        steps = np.concatenate([r["step_s"] for r in results]) * 1e3
        rows[name] = {"p50_ms": float(np.percentile(steps, 50)), "p90_ms": float(np.percentile(steps, 90)),
                      "p99_ms": float(np.percentile(steps, 99)), "max_ms": float(steps.max()),
                      "mean_ms": float(steps.mean()), "first_step_ms": float(np.mean([r["step_s"][0] for r in results]) * 1e3),
                      "auc_first_half": float(np.mean([r["auc_first_half"] for r in results])),
                      "final_coverage": float(np.mean([r["final_coverage"] for r in results])),
                      "wall_s": float(np.mean([r["wall_s"] for r in results])),
                      "stages_mean_ms": {k: float(np.mean([r["stages_mean_ms"][k] for r in results]))
                                         for k in results[0]["stages_mean_ms"]}}
    reference = rows["sync"]
    lines = [f"{args.map} start {args.start}, {args.steps} steps, SuperEx pipeline, {args.repeats} episode(s) per "
             f"setting, alternated. Step = what the control loop waits (ms).", "",
             "| setting | p50 | p90 | p99 | max | mean | first step | first-half AUC | vs sync | coverage at end | "
             "episode wall s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, row in rows.items():
        lines.append(f"| {name} | {row['p50_ms']:.1f} | {row['p90_ms']:.1f} | {row['p99_ms']:.1f} | "
                     f"{row['max_ms']:.0f} | {row['mean_ms']:.1f} | {row['first_step_ms']:.0f} | "
                     f"{100 * row['auc_first_half']:.1f} | "
                     f"{100 * (row['auc_first_half'] / reference['auc_first_half'] - 1):+.1f} % | "
                     f"{100 * row['final_coverage']:.1f} | {row['wall_s']:.0f} |")
    text = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "realtime.json").write_text(json.dumps({"map": args.map, "start": args.start, "steps": args.steps,
                                                        "settings": {k: list(v) for k, v in SETTINGS.items()},
                                                        "rows": rows}, indent=1))
    (args.out / "realtime.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
