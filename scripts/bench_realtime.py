"""Run time against error of the SuperEx pipeline, one row per real-time setting.

Two measurements, each against the unskipped pipeline (``full``):

* **error** (``--error eval|train``): every setting explores the 40 eval scenarios (or, to choose settings, 12
  scenarios on the held-out train floors, :func:`superex_deploy.evaluation.heldout_scenarios`) for ``--steps``
  steps with the deterministic prediction schedule, so the episodes do not depend on the machine; the first-half
  coverage AUC and the map IoU at 10 / 20 / 30 % coverage are paired by scenario with ``full`` (mean difference,
  bootstrap 95 % interval, ratio of means). Episodes are journaled per setting (``OUT/error_SPLIT/NAME.episodes.jsonl``):
  an interrupted run resumes.
  The default's free-running mode is measured against its simulated clock: ``--free-repeats`` repeats of its
  error episodes on the robot clock (``realtime@freeR``: predictions land when this machine finishes them),
  paired by scenario with the simulated-clock episodes, and the spread of their means over the repeats.
* **timing** (``--timing``): every setting explores the largest eval map (50015847, start 0) for 500 steps,
  paced at the sensor's 10 Hz (the loop sleeps until the next frame, as on the robot, so an asynchronous
  predictor has the time between frames), on its robot clock (the default never waits), contenders alternated,
  each in a fresh worker process with the numba cache and the sessions warm (a 3-step episode first). Step =
  what the control loop waits inside ``Explorer.step``: p50 / p90 / p99 / max / mean, the first step, per-stage
  means, and the prediction wait after the first step (p99, max). Then the same paced run of ``full`` and the
  default (``--loaded-settings``) while a busy-loop process pinned to one core holds it (a robot's SLAM), and
  1000-step episodes of ``full``, the default and MapEx on the observed map, unpaced, alternated: the episode's
  wall time. ``--timing-floors``: the default profile paced on other floors too (rows ``realtime@FLOOR``, beside
  ``realtime@50015847`` at 0.1 m: ``MAP@xK`` upsampled K times, ``generated@RES`` a generated 96 m x 64 m floor,
  :func:`superex_deploy.sim.generated_floors.named_floor`).

    NUMBA_NUM_THREADS=1 python scripts/bench_realtime.py --error train --out benchmarks/realtime   # choose
    NUMBA_NUM_THREADS=1 python scripts/bench_realtime.py --error eval --timing --out benchmarks/realtime
    python scripts/bench_realtime.py --timing --settings full --only-floors --repeats 2 --timing-steps 300 \
        --timing-floors 50015847@x2,generated,generated@0.05 --out benchmarks/realtime/fine   # SLAM resolutions

A quick check (one scenario, a few steps; minutes):

    python scripts/bench_realtime.py --error eval --scenarios 1 --steps 6 --settings full,realtime \
        --free-repeats 2 --jobs 1 --timing --timing-steps 5 --wall-steps 5 --out /tmp/bench_realtime_check

Writes ``OUT/realtime.json``, ``OUT/realtime.md`` and ``OUT/pareto.png`` (p99 step time against the AUC loss,
the chosen default marked) from whatever the folder holds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import markdown_table

ROOT = Path(__file__).resolve().parents[1]

from superex_deploy.onboard.prediction.reuse import PredictionReuse  # noqa: E402
from superex_deploy.pipeline import DEFAULT_PROFILE, PIPELINES, PROFILES, RealtimeProfile  # noqa: E402

TIMING_MAP, TIMING_START, TIMING_STEPS, PACE_HZ = "50015847", 0, 500, 10.0
CROP = PredictionReuse(crop_margin_m=6.4)

SETTINGS: dict[str, RealtimeProfile] = {
    "full": PROFILES["full"],
    "crop_6.4m": RealtimeProfile(reuse=CROP),
    "crop_3.2m": RealtimeProfile(reuse=PredictionReuse(crop_margin_m=3.2)),
    "crop_12.8m": RealtimeProfile(reuse=PredictionReuse(crop_margin_m=12.8)),
    "changed_200": RealtimeProfile(reuse=PredictionReuse(min_changed_m2=2.0)),
    "members_1": RealtimeProfile(max_members=1),
    "members_2": RealtimeProfile(max_members=2),
    DEFAULT_PROFILE: PROFILES[DEFAULT_PROFILE],
    "realtime_no_lattice_filter": PROFILES[DEFAULT_PROFILE],
}
"""Setting name -> profile: the unskipped pipeline, then one knob at a time, then the default profile. The error
runs use each profile's simulated clock (``RealtimeProfile.episode_config``) and the timing runs its robot clock,
so every error episode is independent of the machine except the free-running repeats (``SETTING@freeR``).
The settings of retired options (``agreement_0.05``, ``nlos_skips``, ``crop_skips`` and the ``async_*`` settings of
the threaded deterministic schedule) keep their committed rows in ``benchmarks/realtime/``; this script at commit
1761b27 ran them (see that folder's README)."""

RAW_LATTICE = frozenset({"realtime_no_lattice_filter"})
"""Settings whose LaMa ensemble runs without the lattice filter (``with_lattice_filter(False)``): the default profile
timed against itself with the filter off, to split the filter's cost from the machine's."""

CHOSEN = DEFAULT_PROFILE
"""The setting that ``pipeline.PROFILES[DEFAULT_PROFILE]`` is (marked in the plot): on the robot it never waits
(``free``), in error runs it predicts on the simulated clock (the committed ``async_crop_2_2_first_members_1``
episodes, but for the SPAD evidence on every 2nd frame)."""

FREE = "@free"
"""``NAME@freeR``: repeat R of setting NAME's error episodes on its robot clock (free-running: where the
predictions land depends on the machine and its load), paired with NAME's simulated-clock episodes."""

MAPEX = "mapex_observed"
"""Timing contender without prediction or SPAD: the MapEx planner on the observed map."""


def _setting(name: str) -> tuple[str, bool]:
    """(setting name, whether the episode runs on the robot clock) of a run name (``NAME`` or ``NAME@freeR``)."""
    base, free, _ = name.partition(FREE)
    return base, bool(free)


def _names(spec: str) -> list[str]:
    names = list(SETTINGS) if spec == "all" else [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in SETTINGS]
    if unknown or "full" not in names:
        raise ValueError(f"unknown setting(s) {unknown} (choose from {', '.join(SETTINGS)}); 'full' must be one")
    return names


def _episode(task: tuple) -> dict:
    """One episode in a worker: ``(map, start index, start cell, setting, steps, mode)``; mode ``error`` (IoU
    evaluated, no timings kept; the simulated clock, the robot's for ``NAME@freeR``), ``paced`` (10 Hz, timings
    kept, the robot clock), ``loaded`` (``paced``, while another process holds a core: started by the caller) or
    ``wall`` (unpaced, wall time, the robot clock)."""
    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.prediction.inference import available_cores
    from superex_deploy.sim.generated_floors import named_floor

    map_name, start_index, start, name, steps, mode = task
    if start is None:  # a timing floor by name (--timing-floors): its grid and start
        grid, start = named_floor(map_name)
    else:
        grid = load_map(map_name)
    setting, free = _setting(name)
    if setting == MAPEX:
        planner, predictor_name, spad, profile = "mapex", "observed", False, PROFILES["full"]
    else:
        pipeline = PIPELINES["superex"]
        planner, predictor_name, spad, profile = pipeline.planner, pipeline.predictor, pipeline.spad, SETTINGS[setting]
    iou = {"iou_every": 10, "iou_dense_until": 0.35} if mode == "error" else {"iou_every": 0}
    robot = mode != "error" or free
    cfg = profile.episode_config(clock="robot" if robot else "simulated", **iou)
    cores = available_cores() if robot else None  # the robot's thread budget; the benchmarks' fixed sessions
    counters: dict = {}
    waits: list[float] = []

    def episode(n_steps: int, pace_hz: float = 0.0):
        tick = [time.perf_counter()]

        def after_step(observation, command, explorer):
            # What the control loop waited for the predictor: blocked on the worker or computing inline.
            waits.append(command.timings_s["prediction"] if explorer.scheduled is None
                         else explorer.scheduled.last_wait_s)
            counters["members"] = getattr(explorer.predictor, "members_run", None)
            if explorer.reusing is not None:
                counters.update(runs=explorer.reusing.runs, reused=explorer.reusing.reused,
                                predicted_cells=explorer.reusing.predicted_cells)
            if explorer.spad_processing is not None:
                counters["nlos"] = dict(explorer.spad_processing.counts)
            if pace_hz:
                tick[0] += 1.0 / pace_hz
                time.sleep(max(0.0, tick[0] - time.perf_counter()))

        waits.clear()
        predictor, sensing = predictor_name, None
        if setting in RAW_LATTICE:  # a fresh predictor and sensing per episode, as a name gives
            from superex_deploy.pipeline import make_predictor, make_sensing

            predictor = make_predictor(predictor_name, profile=profile, cores=cores).with_lattice_filter(False)
            sensing = make_sensing(predictor_name, spad, 0, profile=profile)
        return run_benchmark_episode(grid, start, planner, predictor, steps=n_steps, seed=0, cfg=cfg,
                                     profile=profile, spad=spad, sensing=sensing, cores=cores,
                                     on_observation=after_step).result

    if mode != "error":
        episode(3)  # compiled kernels, loaded sessions: the measured episode starts warm
    clock = time.perf_counter()
    result = episode(steps, PACE_HZ if mode in ("paced", "loaded") else 0.0)
    wall = time.perf_counter() - clock
    summary = result.to_json()
    summary.pop("poses")
    summary["start_index"] = start_index
    summary["setting"] = name
    summary["clock"] = "robot" if robot else "simulated"
    summary["wall_s"] = wall
    summary["counters"] = counters
    if mode == "error":
        summary.pop("timings_s")
    else:
        summary["step_ms"] = (np.sum([np.asarray(v) for v in result.timings_s.values()], axis=0) * 1e3).tolist()
        summary["wait_ms"] = (np.asarray(waits) * 1e3).tolist()
    return summary


def _error_scenarios(split: str) -> list[tuple[str, int, tuple[int, int]]]:
    from superex_deploy.evaluation import eval_scenarios, heldout_scenarios

    return eval_scenarios("map") if split == "eval" else heldout_scenarios(12)


def run_error(split: str, names: list[str], steps: int, jobs: int, out: Path, free_repeats: int = 0,
              scenarios: int = 0) -> None:
    """Error episodes of ``names`` (simulated clock), then ``free_repeats`` free-running repeats of the default
    (``CHOSEN@freeR``, robot clock); ``scenarios`` > 0: only the first that many scenarios (a quick check)."""
    from superex_deploy.parallel import run_tasks

    folder = out / f"error_{split}"
    folder.mkdir(parents=True, exist_ok=True)
    places = _error_scenarios(split)[:scenarios or None]
    if free_repeats and CHOSEN not in names:
        names = [*names, CHOSEN]
    for name in [*names, *(f"{CHOSEN}{FREE}{r}" for r in range(free_repeats))]:
        setting = {"steps": steps, "profile": SETTINGS[_setting(name)[0]].to_json(),
                   "clock": "robot" if _setting(name)[1] else "simulated"}
        recorded = folder / f"{name}.setting.json"
        if recorded.is_file() and json.loads(recorded.read_text()) != setting:
            raise ValueError(f"{recorded} holds a run of other settings; move it away")
        recorded.write_text(json.dumps(setting))
        tasks = [(m, k, pose, name, steps, "error") for m, k, pose in places]
        keys = [f"{m}/{k}" for m, k, _ in places]
        episodes = run_tasks(_episode, tasks, keys, jobs, folder / f"{name}.episodes.jsonl", name)
        (folder / f"{name}.json").write_text(json.dumps({"setting": setting, "episodes": episodes}))


def _busy_core():
    """A process that holds one core (a busy loop pinned to the last core this process may use): a robot's SLAM."""
    import os
    import subprocess

    core = max(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    pin = (lambda: os.sched_setaffinity(0, {core})) if core is not None else None
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=pin)


def run_timing(names: list[str], walls: list[str], repeats: int, out: Path, steps: int = TIMING_STEPS,
               wall_steps: int = 1000, loaded: list[str] = (), floors: list[str] = (), only_floors: bool = False
               ) -> None:
    """Paced episodes of ``names``, the same of ``loaded`` while a busy-loop process holds one core, then unpaced
    episodes of ``full``, ``walls`` and MapEx; then paced episodes of the default profile on each of ``floors``
    (:func:`~superex_deploy.sim.generated_floors.named_floor`: the timing map at a SLAM resolution, a generated
    floor at 0.1 and 0.05 m), alternated with the timing map at 0.1 m (``only_floors``: those alone); one at a
    time."""
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import run_tasks

    folder = out / "timing"
    folder.mkdir(parents=True, exist_ok=True)
    start = start_poses(TIMING_MAP)[TIMING_START]
    order = [(n, r, "paced", steps) for r in range(repeats) for n in (names if r % 2 == 0 else names[::-1])]
    loaded = list(loaded)
    order += [(n, r, "loaded", steps) for r in range(repeats) for n in (loaded if r % 2 == 0 else loaded[::-1])]
    walls = list(dict.fromkeys(["full", *walls, MAPEX]))
    order += [(n, r, "wall", wall_steps) for r in range(repeats) for n in (walls if r % 2 == 0 else walls[::-1])]
    floors = [TIMING_MAP, *floors] if floors else []
    if only_floors:
        order = []
    order += [(f"{DEFAULT_PROFILE}@{f}", r, "paced", steps) for r in range(repeats)
              for f in (floors if r % 2 == 0 else floors[::-1])]
    for name, repeat, mode, n_steps in order:  # one at a time: the two cores belong to the measured episode
        key = f"{name}/{mode}/{repeat}"
        busy = _busy_core() if mode == "loaded" else None
        setting, _, floor = name.partition("@")
        task = (floor, TIMING_START, None, setting, n_steps, mode) if floor else \
            (TIMING_MAP, TIMING_START, start, name, n_steps, mode)
        try:
            run_tasks(_episode, [task], [key], 1, folder / "episodes.jsonl")
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()
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
        row = rows.setdefault(name if mode != "loaded" else f"{name} (1 core held)", {})
        if mode == "wall":
            row["episode_wall_s"] = float(np.median([e["wall_s"] for e in episodes]))
            continue
        steps = np.concatenate([e["step_ms"] for e in episodes])
        # The prediction wait after the first step (the first may wait for its own prediction: wait_first).
        waits = np.concatenate([e["wait_ms"][1:] for e in episodes]) if all("wait_ms" in e for e in episodes) \
            else np.zeros(0)
        row.update(wait_p99_ms=float(np.percentile(waits, 99)) if waits.size else float("nan"),
                   wait_max_ms=float(waits.max()) if waits.size else float("nan"))
        row.update(p50_ms=float(np.percentile(steps, 50)), p90_ms=float(np.percentile(steps, 90)),
                   p99_ms=float(np.percentile(steps, 99)), max_ms=float(steps.max()), mean_ms=float(steps.mean()),
                   first_step_ms=float(np.median([e["step_ms"][0] for e in episodes])),
                   stages_mean_ms={k: float(np.mean([np.mean(e["timings_s"][k]) * 1e3 for e in episodes]))
                                   for k in episodes[0]["timings_s"]},
                   counters=episodes[-1]["counters"], repeats=len(episodes), steps=len(episodes[0]["step_ms"]))
    return rows


def _fmt(value: float, digits: int = 1) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def report(out: Path) -> None:
    from superex_deploy.evaluation import write_json, write_text
    from superex_deploy.evaluation.summary import paired_summary, row_summary, scenario_key

    timing = _timing_rows(out)
    error = {}
    for split in ("eval", "train"):
        rows = _load_rows(out / f"error_{split}") if (out / f"error_{split}").is_dir() else {}
        if "full" not in rows:
            continue
        steps = json.loads((out / f"error_{split}" / "full.setting.json").read_text())["steps"]
        # Every row on the scenarios all of them finished (an interrupted or --scenarios-limited run pairs on those).
        shared = set.intersection(*({scenario_key(e) for e in episodes} for episodes in rows.values()))
        complete = {n: sorted((e for e in episodes if scenario_key(e) in shared), key=scenario_key)
                    for n, episodes in rows.items()}
        error[split] = {"summary": {n: row_summary(e, steps) for n, e in complete.items()},
                        "paired": {n: paired_summary(complete["full"], e, steps) for n, e in complete.items()
                                   if n != "full"}, "scenarios": len(shared), "steps": steps,
                        "free_paired": {n: paired_summary(complete[CHOSEN], e, steps) for n, e in complete.items()
                                        if FREE in n and CHOSEN in complete}}
    lines = []
    full_t = timing.get("full", {})
    if timing:
        paced = next((r for r in timing.values() if "steps" in r), {})
        lines += [f"**Timing**: {TIMING_MAP} start {TIMING_START}, {paced.get('steps', TIMING_STEPS)} steps paced at "
                  f"{PACE_HZ:.0f} Hz, 2 cores, alternated, each profile on its robot clock (`realtime`: never waits); "
                  "step = what the control loop waits (ms); prediction wait = what it waited for the predictor "
                  "after the first step (blocked on the worker, or predicting inline); `(1 core held)`: while a "
                  "busy-loop process holds one core; ratios to `full` in the same run. Episode wall: unpaced.", ""]
        lines += markdown_table(
            ["setting", "p50", "p90", "p99", "max", "mean", "first step", "p99 / full", "mean / full", "map update",
             "prediction", "prediction wait p99 (max)", "episode wall s"],
            [[name, _fmt(row["p50_ms"]), _fmt(row["p90_ms"]), _fmt(row["p99_ms"]), _fmt(row["max_ms"], 0),
              _fmt(row["mean_ms"]), _fmt(row["first_step_ms"]), _fmt(row["p99_ms"] / full_t.get("p99_ms", np.nan), 2),
              _fmt(row["mean_ms"] / full_t.get("mean_ms", np.nan), 2), _fmt(row["stages_mean_ms"]["map_update"]),
              _fmt(row["stages_mean_ms"]["prediction"]),
              f"{_fmt(row.get('wait_p99_ms', np.nan), 2)} ({_fmt(row.get('wait_max_ms', np.nan), 1)})",
              _fmt(row.get("episode_wall_s", np.nan), 0)] for name, row in timing.items() if "p99_ms" in row],
            ["-"] + ["---:"] * 12)
        walls = {n: r["episode_wall_s"] for n, r in timing.items() if "episode_wall_s" in r}
        if MAPEX in walls:
            lines += ["", "Episode wall time, unpaced, over MapEx on the observed map: " + ", ".join(
                f"{n} {w:.0f} s ({w / walls[MAPEX]:.1f}x)" for n, w in walls.items()), ""]
    for split, data in error.items():
        lines += _free_lines(split, data)
    for split, data in error.items():
        lines += ["", f"**Error** ({split}: {data['scenarios']} scenarios, {data['steps']} steps, deterministic): paired "
                  "with `full`, mean difference [bootstrap 95 %] (ratio of means - 1).", ""]
        full_row = data["summary"]["full"]
        cells = [["full", f"{100 * full_row['auc_first_half']:.1f}", "-", f"{full_row['iou@0.10']:.3f}",
                  f"{full_row['iou@0.20']:.3f}", f"{full_row['iou@0.30']:.3f}", "-"]]
        cells += [_paired_cells(name, data, paired) for name, paired in data["paired"].items() if FREE not in name]
        lines += markdown_table(["setting", *PAIRED_COLUMNS], cells, PAIRED_ALIGN)
    text = "\n".join(lines) + "\n"
    write_text(out / "realtime.md", text)
    write_json(out / "realtime.json", {"timing": timing, "error": error, "default": DEFAULT_PROFILE,
                                       "settings": {n: p.to_json() for n, p in SETTINGS.items()}})
    _pareto(out, timing, error)
    print(text)


PAIRED_COLUMNS = ("first-half AUC", "AUC points", "IoU@10%", "IoU@20%", "IoU@30%", "better / worse / tied")
PAIRED_ALIGN = ("-", "---:", "-", "---:", "---:", "---:", "-")


def _paired_cells(name: str, data: dict, paired: dict) -> list[str]:
    """A row paired with its reference (:func:`~superex_deploy.evaluation.metrics.paired_summary`): its first-half
    AUC, the paired AUC difference in points [95 %] (ratio), the IoU ratios at 10 / 20 / 30 % coverage, the counts."""
    auc = paired["auc_first_half"]
    ious = [paired.get(f"iou@{level:.2f}", {}).get("ratio", np.nan) for level in (0.1, 0.2, 0.3)]
    return [name, f"{100 * data['summary'][name]['auc_first_half']:.1f}",
            f"{100 * auc['mean']:+.2f} [{100 * auc['low']:+.2f}, {100 * auc['high']:+.2f}] "
            f"({100 * auc['ratio']:+.1f} %)",
            *(f"{100 * r:+.1f} %" for r in ious), f"{auc['better']} / {auc['worse']} / {auc['tied']}"]


def _free_lines(split: str, data: dict) -> list[str]:
    """The free-running repeats of the default against its simulated-clock episodes (paired by scenario), and
    the spread of the free-running means over the repeats."""
    free = sorted(n for n in data["summary"] if n.startswith(CHOSEN + FREE))
    if not free or CHOSEN not in data["summary"]:
        return []

    metrics = ("auc_first_half", "iou@0.10", "iou@0.20", "iou@0.30")
    lines = ["", f"**Free-running vs simulated clock** ({split}: {data['scenarios']} scenarios, {data['steps']} "
             f"steps): `{CHOSEN}` on the robot clock (never waits: predictions land when this machine finished them) "
             f"paired with the same profile on the simulated clock (every 2 steps, applied 2 later); mean difference "
             "(ratio of means - 1).", ""]
    lines += markdown_table(["run", *PAIRED_COLUMNS], [_paired_cells(name, data, data["free_paired"][name])
                                                       for name in free], PAIRED_ALIGN)
    spread = {m: np.std([data["summary"][n][m] for n in free], ddof=1) if len(free) > 1 else np.nan
              for m in metrics}
    lines += ["", f"Spread of the free-running means over {len(free)} repeats (standard deviation): first-half AUC "
              f"{100 * spread['auc_first_half']:.2f} points, IoU@10/20/30% " +
              " / ".join(f"{spread[m]:.4f}" for m in metrics[1:]) + "."]
    return lines


def _pareto(out: Path, timing: dict, error: dict) -> None:
    """p99 step time (timing run) against the first-half AUC loss vs ``full``: one marker per setting and split
    (train: where the settings are chosen; eval: where they are reported); the default is a star."""
    if not error or not timing:
        return
    from superex_deploy.evaluation.reports import pyplot, save_figure

    fig, ax = pyplot().subplots(figsize=(8, 5))
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
    save_figure(fig, out / "pareto.png", dpi=120)


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
    parser.add_argument("--free-repeats", type=int, default=3, help="with --error: free-running (robot clock) "
                        "repeats of the default's error episodes, paired with its simulated-clock ones (0: none)")
    parser.add_argument("--scenarios", type=int, default=0, help="with --error: only the first N scenarios (0: all)")
    parser.add_argument("--timing-steps", type=int, default=TIMING_STEPS, help="paced episode length")
    parser.add_argument("--wall-steps", type=int, default=1000, help="unpaced episode length (episode wall time)")
    parser.add_argument("--loaded-settings", default=None, help="settings also timed paced while a busy-loop "
                        "process holds one core (default: full and the default profile; '' for none)")
    parser.add_argument("--timing-floors", default="", help=f"with --timing: floors to time too (e.g. {TIMING_MAP}@x2)")
    parser.add_argument("--only-floors", action="store_true", help="with --timing-floors: time those floors alone")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "realtime")
    args = parser.parse_args()
    names = _names(args.settings)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.error:
        run_error(args.error, names, args.steps, args.jobs, args.out, args.free_repeats, args.scenarios)
    if args.timing:
        walls = [w for w in _names(f"full,{CHOSEN}," + args.wall_settings) if w != "full"]
        if args.loaded_settings is None:
            loaded = ["full", CHOSEN]
        else:
            loaded = [n for n in args.loaded_settings.split(",") if n.strip()]
            unknown = [n for n in loaded if n not in SETTINGS]
            if unknown:
                raise ValueError(f"--loaded-settings: unknown setting(s) {unknown}")
        run_timing(_names(args.timing_settings) if args.timing_settings else names, walls, args.repeats, args.out,
                   args.timing_steps, args.wall_steps, loaded, floors=[f for f in args.timing_floors.split(",") if f],
                   only_floors=args.only_floors)
    report(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
