"""Run time against error of the SuperEx pipeline, one row per real-time setting (issue #16).

Two measurements, each against the unskipped pipeline (``full``):

* **error** (``--error eval|train``): every setting explores the 40 eval scenarios (or, to choose settings, 12
  scenarios on the held-out train floors, ``scripts/ceiling_study.scenarios``) for ``--steps`` steps with the
  deterministic prediction schedule, so the episodes do not depend on the machine; the first-half coverage AUC
  and the map IoU at 10 / 20 / 30 % coverage are paired by scenario with ``full`` (mean difference, bootstrap
  95 % interval, ratio of means). Episodes are journaled per setting (``OUT/error_SPLIT/NAME.episodes.jsonl``):
  an interrupted run resumes.
* **timing** (``--timing``): every setting explores the largest eval map (50015847, start 0) for 500 steps,
  paced at the sensor's 10 Hz (the loop sleeps until the next frame, as on the robot, so an asynchronous
  predictor has the time between frames), contenders alternated, each in a fresh worker process with the
  numba cache and the sessions warm (a 3-step episode first). Step = what the control loop waits inside
  ``Explorer.step``: p50 / p90 / p99 / max / mean, the first step, per-stage means. Then 1000-step episodes of
  ``full``, the chosen default and MapEx on the observed map, unpaced, alternated: the episode's wall time.

    NUMBA_NUM_THREADS=1 python scripts/bench_realtime.py --error train --out benchmarks/realtime   # choose
    NUMBA_NUM_THREADS=1 python scripts/bench_realtime.py --error eval --timing --out benchmarks/realtime

Writes ``OUT/realtime.json``, ``OUT/realtime.md`` and ``OUT/pareto.png`` (p99 step time against the AUC loss,
the chosen default marked) from whatever the folder holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from superex_deploy.onboard.explorer import PredictionSchedule  # noqa: E402
from superex_deploy.onboard.inference import SessionConfig  # noqa: E402
from superex_deploy.onboard.prediction_reuse import PredictionReuse  # noqa: E402
from superex_deploy.onboard.spad_processing import NlosSkips  # noqa: E402
from superex_deploy.pipeline import DEFAULT_PROFILE, PROFILES, RealtimeProfile  # noqa: E402

TIMING_MAP, TIMING_START, TIMING_STEPS, PACE_HZ = "50015847", 0, 500, 10.0
ASYNC_SESSION = SessionConfig(intra_op_threads=1, allow_spinning=False)
CROP = PredictionReuse(crop_margin_m=6.4)
ALL_NLOS_SKIPS = NlosSkips(without_unknown=True, when_still=True, filter_without_votes=True)

SETTINGS: dict[str, RealtimeProfile] = {
    "full": PROFILES["full"],
    "crop_6.4m": RealtimeProfile(reuse=CROP),
    "crop_3.2m": RealtimeProfile(reuse=PredictionReuse(crop_margin_m=3.2)),
    "crop_12.8m": RealtimeProfile(reuse=PredictionReuse(crop_margin_m=12.8)),
    "changed_200": RealtimeProfile(reuse=PredictionReuse(min_changed_cells=200)),
    "members_1": RealtimeProfile(max_members=1),
    "members_2": RealtimeProfile(max_members=2),
    "agreement_0.05": RealtimeProfile(agreement_stop=0.05),
    "nlos_skips": RealtimeProfile(nlos_skips=ALL_NLOS_SKIPS),
    "async_crop_5_3": RealtimeProfile(schedule=PredictionSchedule(True, 5, 3), reuse=CROP, session=ASYNC_SESSION),
    "async_crop_1_1": RealtimeProfile(schedule=PredictionSchedule(True, 1, 1), reuse=CROP, session=ASYNC_SESSION),
    "async_crop_2_1": RealtimeProfile(schedule=PredictionSchedule(True, 2, 1), reuse=CROP, session=ASYNC_SESSION),
    "async_crop_1_1_first": RealtimeProfile(schedule=PredictionSchedule(True, 1, 1, wait_first=True), reuse=CROP,
                                            session=ASYNC_SESSION),
    "async_crop_2_1_first": RealtimeProfile(schedule=PredictionSchedule(True, 2, 1, wait_first=True), reuse=CROP,
                                            session=ASYNC_SESSION),
    "async_crop_2_1_first_skips": RealtimeProfile(schedule=PredictionSchedule(True, 2, 1, wait_first=True),
                                                  reuse=replace(CROP, min_changed_cells=50), nlos_skips=ALL_NLOS_SKIPS,
                                                  session=ASYNC_SESSION),
    "async_crop_2_2_first": RealtimeProfile(schedule=PredictionSchedule(True, 2, 2, wait_first=True), reuse=CROP,
                                            session=ASYNC_SESSION),
    "async_crop_2_2_first_members_1": RealtimeProfile(schedule=PredictionSchedule(True, 2, 2, wait_first=True),
                                                      reuse=CROP, max_members=1, session=ASYNC_SESSION),
    "async_crop_2_2_first_agreement": RealtimeProfile(schedule=PredictionSchedule(True, 2, 2, wait_first=True),
                                                      reuse=CROP, agreement_stop=0.05, session=ASYNC_SESSION),
    "async_crop_10_10": RealtimeProfile(schedule=PredictionSchedule(True, 10, 10), reuse=CROP,
                                        session=ASYNC_SESSION),
    "async_crop_5_3_skips": RealtimeProfile(schedule=PredictionSchedule(True, 5, 3), reuse=CROP,
                                            nlos_skips=ALL_NLOS_SKIPS, agreement_stop=0.05, session=ASYNC_SESSION),
    "crop_skips": RealtimeProfile(reuse=replace(CROP, min_changed_cells=200), nlos_skips=ALL_NLOS_SKIPS,
                                  agreement_stop=0.05),
}
"""Setting name -> profile: the unskipped pipeline, then one knob at a time, then combinations. Every setting
here is deterministic (``PredictionSchedule.every_steps >= 1``): its episodes do not depend on the machine."""

CHOSEN = next((n for n, p in SETTINGS.items() if n != "full" and p == PROFILES[DEFAULT_PROFILE]), "full")
"""The setting that ``pipeline.PROFILES[DEFAULT_PROFILE]`` is (marked in the plot)."""

MAPEX = "mapex_observed"
"""Timing contender without prediction or SPAD: the MapEx planner on the observed map."""


def _names(spec: str) -> list[str]:
    names = list(SETTINGS) if spec == "all" else [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in SETTINGS]
    if unknown or "full" not in names:
        raise ValueError(f"unknown setting(s) {unknown} (choose from {', '.join(SETTINGS)}); 'full' must be one")
    return names


def _episode(task: tuple) -> dict:
    """One episode in a worker: ``(map, start index, start cell, setting, steps, mode)``; mode ``error`` (IoU
    evaluated, no timings kept), ``paced`` (10 Hz, timings kept) or ``wall`` (unpaced, wall time)."""
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.pipeline import make_predictor, make_sensing
    from superex_deploy.sim.episode import run_episode

    map_name, start_index, start, name, steps, mode = task
    grid = load_map(map_name)
    if name == MAPEX:
        planner, predictor_name, spad, profile = "mapex", "observed", False, PROFILES["full"]
    else:
        planner, predictor_name, spad, profile = "superex", "lama_bp", True, SETTINGS[name]
    iou = {"iou_every": 10, "iou_dense_until": 0.35} if mode == "error" else {"iou_every": 0}
    cfg = profile.episode_config(**iou)
    counters: dict = {}

    def episode(n_steps: int, pace_hz: float = 0.0):
        tick = [time.perf_counter()]

        def after_step(observation, command, explorer):
            counters["members"] = getattr(explorer.predictor, "members_run", None)
            if explorer.reusing is not None:
                counters.update(runs=explorer.reusing.runs, reused=explorer.reusing.reused,
                                predicted_cells=explorer.reusing.predicted_cells)
            if explorer.spad_processing is not None:
                counters["nlos"] = dict(explorer.spad_processing.counts)
            if pace_hz:
                tick[0] += 1.0 / pace_hz
                time.sleep(max(0.0, tick[0] - time.perf_counter()))

        return run_episode(grid, start, make_planner(planner), make_predictor(predictor_name, grid, profile=profile),
                           steps=n_steps, seed=0, cfg=cfg, sensing=make_sensing(predictor_name, spad, 0, profile=profile),
                           on_observation=after_step)

    if mode != "error":
        episode(3)  # compiled kernels, loaded sessions: the measured episode starts warm
    clock = time.perf_counter()
    result = episode(steps, PACE_HZ if mode == "paced" else 0.0)
    wall = time.perf_counter() - clock
    summary = result.to_json()
    summary.pop("poses")
    summary["start_index"] = start_index
    summary["setting"] = name
    summary["wall_s"] = wall
    summary["counters"] = counters
    if mode == "error":
        summary.pop("timings_s")
    else:
        summary["step_ms"] = (np.sum([np.asarray(v) for v in result.timings_s.values()], axis=0) * 1e3).tolist()
    return summary


def _error_scenarios(split: str) -> list[tuple[str, int, tuple[int, int]]]:
    from superex_deploy.maps import list_maps, start_poses

    if split == "eval":
        return [(m, k, pose) for m in list_maps("eval") for k, pose in enumerate(start_poses(m))]
    from ceiling_study import scenarios

    return [(m, 0, tuple(int(v) for v in start)) for m, start in scenarios(12, 1, 40000, heldout=True)]


def run_error(split: str, names: list[str], steps: int, jobs: int, out: Path) -> None:
    from superex_deploy.parallel import run_tasks

    folder = out / f"error_{split}"
    folder.mkdir(parents=True, exist_ok=True)
    places = _error_scenarios(split)
    for name in names:
        setting = {"steps": steps, "profile": SETTINGS[name].to_json()}
        recorded = folder / f"{name}.setting.json"
        if recorded.is_file() and json.loads(recorded.read_text()) != setting:
            raise ValueError(f"{recorded} holds a run of other settings; move it away")
        recorded.write_text(json.dumps(setting))
        tasks = [(m, k, pose, name, steps, "error") for m, k, pose in places]
        keys = [f"{m}/{k}" for m, k, _ in places]
        episodes = run_tasks(_episode, tasks, keys, jobs, folder / f"{name}.episodes.jsonl", name)
        (folder / f"{name}.json").write_text(json.dumps({"setting": setting, "episodes": episodes}))


def run_timing(names: list[str], walls: list[str], repeats: int, out: Path) -> None:
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import run_tasks

    folder = out / "timing"
    folder.mkdir(parents=True, exist_ok=True)
    start = start_poses(TIMING_MAP)[TIMING_START]
    order = [(n, r, "paced", TIMING_STEPS) for r in range(repeats) for n in (names if r % 2 == 0 else names[::-1])]
    walls = list(dict.fromkeys(["full", *walls, MAPEX]))
    order += [(n, r, "wall", 1000) for r in range(repeats) for n in (walls if r % 2 == 0 else walls[::-1])]
    for name, repeat, mode, steps in order:  # one at a time: the two cores belong to the measured episode
        key = f"{name}/{mode}/{repeat}"
        run_tasks(_episode, [(TIMING_MAP, TIMING_START, start, name, steps, mode)], [key], 1,
                  folder / "episodes.jsonl")
        print(f"timing {key} done", flush=True)


def _load_rows(folder: Path) -> dict[str, list[dict]]:
    from superex_deploy.parallel import read_journal

    rows = {}
    for journal in sorted(folder.glob("*.episodes.jsonl")):
        rows[journal.name[:-len(".episodes.jsonl")]] = list(read_journal(journal).values())
    return rows


def _timing_rows(out: Path) -> dict[str, dict]:
    from superex_deploy.parallel import read_journal

    journal = out / "timing" / "episodes.jsonl"
    if not journal.is_file():
        return {}
    by_setting: dict[tuple[str, str], list[dict]] = {}
    for key, episode in read_journal(journal).items():
        name, mode, _ = key.split("/")
        by_setting.setdefault((name, mode), []).append(episode)
    rows: dict[str, dict] = {}
    for (name, mode), episodes in by_setting.items():
        row = rows.setdefault(name, {})
        if mode == "wall":
            row["episode_wall_s"] = float(np.median([e["wall_s"] for e in episodes]))
            continue
        steps = np.concatenate([e["step_ms"] for e in episodes])
        row.update(p50_ms=float(np.percentile(steps, 50)), p90_ms=float(np.percentile(steps, 90)),
                   p99_ms=float(np.percentile(steps, 99)), max_ms=float(steps.max()), mean_ms=float(steps.mean()),
                   first_step_ms=float(np.median([e["step_ms"][0] for e in episodes])),
                   stages_mean_ms={k: float(np.mean([np.mean(e["timings_s"][k]) * 1e3 for e in episodes]))
                                   for k in episodes[0]["timings_s"]},
                   counters=episodes[-1]["counters"], repeats=len(episodes))
    return rows


def _fmt(value: float, digits: int = 1) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def report(out: Path) -> None:
    from superex_deploy.sim.suite import paired_summary, row_summary

    timing = _timing_rows(out)
    error = {}
    for split in ("eval", "train"):
        rows = _load_rows(out / f"error_{split}") if (out / f"error_{split}").is_dir() else {}
        if "full" not in rows:
            continue
        steps = json.loads((out / f"error_{split}" / "full.setting.json").read_text())["steps"]
        complete = {n: e for n, e in rows.items() if len(e) == len(rows["full"])}
        error[split] = {"summary": {n: row_summary(e, steps) for n, e in complete.items()},
                        "paired": {n: paired_summary(complete["full"], e, steps) for n, e in complete.items()
                                   if n != "full"}, "scenarios": len(rows["full"]), "steps": steps}
    lines = []
    full_t = timing.get("full", {})
    if timing:
        lines += [f"**Timing**: {TIMING_MAP} start {TIMING_START}, {TIMING_STEPS} steps paced at {PACE_HZ:.0f} Hz, "
                  "2 cores, alternated; step = what the control loop waits (ms); ratios to `full` in the same run. "
                  "Episode wall: 1000 steps unpaced.", "",
                  "| setting | p50 | p90 | p99 | max | mean | first step | p99 / full | mean / full | map update | "
                  "prediction | episode wall s |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for name, row in timing.items():
            if "p99_ms" not in row:
                continue
            lines.append(f"| {name} | {_fmt(row['p50_ms'])} | {_fmt(row['p90_ms'])} | {_fmt(row['p99_ms'])} | "
                         f"{_fmt(row['max_ms'], 0)} | {_fmt(row['mean_ms'])} | {_fmt(row['first_step_ms'])} | "
                         f"{_fmt(row['p99_ms'] / full_t.get('p99_ms', np.nan), 2)} | "
                         f"{_fmt(row['mean_ms'] / full_t.get('mean_ms', np.nan), 2)} | "
                         f"{_fmt(row['stages_mean_ms']['map_update'])} | {_fmt(row['stages_mean_ms']['prediction'])} "
                         f"| {_fmt(row.get('episode_wall_s', np.nan), 0)} |")
        walls = {n: r["episode_wall_s"] for n, r in timing.items() if "episode_wall_s" in r}
        if MAPEX in walls:
            lines += ["", "Episode wall time, 1000 steps unpaced, over MapEx on the observed map: " + ", ".join(
                f"{n} {w:.0f} s ({w / walls[MAPEX]:.1f}x)" for n, w in walls.items()), ""]
    for split, data in error.items():
        lines += ["", f"**Error** ({split}: {data['scenarios']} scenarios, {data['steps']} steps, deterministic): paired "
                  "with `full`, mean difference [bootstrap 95 %] (ratio of means - 1).", "",
                  "| setting | first-half AUC | AUC points | IoU@10% | IoU@20% | IoU@30% | better / worse / tied |",
                  "|---|---:|---|---:|---:|---:|---|"]
        full_row = data["summary"]["full"]
        lines.append(f"| full | {100 * full_row['auc_first_half']:.1f} | - | {full_row['iou@0.10']:.3f} | "
                     f"{full_row['iou@0.20']:.3f} | {full_row['iou@0.30']:.3f} | - |")
        for name, paired in data["paired"].items():
            auc = paired["auc_first_half"]
            ious = [paired.get(f"iou@{lv:.2f}", {}).get("ratio", np.nan) for lv in (0.1, 0.2, 0.3)]
            lines.append(f"| {name} | {100 * data['summary'][name]['auc_first_half']:.1f} | "
                         f"{100 * auc['mean']:+.2f} [{100 * auc['low']:+.2f}, {100 * auc['high']:+.2f}] "
                         f"({100 * auc['ratio']:+.1f} %) | " + " | ".join(f"{100 * r:+.1f} %" for r in ious)
                         + f" | {auc['better']} / {auc['worse']} / {auc['tied']} |")
    text = "\n".join(lines) + "\n"
    (out / "realtime.md").write_text(text)
    (out / "realtime.json").write_text(json.dumps({
        "timing": timing, "error": error, "default": DEFAULT_PROFILE,
        "settings": {n: p.to_json() for n, p in SETTINGS.items()}}, indent=1))
    _pareto(out, timing, error)
    print(text)


def _pareto(out: Path, timing: dict, error: dict) -> None:
    """p99 step time (timing run) against the first-half AUC loss vs ``full``: one marker per setting and split
    (train: where the settings are chosen; eval: where they are reported); the default is a star."""
    if not error or not timing:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for split, marker, colour in (("train", "o", "tab:blue"), ("eval", "s", "tab:orange")):
        if split not in error:
            continue
        shown = False
        for name, row in timing.items():
            if "p99_ms" not in row or (name != "full" and name not in error[split]["paired"]):
                continue
            loss = 0.0 if name == "full" else -100 * error[split]["paired"][name]["auc_first_half"]["ratio"]
            chosen = name == CHOSEN
            ax.scatter(row["p99_ms"], loss, s=120 if chosen else 30, marker="*" if chosen else marker,
                       color="tab:red" if chosen else colour, zorder=3,
                       label=None if shown else f"{split} ({error[split]['scenarios']} scenarios)")
            shown = True
            ax.annotate(name + (f" (default, {split})" if chosen else ""), (row["p99_ms"], loss), fontsize=6,
                        xytext=(4, 3), textcoords="offset points")
    ax.axvline(100, color="grey", lw=0.8, ls="--")
    ax.axhline(1, color="grey", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_xlabel(f"p99 step time, ms ({TIMING_MAP}, {PACE_HZ:.0f} Hz, 2 cores)")
    ax.set_ylabel("first-half AUC loss vs full, %")
    ax.set_title("SuperEx pipeline: run time against coverage (targets: p99 <= 100 ms, loss <= 1 %)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "pareto.png", dpi=120)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--error", choices=("eval", "train"), default=None)
    parser.add_argument("--timing", action="store_true")
    parser.add_argument("--settings", default="all", help="comma-separated names of SETTINGS, or 'all'")
    parser.add_argument("--timing-settings", default=None, help="settings timed (default: --settings)")
    parser.add_argument("--wall-settings", default="", help="settings whose 1000-step unpaced episode wall time is "
                        "measured besides full and MapEx (comma-separated)")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=1, help="timing episodes per setting")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "realtime")
    args = parser.parse_args()
    names = _names(args.settings)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.error:
        run_error(args.error, names, args.steps, args.jobs, args.out)
    if args.timing:
        walls = [w for w in _names("full," + args.wall_settings) if w != "full"]
        run_timing(_names(args.timing_settings) if args.timing_settings else names, walls, args.repeats, args.out)
    report(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
