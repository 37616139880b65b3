"""``superex benchmark --suite paper``: the paper's rows on the 40 eval scenarios, resumable row by row."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.commands._options import (check_jobs, check_output_folder, eval_maps, make_backend,
                                               settings_differences)
from superex_deploy.files import write_atomically
from superex_deploy.sim.suite import (CHECKPOINTS, IOU_BINS, IOU_LEVELS, PAPER_ROWS, REFERENCE_ROW,
                                          paired_summary, row_summary)

IOU_SCHEDULE = {"iou_every": 10, "iou_dense_until": 0.35}
"""IoU every 10 steps while the coverage is below 35 % (the IoU metrics read that part), every 100 after."""


def _rows(names: list[str]) -> list[str]:
    """``--rows`` (a :func:`~superex_deploy.commands._options.name_list`) -> row names; ``["all"]`` is every row."""
    names = list(PAPER_ROWS) if list(names) == ["all"] else list(names)
    unknown = [r for r in names if r not in PAPER_ROWS]
    if unknown:
        raise ValueError(f"--rows: unknown row(s) {', '.join(unknown)}; choose from {', '.join(PAPER_ROWS)} or 'all'")
    return names


def _refuse_other_settings(path: Path, recorded: dict, setting: dict, advice: str) -> None:
    differences = settings_differences(recorded, json.loads(json.dumps(setting)))
    if differences:
        raise ValueError(f"{path} was run with other settings ({'; '.join(differences)}); {advice}")


def _run_row(name: str, args: argparse.Namespace, maps: list[str], rows_dir: Path, setting: dict,
             backend) -> list[dict]:
    """The row's episodes, each appended to ``rows_dir/NAME.episodes.jsonl`` as it finishes (a rerun resumes)."""
    from superex_deploy.benchmarking import ScenarioTask, run_scenario
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import run_tasks

    row = PAPER_ROWS[name]
    tasks = [ScenarioTask(map_name=m, start_index=k, start_rc=pose, planner=row.planner, predictor=row.predictor,
                          spad=row.spad, steps=args.steps, seed=args.seed, **IOU_SCHEDULE)
             for m in maps for k, pose in enumerate(start_poses(m))]
    keys = [f"{task.map_name}/{task.start_index}" for task in tasks]
    recorded = rows_dir / f"{name}.setting.json"
    setting = {**setting, "row": {"planner": row.planner, "predictor": row.predictor, "spad": row.spad}}
    if recorded.is_file():
        _refuse_other_settings(recorded, json.loads(recorded.read_text()), setting,
                               f"move it and {name}.episodes.jsonl away or choose another --out")
    write_atomically(recorded, json.dumps(setting))
    episodes = run_tasks(run_scenario, tasks, keys, backend, rows_dir / f"{name}.episodes.jsonl", name)
    for episode in episodes:
        episode["row"] = name
    return episodes


def _percent(value: float, digits: int = 1) -> str:
    return "-" if not np.isfinite(value) else f"{100 * value:.{digits}f}"


