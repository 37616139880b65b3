"""``superex benchmark --suite paper`` and ``--suite altered``: the paper's rows on the 40 eval scenarios, resumable
row by row. Its rows are the named pipelines (:data:`~superex_deploy.pipeline.PIPELINES`), each run under the
``full`` profile (the table measures models and planners).

``altered`` runs them on the eval floors altered with a fixed seed per scenario
(:mod:`superex_deploy.sim.altered_floors`): the floors are made first, once each, into ``OUT/floors/`` (journal
``OUT/floors.jsonl``; ``OUT/floors.json`` lists what each holds), and the table gains the dead-end entries and a
second pairing, against MapEx on the observed map (the oracle ceiling's baseline).

A finished row run on fewer maps (``--maps``, e.g. an expensive SPAD row) enters the table of a later run of the
same protocol; it is paired on the scenarios it shares with the reference. A row's setting holds its planner's and
its SPAD sensing's whole configurations (``planner_config``, ``sensing``): a row finished with other defaults is
refused by a rerun that names it, and left out of the table of a run that does not.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.commands.options import (check_jobs, check_output_folder, eval_maps, make_backend,
                                             settings_differences)
from superex_deploy.files import write_atomically
from superex_deploy.pipeline import PIPELINES
from superex_deploy.evaluation.metrics import CHECKPOINTS, DEAD_END_METRICS, IOU_BINS, IOU_LEVELS
from superex_deploy.evaluation.summary import REFERENCE_ROW, common_scenarios, paired_summary, row_summary

IOU_SCHEDULE = {"iou_every": 10, "iou_dense_until": 0.35}
"""IoU every 10 steps while the coverage is below 35 % (the IoU metrics read that part), every 100 after."""


def _rows(names: list[str]) -> list[str]:
    """``--rows`` (a :func:`~superex_deploy.commands.options.name_list`) -> row names; ``["all"]`` is every row."""
    names = list(PIPELINES) if list(names) == ["all"] else list(names)
    unknown = [r for r in names if r not in PIPELINES]
    if unknown:
        raise ValueError(f"--rows: unknown row(s) {', '.join(unknown)}; choose from {', '.join(PIPELINES)} or 'all'")
    return names


CEILING_REFERENCE = "mapex_observed"
"""The altered suite also pairs every row against this one: the oracle ceiling's baseline."""


def _row_setting(setting: dict, name: str) -> dict:
    """``setting`` with what row ``name`` runs in full: its planner's whole configuration (``planner_config``) and
    its SPAD sensing's (``sensing``, None without). A row written by a version before 0.2 holds neither: it differs
    from every setting of this version, and is refused (or left out of the table) as one of another protocol."""
    from superex_deploy.evaluation.tasks import default_sensing_settings
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.recording.metadata import planner_settings

    row = PIPELINES[name]
    return json.loads(json.dumps({**setting, "planner_config": planner_settings(make_planner(row.planner)),
                                  "sensing": default_sensing_settings() if row.spad else None}))


def _same_protocol(recorded: dict, setting: dict) -> bool:
    """Whether a finished row's setting is ``setting`` but perhaps for its maps (a row run on fewer maps)."""
    if not isinstance(recorded, dict):
        return False
    recorded, setting = json.loads(json.dumps(recorded)), json.loads(json.dumps(setting))
    return ({k: v for k, v in recorded.items() if k != "maps"} == {k: v for k, v in setting.items() if k != "maps"}
            and set(recorded.get("maps", ())) <= set(setting["maps"]))


def _make_floors(maps: list[str], out: Path, backend) -> list[dict]:
    """The altered floor of every scenario of ``maps``, made once into ``OUT/floors/`` (resumable); their
    summaries (:func:`~superex_deploy.sim.altered_floors.floor_summary`), in scenario order."""
    from superex_deploy.evaluation.tasks import make_altered_floor
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import run_tasks

    tasks = [(m, pose, str(out / "floors")) for m in maps for pose in start_poses(m)]
    keys = [f"{m}/{pose[0]}_{pose[1]}" for m, pose, _ in tasks]
    return run_tasks(make_altered_floor, tasks, keys, backend, out / "floors.jsonl", "floors")


def _refuse_other_settings(path: Path, recorded: dict, setting: dict, advice: str) -> None:
    differences = settings_differences(recorded, json.loads(json.dumps(setting)))
    if differences:
        raise ValueError(f"{path} was run with other settings ({'; '.join(differences)}); {advice}")


