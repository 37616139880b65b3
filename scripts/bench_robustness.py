"""How the onboard explorer holds up on a robot's data: localisation error, LiDAR noise, SPAD photon budgets.

The results and their reading: docs/on-a-robot.md, "What it tolerates, and where it breaks".

Every setting is a point of the grid pose noise x SPAD preset x LiDAR noise:

* pose noise (``sigma_xy`` m, ``sigma_yaw`` deg; white jitter plus a bounded drift, see
  :class:`superex_deploy.sim.noise.pose.PoseNoise`): ``0``, ``0.02,0.5``, ``0.05,1``, ``0.10,2``;
* SPAD photon budget (:data:`superex_deploy.spad_types.SPAD_PRESETS`): ``off`` (the ideal noise-free sensor),
  ``realistic``, ``low``;
* LiDAR range noise ``sigma`` (m, with 1 % dropouts and 0.1 % spurious short returns when on): ``0``, ``0.02``.

Two groups of rows explore the eval scenarios (reporting only; nothing here is tuned):

* ``nearest`` (the nearest-frontier planner on the observed map, SPAD carving on): every setting, on
  ``--scenarios`` eval scenarios;
* the SuperEx pipeline (``superex`` planner, LaMa-BP, SPAD) and its line-of-sight counterpart (``superex`` on
  LaMa-LOS) at the settings named by ``--superex-settings``, on ``--superex-scenarios`` scenarios: SuperEx's map
  IoU gain over LaMa-LOS at 10 / 20 % coverage, noise-free against noisy.

Per setting: collisions, true wall cells held free per 1,000 true wall cells seen (pooled over episodes) and the
part of them with no wall of the map within one cell ("missing": walls the map lacks, not walls it holds a cell
off), true wall cells carved, the explorer map's wall IoU as a fraction of the same scenario's noise-free run
(median; also the IoU that forgives a wall held one cell off), and the first-half coverage AUC paired with the
noise-free run (the mean relative difference, which the AUC target reads, and the mean difference in coverage
points, each with a bootstrap 95 % interval seeded per row). SuperEx's gain is paired per scenario
(bootstrap 95 % interval) and set against its noise-free gain (target: at least half of it kept at 10 % coverage).
The targets (no collision, no true wall carved, at most 1 true wall held free per 1,000 seen, map IoU at least 0.9x
and first-half AUC within 3 % of noise-free) are checked per setting and the table says where each breaks.

Every episode is journaled (``OUT/episodes.jsonl``): an interrupted run resumes where it stopped, and a second run
with more scenarios adds only the missing episodes. Writes ``OUT/robustness.json``, ``OUT/robustness.md`` and one
plot per measure against the pose noise (``OUT/*.png``).

    python scripts/bench_robustness.py --out benchmarks/robustness --scenarios 40 --superex-scenarios 12
"""

from __future__ import annotations

import argparse
import json
import sys
import zlib
from pathlib import Path

import numpy as np

from superex_deploy import evaluation
from superex_deploy.evaluation.metrics import first_half_auc, iou_at_coverage
from superex_deploy.evaluation.summary import mean_with_interval, scenario_key
from superex_deploy.evaluation.reports import markdown_table, pyplot, save_figure

POSE_LEVELS = ((0.0, 0.0), (0.02, 0.5), (0.05, 1.0), (0.10, 2.0))
SPAD_PRESETS = ("off", "realistic", "low")
LIDAR_LEVELS = (0.0, 0.02)
LIDAR_DROPOUT, LIDAR_SPURIOUS = 0.01, 0.001
TARGET_POSE = (0.05, 1.0)  # the targets hold up to this pose noise, LiDAR 2 cm and the realistic preset
FIRST_HALF = 0.5  # the AUC's share of the run (evaluation.first_half_auc: steps // 2), recorded in the JSON


def setting_name(pose, spad: str, lidar: float) -> str:
    return f"pose{pose[0]:g}m{pose[1]:g}deg_spad-{spad}_lidar{lidar:g}m"


def all_settings() -> list[tuple[tuple[float, float], str, float]]:
    return [(pose, spad, lidar) for pose in POSE_LEVELS for spad in SPAD_PRESETS for lidar in LIDAR_LEVELS]


