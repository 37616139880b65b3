"""The same floors at a SLAM resolution: each eval floor at 0.1 m and upsampled x2 to 0.05 m (every cell a 2 x 2
block, so the building is the same), the SuperEx pipeline (``superex`` planner, LaMa-BP, SPAD) on both.

* ``--error``: paired episodes (the simulated clock, reproducible), ``--steps`` each: first-half coverage AUC,
  path length, wall IoU of the prediction at 10 / 20 / 30 % coverage; 0.05 m over 0.1 m per scenario, paired
  bootstrap intervals of the differences.
* ``--timing``: the default profile on the robot clock, paced at the sensor's 10 Hz, on one floor at both
  resolutions, alternated: step-time p50 / p99 / mean / max (the committed timing rows come from
  ``scripts/bench_realtime.py --timing-floors``, beside the other real-time rows).
* ``--interpolation N``: what the IoU metric loses at 0.05 m by itself, the same 0.1 m predictions scored on both
  grids (N held-out train floors).

Results go to ``--out`` (``resolution.json`` / ``resolution.md``; episodes journaled in ``error.jsonl`` and
``timing.jsonl``, so a killed run resumes). Times are this machine's.

    python scripts/bench_resolution.py --error --scenarios 40 --steps 500 --interpolation 8 --out benchmarks/resolution
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import (bootstrap_interval, eval_scenarios, first_half_auc, iou_at_coverage,
                                       markdown_table, run_benchmark_episode, write_json, write_text)
from superex_deploy.maps import load_map
from superex_deploy.pipeline import DEFAULT_PROFILE, PIPELINES, PROFILES
from superex_deploy.sim.generated_floors import upsampled

PACE_HZ = 10.0
TIMING_MAP, TIMING_START = "50015847", 0
LEVELS = (0.1, 0.2, 0.3)
PIPELINE = PIPELINES["superex"]
"""The pipeline every episode runs (its planner, predictor and SPAD sensing; the profile as each mode says)."""


def _episode(map_name: str, start, factor: int, steps: int, mode: str) -> dict:
    from superex_deploy.onboard.prediction.inference import available_cores

    grid = load_map(map_name)
    if factor > 1:
        grid = upsampled(grid, factor)
        start = (start[0] * factor + factor // 2, start[1] * factor + factor // 2)
    profile = PROFILES[DEFAULT_PROFILE]
    robot = mode == "timing"
    cfg = profile.episode_config(clock="robot" if robot else "simulated",
                                 **({"iou_every": 0} if robot else {"iou_every": 10, "iou_dense_until": 0.35}))
    tick = [0.0]

    def paced(observation, command, explorer):
        tick[0] += 1.0 / PACE_HZ
        time.sleep(max(0.0, tick[0] - time.perf_counter()))

    def run(n):
        tick[0] = time.perf_counter()
        return run_benchmark_episode(grid, start, PIPELINE.planner, PIPELINE.predictor, steps=n, seed=0, cfg=cfg,
                                     profile=profile, spad=PIPELINE.spad, cores=available_cores() if robot else None,
                                     on_observation=paced if robot else None)

    if robot:
        run(3)
    episode = run(steps)
    summary = episode.result.to_json()
    out = {"map": map_name, "factor": factor, "resolution_m": grid.resolution_m, "steps": steps, "mode": mode,
           "coverage": summary["coverage"], "coverage_with_carving": summary["coverage_with_carving"],
           "path_m": float(summary["path_length_m"][-1]) if summary["path_length_m"] else 0.0, "iou": summary.get("iou", {}),
           "wall_s": episode.seconds}
    if robot:
        out["step_ms"] = (np.sum([np.asarray(v) for v in episode.result.timings_s.values()], axis=0) * 1e3).tolist()
    return out


def _interpolation(task: tuple) -> dict:
    """What the metric loses at 0.05 m by itself: the ``full`` pipeline's 0.1 m predictions after ``steps`` steps
    on a held-out train floor, scored at 0.1 m, and on the floor upsampled x2 as the explorer would hand them out
    there (bilinear, :func:`~superex_deploy.onboard.prediction.scale.upsample_linear`) and with each cell repeated."""
    from superex_deploy.onboard.prediction.scale import upsample_linear
    from superex_deploy.evaluation.metrics import map_iou

    map_name, start, steps = task
    grid, grabbed = load_map(map_name), {}

    def grab(observation, command, explorer):
        if explorer.steps in steps:
            grabbed[explorer.steps] = explorer.predict().mean.copy()

    profile = PROFILES["full"]
    run_benchmark_episode(grid, tuple(start), PIPELINE.planner, PIPELINE.predictor, steps=max(steps) + 1, seed=0,
                          profile=profile, cfg=profile.episode_config(clock="simulated", iou_every=0),
                          spad=PIPELINE.spad, on_observation=grab)
    fine = upsampled(grid, 2)
    return {"mode": "interpolation", "map": map_name, "iou": {
        str(step): {"0.1m": map_iou(mean, grid), "bilinear": map_iou(upsample_linear(mean, 2, fine.shape), fine),
                    "repeated": map_iou(np.kron(mean, np.ones((2, 2), np.float32)), fine)}
        for step, mean in grabbed.items()}}


def _task(task: tuple) -> dict:
    if task[0] == "interpolation":
        return _interpolation(task[1:])
    mode, map_name, start_index, start, factor, steps = task
    episode = _episode(map_name, tuple(start), factor, steps, mode)
    episode["start_index"] = start_index
    return episode


def main() -> int:
    from superex_deploy.parallel import read_journal, run_tasks

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--error", action="store_true")
    parser.add_argument("--timing", action="store_true")
    parser.add_argument("--scenarios", type=int, default=40, help="the first N of the 40 eval scenarios")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--timing-steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=1, help="timing episodes per resolution")
    parser.add_argument("--interpolation", type=int, default=0, metavar="N",
                        help="the metric's own loss at 0.05 m on N held-out train floors (predictions at steps 40, 80)")
    parser.add_argument("--jobs", type=int, default=2, help="error episodes at a time (timing runs alone)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.error:
        tasks = [("error", s.map_name, s.start_index, list(s.start_rc), factor, args.steps)
                 for s in eval_scenarios()[:args.scenarios] for factor in (1, 2)]
        run_tasks(_task, tasks, [f"error {t[1]} {t[2]} x{t[4]} {t[5]}" for t in tasks], args.jobs,
                  args.out / "error.jsonl", progress="error episodes")
    if args.timing:
        from superex_deploy.maps import start_poses

        start = list(start_poses(TIMING_MAP)[TIMING_START])
        tasks = [("timing", TIMING_MAP, repeat, start, factor, args.timing_steps) for repeat in range(args.repeats)
                 for factor in ((1, 2) if repeat % 2 == 0 else (2, 1))]
        run_tasks(_task, tasks, [f"timing {t[2]} x{t[4]} {t[5]}" for t in tasks], 1, args.out / "timing.jsonl",
                  progress="timing episodes")
    if args.interpolation:
        from superex_deploy.evaluation import heldout_scenarios

        tasks = [("interpolation", s.map_name, list(s.start_rc), [40, 80]) for s in heldout_scenarios(args.interpolation)]
        run_tasks(_task, tasks, [f"interpolation {t[1]}" for t in tasks], args.jobs, args.out / "interpolation.jsonl",
                  progress="interpolation episodes")
    episodes = []
    for name in ("error.jsonl", "timing.jsonl", "interpolation.jsonl"):
        if (args.out / name).exists():
            episodes += list(read_journal(args.out / name).values())
    report(args.out, episodes)
    return 0


def report(out: Path, episodes: list[dict]) -> None:
    rows, result = [], {"machine": "this project's 2-core sandbox (no GPU)", "profile": DEFAULT_PROFILE}
    error = [e for e in episodes if e["mode"] == "error"]
    pairs = {}
    for e in error:
        pairs.setdefault((e["map"], e["start_index"]), {})[e["factor"]] = e
    pairs = {k: v for k, v in pairs.items() if 1 in v and 2 in v}
    if pairs:
        measures = {"first-half AUC (%)": lambda e: 100 * first_half_auc(e["coverage_with_carving"], e["steps"]),
                    "path (m)": lambda e: e["path_m"]}
        measures.update({f"IoU @{int(100 * level)} %": (lambda level: lambda e: iou_at_coverage(e, level))(level)
                         for level in LEVELS})
        for name, measure in measures.items():
            coarse = np.array([measure(p[1]) for p in pairs.values()], float)
            fine = np.array([measure(p[2]) for p in pairs.values()], float)
            ok = np.isfinite(coarse) & np.isfinite(fine)
            ratio = fine[ok] / coarse[ok]
            low, high = bootstrap_interval(fine[ok] - coarse[ok])
            rows.append([name, int(ok.sum()), f"{coarse[ok].mean():.3f}", f"{fine[ok].mean():.3f}",
                         f"{100 * (fine[ok].mean() / coarse[ok].mean() - 1):+.1f} %",
                         f"{np.mean(fine[ok] - coarse[ok]):+.3f} [{low:+.3f}, {high:+.3f}]",
                         f"{np.median(ratio):.3f}"])
            result[name] = {"scenarios": int(ok.sum()), "mean_0.1m": float(coarse[ok].mean()),
                            "mean_0.05m": float(fine[ok].mean()), "difference": float(np.mean(fine[ok] - coarse[ok])),
                            "interval": [low, high]}
    lines = []
    if rows:
        lines += [f"**Error** ({len(pairs)} eval scenarios, {error[0]['steps']} steps, the `{DEFAULT_PROFILE}` "
                  "profile on the simulated clock; 0.05 m = the floor upsampled x2):", "",
                  *markdown_table(["measure", "scenarios", "0.1 m", "0.05 m", "0.05 / 0.1 (means)",
                                   "paired difference [95 %]", "median ratio"], rows), ""]
    timing = [e for e in episodes if e["mode"] == "timing"]
    if timing:
        trows = []
        for factor in (1, 2):
            steps = np.concatenate([np.asarray(e["step_ms"][1:]) for e in timing if e["factor"] == factor] or
                                   [np.zeros(0)])
            if steps.size:
                trows.append([f"{0.1 / factor:g} m", f"{np.percentile(steps, 50):.1f}",
                              f"{np.percentile(steps, 99):.1f}", f"{steps.mean():.1f}", f"{steps.max():.0f}"])
                result[f"timing_{0.1 / factor:g}m"] = {"p50": float(np.percentile(steps, 50)),
                                                      "p99": float(np.percentile(steps, 99)),
                                                      "mean": float(steps.mean()), "max": float(steps.max())}
        lines += [f"**Timing** ({TIMING_MAP} start {TIMING_START}, {timing[0]['steps']} steps paced at 10 Hz, the "
                  f"`{DEFAULT_PROFILE}` profile on the robot clock, alternated; step ms after the first; targets "
                  "p99 <= 100, mean <= 25):", "",
                  *markdown_table(["grid", "p50", "p99", "mean", "max"], trows), ""]
    scored = [v for e in episodes if e["mode"] == "interpolation" for v in e["iou"].values()]
    if scored:
        means = {k: float(np.mean([v[k] for v in scored])) for k in ("0.1m", "bilinear", "repeated")}
        result["interpolation"] = {"predictions": len(scored), **means}
        lines += [f"**The metric at 0.05 m by itself** ({len(scored)} predictions of the `full` pipeline at 0.1 m, "
                  "steps 40 and 80 on held-out train floors, wall IoU on the floor and on its x2 copy): the same "
                  "prediction loses IoU at 0.05 m from its evaluation area's cells and from the interpolation.", "",
                  *markdown_table(["scored as", "wall IoU", "vs 0.1 m"],
                                  [["0.1 m", f"{means['0.1m']:.4f}", "-"]] +
                                  [[f"0.05 m, {k}", f"{means[k]:.4f}", f"{100 * (means[k] / means['0.1m'] - 1):+.1f} %"]
                                   for k in ("repeated", "bilinear")]), ""]
    write_json(out / "resolution.json", result)
    write_text(out / "resolution.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    raise SystemExit(main())