def _run_row(name: str, args: argparse.Namespace, maps: list[str], rows_dir: Path, setting: dict,
             backend) -> list[dict]:
    """The row's episodes, each appended to ``rows_dir/NAME.episodes.jsonl`` as it finishes (a rerun resumes)."""
    from superex_deploy.evaluation.tasks import ScenarioTask, run_scenario
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import run_tasks

    from superex_deploy.sim.altered_floors import alteration_seed

    row = PIPELINES[name]
    altered = {} if "alteration" not in setting else {"floors_dir": str(args.out / "floors")}
    tasks = [ScenarioTask(map_name=m, start_index=k, start_rc=pose, planner=row.planner, predictor=row.predictor,
                          spad=row.spad, carving=row.carving, steps=args.steps, seed=args.seed, profile="full",
                          **IOU_SCHEDULE, **altered,
                          **({"alteration_seed": alteration_seed(m, pose)} if altered else {}))
             for m in maps for k, pose in enumerate(start_poses(m))]
    keys = [f"{task.map_name}/{task.start_index}" for task in tasks]
    recorded = rows_dir / f"{name}.setting.json"
    setting = {**setting, "row": {"planner": row.planner, "predictor": row.predictor, "spad": row.spad,
                                  **({} if row.carving else {"carving": False})}}
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


def _paired_lines(rows: dict[str, list[dict]], reference: str, steps: int, metrics: list[str]
                  ) -> tuple[str, dict]:
    """The paired table of every row against ``reference`` (markdown) and its numbers."""
    paired = {}
    for name, episodes in rows.items():
        if name != reference:
            ref, cand = common_scenarios(rows[reference], episodes)
            paired[name] = paired_summary(ref, cand, steps)
    note = ("; dead ends in entries and metres per scenario (there better / worse count larger / smaller values: "
            "fewer metres is the better outcome)") if any(m in DEAD_END_METRICS for m in metrics) else ""
    text = (f"\nPaired by scenario against {reference} ({PIPELINES[reference].label}): mean difference "
            f"[bootstrap 95 % interval], ratio of means - 1, better / worse / tied. Coverage in points{note}.\n\n")
    sizes = {name: max((d["n"] for d in per.values()), default=0) for name, per in paired.items()}
    uneven = len(set(sizes.values())) > 1
    text += ("| row | " + ("scenarios | " if uneven else "") + " | ".join(metrics) + " |\n|---|"
             + ("---:|" if uneven else "") + "---|" * len(metrics) + "\n")
    for name, per_metric in paired.items():
        cells = [str(sizes[name])] if uneven else []
        for metric in metrics:
            d = per_metric.get(metric)
            if d is None:
                cells.append("-")
                continue
            scale, digits = ((100.0, 2) if not metric.startswith(("iou", "dead_end")) else
                             (1.0, 3) if metric.startswith("iou") else (1.0, 2))
            cells.append(f"{d['mean'] * scale:+.{digits}f} [{d['low'] * scale:+.{digits}f}, "
                         f"{d['high'] * scale:+.{digits}f}] {d['ratio']:+.1%} {d['better']}/{d['worse']}/"
                         f"{d['tied']}")
        text += f"| {name} | " + " | ".join(cells) + " |\n"
    return text, paired


def _table(rows: dict[str, list[dict]], steps: int, references: tuple[str, ...] = (REFERENCE_ROW,)
           ) -> tuple[str, dict]:
    summaries = {name: row_summary(episodes, steps) for name, episodes in rows.items()}
    checkpoints = [n for n in CHECKPOINTS if n <= steps]
    cov_cols = [f"coverage@{n}" for n in checkpoints] + ["auc_first_half", "auc"]
    dead_ends = [m for m in DEAD_END_METRICS if any(m in summary for summary in summaries.values())]
    sizes = {name: len(episodes) for name, episodes in rows.items()}
    uneven = len(set(sizes.values())) > 1
    lines = ["| row | what | " + ("scenarios | " if uneven else "") + " | ".join(cov_cols)
             + " | LOS only: auc_first_half | "
             + " | ".join(f"IoU@{int(100 * lv)}%" for lv in IOU_LEVELS) + " | "
             + " | ".join(f"IoU {int(100 * a)}-{int(100 * b)}%" for a, b in IOU_BINS)
             + " | scoring ms / goal | prediction ms / goal |"
             + "".join(f" {m.replace('_', ' ')} / scenario |" for m in dead_ends),
             "|---|---|" + "---:|" * (len(cov_cols) + 3 + len(IOU_LEVELS) + len(IOU_BINS) + uneven
                                      + len(dead_ends))]
    for name, summary in summaries.items():
        cells = [str(sizes[name])] if uneven else []
        cells += [_percent(summary[c]) for c in cov_cols] + [_percent(summary["los_auc_first_half"])]
        cells += [f"{summary[f'iou@{lv:.2f}']:.3f}" for lv in IOU_LEVELS]
        cells += [f"{summary[f'iou_bin_{a:.1f}_{b:.1f}']:.3f}" for a, b in IOU_BINS]
        cells += [f"{summary.get(f'{stage}_ms_per_goal', float('nan')):.1f}" for stage in ("scoring", "prediction")]
        cells += [f"{summary.get(m, float('nan')):.2f}" for m in dead_ends]
        lines.append(f"| {name} | {PIPELINES[name].label} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    metrics = ["auc_first_half", "auc"] + [f"coverage@{n}" for n in checkpoints] + [
        f"iou@{lv:.2f}" for lv in IOU_LEVELS] + [f"iou_bin_{a:.1f}_{b:.1f}" for a, b in IOU_BINS] + dead_ends
    paired = {}
    for reference in references:
        if reference in rows and len(rows) > 1:
            more, paired[reference] = _paired_lines(rows, reference, steps, metrics)
            text += more
    out = {"summary": summaries, "scenarios": sizes,
           "paired_vs_reference": paired.get(REFERENCE_ROW, {}), "reference": REFERENCE_ROW}
    if len(references) > 1:
        out["paired"] = paired
    return text, out