def eval_scenarios(count: int) -> list[tuple[str, int, tuple[int, int]]]:
    """``count`` of the 40 eval scenarios, spread over the maps: first every map's start 0, then start 1, ..."""
    return evaluation.eval_scenarios("start")[:count]


def episode_task(scenario, planner: str, predictor: str, setting, steps: int):
    from superex_deploy.evaluation.tasks import ScenarioTask
    from superex_deploy.sim.noise.model import SimNoise

    (map_name, start_index, start_rc), (pose, spad, lidar) = scenario, setting
    noise = SimNoise.from_sigmas(pose=None if pose == (0.0, 0.0) else pose,
                                 lidar=None if lidar == 0.0 else (lidar, LIDAR_DROPOUT, LIDAR_SPURIOUS),
                                 spad=spad if predictor != "lama_los" else "off")
    return ScenarioTask(map_name=map_name, start_index=start_index, start_rc=tuple(start_rc), planner=planner,
                        predictor=predictor, spad=predictor != "lama_los", steps=steps, seed=start_index,
                        profile="full", iou_every=25, noise=noise)


def run_episode_task(task) -> dict:
    """Worker: one episode's summary, trimmed to what the tables read."""
    from superex_deploy.evaluation.tasks import run_scenario

    summary = run_scenario(task)
    keep = ("map", "planner", "predictor", "start_index", "steps", "coverage", "iou", "collisions",
            "true_walls_held_free", "true_walls_carved", "map_iou", "true_walls_seen", "true_walls_missing",
            "map_iou_within_cell", "final_coverage")
    return {key: summary[key] for key in keep}


def summarise_setting(episodes: list[dict], baseline: dict, steps: int, rng) -> dict:
    """One setting's row: pooled and paired measures against the noise-free episodes ``baseline`` (by scenario)."""
    seen = sum(e["true_walls_seen"] for e in episodes)
    held_free = sum(e["true_walls_held_free"] for e in episodes)
    missing = sum(e.get("true_walls_missing", 0) for e in episodes)
    auc_rel, auc_points, iou_ratio, tolerant_ratio = [], [], [], []
    for episode in episodes:
        reference = baseline.get(scenario_key(episode))
        if reference is None:
            continue
        auc, ref_auc = first_half_auc(episode["coverage"], steps), first_half_auc(reference["coverage"], steps)
        auc_rel.append(auc / ref_auc - 1.0 if ref_auc > 0 else np.nan)
        auc_points.append(100.0 * (auc - ref_auc))
        iou_ratio.append(episode["map_iou"] / reference["map_iou"] if reference["map_iou"] > 0 else np.nan)
        tolerant = episode.get("map_iou_within_cell", np.nan), reference.get("map_iou_within_cell", np.nan)
        tolerant_ratio.append(tolerant[0] / tolerant[1] if tolerant[1] > 0 else np.nan)
    auc_mean, auc_low, auc_high = mean_with_interval(np.array(auc_rel), rng)
    return {
        "episodes": len(episodes),
        "collisions": int(sum(e["collisions"] for e in episodes)),
        "held_free_per_1000_seen": 1000.0 * held_free / seen if seen else float("nan"),
        "missing_per_1000_seen": 1000.0 * missing / seen if seen else float("nan"),
        "true_walls_carved": int(sum(e["true_walls_carved"] for e in episodes)),
        "map_iou": float(np.mean([e["map_iou"] for e in episodes])),
        "map_iou_vs_noise_free": float(np.nanmedian(iou_ratio)) if iou_ratio else float("nan"),
        "map_iou_within_cell_vs_noise_free": (float(np.nanmedian(tolerant_ratio))
                                              if np.isfinite(tolerant_ratio).any() else float("nan")),
        "first_half_auc": float(np.mean([first_half_auc(e["coverage"], steps) for e in episodes])),
        "auc_vs_noise_free": [auc_mean, auc_low, auc_high],
        "auc_points_vs_noise_free": list(mean_with_interval(np.array(auc_points), rng)),
        "final_coverage": float(np.mean([e["final_coverage"] for e in episodes])),
    }