def _table(rows: dict[str, list[dict]], steps: int) -> tuple[str, dict]:
    summaries = {name: row_summary(episodes, steps) for name, episodes in rows.items()}
    paired = {name: paired_summary(rows[REFERENCE_ROW], episodes, steps)
              for name, episodes in rows.items() if REFERENCE_ROW in rows and name != REFERENCE_ROW}
    checkpoints = [n for n in CHECKPOINTS if n <= steps]
    cov_cols = [f"coverage@{n}" for n in checkpoints] + ["auc_first_half", "auc"]
    lines = ["| row | what | " + " | ".join(cov_cols) + " | LOS only: auc_first_half | "
             + " | ".join(f"IoU@{int(100 * lv)}%" for lv in IOU_LEVELS) + " | "
             + " | ".join(f"IoU {int(100 * a)}-{int(100 * b)}%" for a, b in IOU_BINS)
             + " | scoring ms / goal | prediction ms / goal |",
             "|---|---|" + "---:|" * (len(cov_cols) + 3 + len(IOU_LEVELS) + len(IOU_BINS))]
    for name, summary in summaries.items():
        cells = [_percent(summary[c]) for c in cov_cols] + [_percent(summary["los_auc_first_half"])]
        cells += [f"{summary[f'iou@{lv:.2f}']:.3f}" for lv in IOU_LEVELS]
        cells += [f"{summary[f'iou_bin_{a:.1f}_{b:.1f}']:.3f}" for a, b in IOU_BINS]
        cells += [f"{summary.get(f'{stage}_ms_per_goal', float('nan')):.1f}" for stage in ("scoring", "prediction")]
        lines.append(f"| {name} | {PAPER_ROWS[name].label} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    if paired:
        metrics = ["auc_first_half", "auc"] + [f"coverage@{n}" for n in checkpoints] + [
            f"iou@{lv:.2f}" for lv in IOU_LEVELS] + [f"iou_bin_{a:.1f}_{b:.1f}" for a, b in IOU_BINS]
        text += (f"\nPaired by scenario against {REFERENCE_ROW} ({PAPER_ROWS[REFERENCE_ROW].label}): mean difference "
                 f"[bootstrap 95 % interval], ratio of means - 1, better / worse / tied. Coverage in points.\n\n")
        text += "| row | " + " | ".join(metrics) + " |\n|---|" + "---|" * len(metrics) + "\n"
        for name, per_metric in paired.items():
            cells = []
            for metric in metrics:
                d = per_metric.get(metric)
                if d is None:
                    cells.append("-")
                    continue
                scale, digits = (100.0, 2) if not metric.startswith("iou") else (1.0, 3)
                cells.append(f"{d['mean'] * scale:+.{digits}f} [{d['low'] * scale:+.{digits}f}, "
                             f"{d['high'] * scale:+.{digits}f}] {d['ratio']:+.1%} {d['better']}/{d['worse']}/"
                             f"{d['tied']}")
            text += f"| {name} | " + " | ".join(cells) + " |\n"
    return text, {"summary": summaries, "paired_vs_reference": paired, "reference": REFERENCE_ROW}


def run_paper(args: argparse.Namespace) -> int:
    from superex_deploy.parallel import Interrupted
    from superex_deploy.render import save_suite_plots

    names = _rows(args.rows)
    if args.planner_option:
        raise ValueError("--planner-option does not apply to --suite paper: its rows fix their planners' settings")
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    check_jobs(args)
    maps = eval_maps(args.maps)
    check_output_folder(args.out)
    backend = make_backend(args)
    rows_dir = args.out / "rows"
    rows_dir.mkdir(parents=True, exist_ok=True)
    setting = {"maps": maps, "steps": args.steps, "seed": args.seed, "iou": IOU_SCHEDULE}
    for name in names:
        path = rows_dir / f"{name}.json"
        if path.is_file():
            done = json.loads(path.read_text())
            if done.get("setting") == setting:
                print(f"{name}: done already ({path})")
                continue
            _refuse_other_settings(path, done.get("setting"), setting, "move it away or choose another --out")
        try:
            episodes = _run_row(name, args, maps, rows_dir, setting, backend)
        except Interrupted as stop:
            stop.kept = (f"the finished episodes of row {name} are in {rows_dir / (name + '.episodes.jsonl')}: rerun "
                         f"the same command to finish")
            raise
        write_atomically(path, json.dumps({"row": name, "setting": setting, "episodes": episodes}))
    rows = {}
    for name in PAPER_ROWS:  # every finished row, in the table's order
        path = rows_dir / f"{name}.json"
        if path.is_file():
            done = json.loads(path.read_text())
            if done.get("setting") == setting:
                rows[name] = done["episodes"]
    text, summary = _table(rows, args.steps)
    header = (f"{len(maps)} maps, {len(next(iter(rows.values())))} scenarios, {args.steps} steps, seed {args.seed}. "
              f"Coverage: % of the valid area known, NLOS-carved cells included (LOS only: without them); "
              f"auc_first_half: mean coverage over steps 1-{args.steps // 2}; IoU: wall IoU of the prediction over "
              f"the evaluation area at the first evaluation reaching each coverage, and the mean within each "
              f"coverage bin; ms / goal: median over episodes of the mean time per goal choice (2 episodes in "
              f"parallel on this machine).\n\n")
    write_atomically(args.out / "results.md", header + text)
    write_atomically(args.out / "results.json", json.dumps({"setting": setting, **summary}, indent=1))
    save_suite_plots(args.out, rows, args.steps)
    print(header + text)
    print(f"wrote {args.out / 'results.md'}, results.json, coverage.png, iou_vs_coverage.png")
    return 0