def _floors_text(floors: list[dict]) -> str:
    """One sentence on the altered floors: how many scenarios hold dead ends, of what kind and length."""
    made = [a for floor in floors for a in floor["alterations"]]
    kinds = {kind: sum(a["kind"] == kind for a in made) for kind in ("corridor", "room", "door")}
    text = (f"Altered floors (seed per scenario {{}}): {sum(bool(f['alterations']) for f in floors)} of {len(floors)} "
            f"scenarios hold a dead end, {len(made)} dead ends in all ({kinds['corridor']} debris across a corridor, "
            f"{kinds['room']} rooms split, {kinds['door']} doors closed)")
    if made:
        text += (f", median {np.median([a['length_m'] for a in made]):.1f} m long, hidden for the first "
                 f"{np.median([a['hidden_m'] for a in made]):.1f} m driven in (median); the start reaches "
                 f"{100 * min(f['kept_fraction'] for f in floors):.0f}-{100 * max(f['kept_fraction'] for f in floors):.0f} "
                 f"% of the unaltered floor's robot cells")
    return text + ". Coverage is of each altered floor's valid area (what the robot reaches).\n\n"


def run_paper(args: argparse.Namespace) -> int:
    from superex_deploy.parallel import Interrupted
    from superex_deploy.render import save_suite_plots

    names = _rows(args.rows)
    if args.planner_option:
        raise ValueError(f"--planner-option does not apply to --suite {args.suite}: its rows fix their planners' "
                         f"settings")
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    check_jobs(args)
    maps = eval_maps(args.maps)
    check_output_folder(args.out)
    backend = make_backend(args)
    rows_dir = args.out / "rows"
    rows_dir.mkdir(parents=True, exist_ok=True)
    setting = {"maps": maps, "steps": args.steps, "seed": args.seed, "iou": IOU_SCHEDULE}
    references: tuple[str, ...] = (REFERENCE_ROW,)
    floors_text = ""
    if args.suite == "altered":
        from dataclasses import asdict

        from superex_deploy.sim.altered_floors import ALTERATION_SEED_RULE
        from superex_deploy.sim.alterations import AlterationConfig

        setting["alteration"] = {"seed": ALTERATION_SEED_RULE, "config": asdict(AlterationConfig())}
        references = (REFERENCE_ROW, CEILING_REFERENCE)
        try:
            floors = _make_floors(maps, args.out, backend)
        except Interrupted as stop:
            stop.kept = f"the finished floors are in {args.out / 'floors'}: rerun the same command to finish"
            raise
        write_atomically(args.out / "floors.json", json.dumps(floors, indent=1))
        floors_text = _floors_text(floors).replace("{}", f"`{ALTERATION_SEED_RULE}`")
    for name in names:
        path, row_setting = rows_dir / f"{name}.json", _row_setting(setting, name)
        if path.is_file():
            done = json.loads(path.read_text()).get("setting")
            if done == row_setting:
                print(f"{name}: done already ({path})")
                continue
            _refuse_other_settings(path, done, row_setting, "move it away or choose another --out")
        try:
            episodes = _run_row(name, args, maps, rows_dir, row_setting, backend)
        except Interrupted as stop:
            stop.kept = (f"the finished episodes of row {name} are in {rows_dir / (name + '.episodes.jsonl')}: rerun "
                         f"the same command to finish")
            raise
        write_atomically(path, json.dumps({"row": name, "setting": row_setting, "episodes": episodes}))
    rows = {}
    for name in PIPELINES:  # every finished row of this protocol (perhaps on fewer maps), in the table's order
        path = rows_dir / f"{name}.json"
        if path.is_file():
            done = json.loads(path.read_text())
            if _same_protocol(done.get("setting"), _row_setting(setting, name)):
                rows[name] = done["episodes"]
    text, summary = _table(rows, args.steps, references)
    sizes = sorted(set(summary["scenarios"].values()))
    header = (f"{len(maps)} maps, {'/'.join(map(str, sizes))} scenarios, {args.steps} steps, seed {args.seed}. "
              f"{floors_text}Coverage: % of the valid area known, NLOS-carved cells included (LOS only: without them); "
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