def targets_met(row: dict) -> dict:
    """The robustness targets for one setting (each True / False)."""
    return {"no collisions": row["collisions"] == 0, "no carved walls": row["true_walls_carved"] == 0,
            "held free <= 1 per 1000": row["held_free_per_1000_seen"] <= 1.0,
            "map IoU >= 0.9 x noise-free": row["map_iou_vs_noise_free"] >= 0.9,
            "AUC within 3 %": row["auc_vs_noise_free"][0] >= -0.03}


def superex_gain(pipeline: list[dict], los: list[dict], level: float, rng) -> list[float]:
    """Mean paired IoU gain (SuperEx pipeline - LaMa-LOS) at coverage ``level`` over the shared scenarios that
    reached it, with a bootstrap 95 % interval: ``[mean, low, high]``."""
    by_scenario = {scenario_key(e): e for e in los}
    gains = [iou_at_coverage(e, level) - iou_at_coverage(by_scenario[scenario_key(e)], level)
             for e in pipeline if scenario_key(e) in by_scenario]
    return list(mean_with_interval(np.array(gains, float), rng))


def _pose_text(row: dict) -> str:
    return f"{row['pose'][0] * 100:g} cm / {row['pose'][1]:g} deg"


def side_by_side(before: dict, rows: dict) -> list[str]:
    """Markdown lines: each setting's headline measures in a previous run (``before``: its robustness.json) and in
    this one."""
    cells = []
    for name, row in rows.items():
        old = before.get("settings", {}).get(name)
        if old is None:
            continue
        cells.append([_pose_text(row), row["spad"], f"{row['lidar_m'] * 100:g} cm",
                      f"{old['held_free_per_1000_seen']:.2f} -> {row['held_free_per_1000_seen']:.2f}",
                      f"{old['map_iou_vs_noise_free']:.3f} -> {row['map_iou_vs_noise_free']:.3f}",
                      f"{old['auc_vs_noise_free'][0] * 100:+.1f} % -> {row['auc_vs_noise_free'][0] * 100:+.1f} %",
                      f"{old['collisions']} -> {row['collisions']}",
                      f"{old['true_walls_carved']} -> {row['true_walls_carved']}",
                      f"{old['episodes']} -> {row['episodes']}"])
    return ["", "## Before and after (the previous run's robustness.json given by --before)", ""] + markdown_table(
        ["pose noise", "SPAD", "LiDAR", "held free / 1000 seen", "map IoU / noise-free", "AUC vs noise-free",
         "collisions", "walls carved", "episodes"], cells)


def report(out: Path, results: dict, steps: int, superex_settings: list, before: dict = None) -> dict:
    def rng(name: str) -> np.random.Generator:
        # One bootstrap stream per row: a row's interval does not depend on which other rows the run holds.
        return np.random.default_rng(zlib.crc32(name.encode()))

    nearest = {name: eps for (group, name), eps in results.items() if group == "nearest"}
    base_name = setting_name((0.0, 0.0), "off", 0.0)
    baseline = {scenario_key(e): e for e in nearest.get(base_name, [])}
    rows = {}
    for pose, spad, lidar in all_settings():
        name = setting_name(pose, spad, lidar)
        if nearest.get(name):
            row = summarise_setting(nearest[name], baseline, steps, rng(name))
            row.update(pose=list(pose), spad=spad, lidar_m=lidar, targets=targets_met(row))
            rows[name] = row
    gains = {}
    for setting in superex_settings:
        name = setting_name(*setting)
        pipeline, los = results.get(("superex_bp", name), []), results.get(("superex_los", name), [])
        if pipeline and los:
            gains[name] = {f"iou_gain@{int(level * 100)}%": superex_gain(pipeline, los, level, rng(f"{name}@{level}"))
                           for level in (0.1, 0.2)}
            gains[name]["episodes"] = min(len(pipeline), len(los))
            gains[name]["collisions"] = int(sum(e["collisions"] for e in pipeline))
            gains[name]["true_walls_carved"] = int(sum(e["true_walls_carved"] for e in pipeline))
    noise_free_gain = gains.get(base_name, {}).get("iou_gain@10%", [float("nan")])[0]
    for name, gain in gains.items():
        # The target: at least half of the noise-free gain at 10 % coverage kept under noise.
        gain["kept@10%"] = gain["iou_gain@10%"][0] / noise_free_gain if noise_free_gain > 0 else float("nan")
    summary = {"steps": steps, "settings": rows, "superex": gains, "first_half": FIRST_HALF}
    evaluation.write_json(out / "robustness.json", summary)
    cells = []
    for row in rows.values():
        mean, low, high = row["auc_vs_noise_free"]
        missed = ", ".join(k for k, ok in row["targets"].items() if not ok) or "-"
        cells.append([_pose_text(row), row["spad"], f"{row['lidar_m'] * 100:g} cm", row["episodes"], row["collisions"],
                      f"{row['held_free_per_1000_seen']:.2f}",
                      f"{row['missing_per_1000_seen']:.2f}", row["true_walls_carved"], f"{row['map_iou']:.3f}",
                      f"{row['map_iou_vs_noise_free']:.3f}", f"{row['map_iou_within_cell_vs_noise_free']:.3f}",
                      f"{row['first_half_auc'] * 100:.1f}",
                      f"{mean * 100:+.1f} % [{low * 100:+.1f}, {high * 100:+.1f}]",
                      "{:+.2f} [{:+.2f}, {:+.2f}]".format(*row["auc_points_vs_noise_free"]), missed])
    lines = [f"# Robustness: {steps} steps per episode, nearest frontier on the observed map with SPAD carving", ""]
    lines += markdown_table(["pose noise", "SPAD", "LiDAR", "episodes", "collisions", "held free / 1000 seen",
                             "of them missing", "walls carved", "map IoU", "IoU / noise-free",
                             "IoU within a cell / noise-free", "first-half AUC", "AUC vs noise-free [95 %]",
                             "AUC points vs noise-free [95 %]", "targets missed"], cells,
                            ["-"] * 3 + ["---:"] * 9 + ["-"] * 3)
    if gains:
        lines += ["", "## The SuperEx pipeline against LaMa-LOS (superex planner), map IoU gain", ""]
        lines += markdown_table(
            ["setting", "episodes", "IoU gain @10 % [95 %]", "IoU gain @20 % [95 %]",
             "gain @10 % kept of noise-free", "collisions", "walls carved"],
            [[name, gain["episodes"], *(f"{g[0]:+.3f} [{g[1]:+.3f}, {g[2]:+.3f}]"
                                        for g in (gain["iou_gain@10%"], gain["iou_gain@20%"])),
              f"{gain['kept@10%']:.2f}", gain["collisions"], gain["true_walls_carved"]]
             for name, gain in gains.items()],
            ["-", "---:", "-", "-", "---:", "---:", "---:"])
    if before:
        lines += side_by_side(before, rows)
    evaluation.write_text(out / "robustness.md", "\n".join(lines) + "\n")
    plot(out, rows)
    return summary


def plot(out: Path, rows: dict) -> None:
    plt = pyplot()
    measures = {"collisions": "collisions", "held_free_per_1000_seen": "true walls held free / 1000 seen",
                "missing_per_1000_seen": "true walls missing (no map wall within a cell) / 1000 seen",
                "true_walls_carved": "true wall cells carved", "map_iou_vs_noise_free": "map IoU / noise-free",
                "auc_vs_noise_free": "first-half AUC vs noise-free"}
    for key, label in measures.items():
        fig, ax = plt.subplots(figsize=(5, 3.2))
        for spad in SPAD_PRESETS:
            for lidar in LIDAR_LEVELS:
                points = [(row["pose"][0] * 100, row[key][0] if key == "auc_vs_noise_free" else row[key])
                          for row in rows.values() if row["spad"] == spad and row["lidar_m"] == lidar]
                if points:
                    xs, ys = zip(*sorted(points))
                    ax.plot(xs, ys, marker="o", label=f"SPAD {spad}, LiDAR {lidar * 100:g} cm")
        ax.set_xlabel("pose noise sigma_xy (cm; yaw 0 / 0.5 / 1 / 2 deg)")
        ax.set_ylabel(label)
        ax.legend(fontsize=6)
        fig.tight_layout()
        save_figure(fig, out / f"{key}.png", dpi=90)


def parse_setting(text: str):
    pose_m, pose_deg, spad, lidar = text.split(",")
    return (float(pose_m), float(pose_deg)), spad, float(lidar)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/robustness"))
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--scenarios", type=int, default=40, help="eval scenarios for the nearest rows (<= 40)")
    parser.add_argument("--superex-scenarios", type=int, default=12)
    parser.add_argument("--superex-settings", nargs="*", type=parse_setting,
                        default=[((0.0, 0.0), "off", 0.0), ((0.05, 1.0), "realistic", 0.02)],
                        help="settings for the SuperEx rows, each POSE_M,POSE_DEG,SPAD,LIDAR_M")
    parser.add_argument("--settings", choices=("all", "targets"), default="all",
                        help="'targets': only the noise-free point and the pose levels at SPAD realistic, LiDAR 2 cm")
    parser.add_argument("--only", nargs="*", type=parse_setting, default=None,
                        help="run only these settings (each POSE_M,POSE_DEG,SPAD,LIDAR_M) instead of --settings; the "
                             "noise-free point is always run (every row is paired with it)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--report-only", action="store_true", help="rewrite the tables from the journal")
    parser.add_argument("--before", type=Path, default=None,
                        help="a previous run's robustness.json: the table gains a before / after comparison")
    args = parser.parse_args(argv)
    if not 1 <= args.scenarios <= 40 or not 0 <= args.superex_scenarios <= 40 or args.steps < 2 or args.jobs < 1:
        parser.error("--scenarios in 1..40, --superex-scenarios in 0..40, --steps >= 2, --jobs >= 1")
    for setting in args.superex_settings + (args.only or []):
        if setting[1] not in SPAD_PRESETS:
            parser.error(f"--superex-settings / --only: SPAD preset {setting[1]!r} is not one of {SPAD_PRESETS}")

    from superex_deploy.parallel import Interrupted, read_journal, run_tasks

    args.out.mkdir(parents=True, exist_ok=True)
    journal = args.out / "episodes.jsonl"
    noise_free = ((0.0, 0.0), "off", 0.0)
    if args.only is not None:
        settings = [noise_free] + [setting for setting in args.only if setting != noise_free]
    else:
        settings = all_settings() if args.settings == "all" else (
            [noise_free] + [(pose, "realistic", 0.02) for pose in POSE_LEVELS])
    tasks, keys = [], []
    for scenario in eval_scenarios(args.scenarios):
        for setting in settings:
            tasks.append(episode_task(scenario, "nearest", "observed", setting, args.steps))
            keys.append(f"nearest|{setting_name(*setting)}|{scenario[0]}|{scenario[1]}|{args.steps}")
    for scenario in eval_scenarios(args.superex_scenarios):
        for setting in args.superex_settings:
            for group, predictor in (("superex_bp", "lama_bp"), ("superex_los", "lama_los")):
                tasks.append(episode_task(scenario, "superex", predictor, setting, args.steps))
                keys.append(f"{group}|{setting_name(*setting)}|{scenario[0]}|{scenario[1]}|{args.steps}")
    if not args.report_only:
        try:
            run_tasks(run_episode_task, tasks, keys, args.jobs, journal, progress="robustness episodes")
        except Interrupted as stop:
            print(f"{stop}; the journal keeps every finished episode: run the same command to resume",
                  file=sys.stderr)
            return 130
    done = read_journal(journal)
    results: dict = {}
    for key, value in done.items():
        group, name, _, _, steps = key.split("|")
        if int(steps) == args.steps:
            results.setdefault((group, name), []).append(value)
    before = json.loads(args.before.read_text()) if args.before is not None else None
    summary = report(args.out, results, args.steps, args.superex_settings, before)
    print((args.out / "robustness.md").read_text())
    print(f"{len(done)} episodes in {journal}; {len(summary['settings'])} settings")
    return 0


if __name__ == "__main__":
    sys.exit(main())
