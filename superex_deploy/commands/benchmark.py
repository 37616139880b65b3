"""``superex benchmark``: every start pose of a set of maps x planners, in parallel processes.

``--suite paper`` runs the paper's table instead (``--suite altered``: on altered eval floors, see
:mod:`superex_deploy.commands.paper_benchmark`): the named pipelines of :data:`~superex_deploy.pipeline.PIPELINES`
(planner x predictor x sensing) on the 40 eval scenarios, each row written to ``OUT/rows/ROW.json`` as soon as it
is done (a rerun skips the rows already there), then the summary paired by scenario against MapEx on LaMa-LOS:
``results.md``, ``results.json``, ``coverage.png``, ``iou_vs_coverage.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from superex_deploy.evaluation.tasks import ScenarioTask, run_scenario
from superex_deploy.commands.options import (add_noise_options, add_parallel_options, add_planner_option,
                                             add_profile_option, check_jobs, check_output_folder, eval_maps,
                                             make_backend, name_list, noise_options,
                                             non_negative_int, planner_options, predictor_help,
                                             settings_differences)
from superex_deploy.onboard.planning.planners import PLANNERS
from superex_deploy.onboard.prediction.registry import kind_of
from superex_deploy.pipeline import PREDICTORS
from superex_deploy.files import write_atomically
from superex_deploy.spad_types import SpadConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--maps", type=name_list, default="eval",
                        help="'eval', or comma-separated bundled eval map names")
    parser.add_argument("--planners", type=name_list, default=",".join(PLANNERS),
                        help="comma-separated planner names (default: every planner, this project's superex "
                             "included)")
    add_planner_option(parser)
    parser.add_argument("--predictor", default="observed", choices=tuple(PREDICTORS), help=predictor_help())
    parser.add_argument("--spad", action="store_true",
                        help=f"simulate the SPAD LiDAR every step ({SpadConfig.n_rays} rays, {SpadConfig.n_secondary} "
                             "secondary rays per wall hit): NLOS carving and back-projection evidence")
    parser.add_argument("--steps", type=int, default=1000)
    add_profile_option(parser)
    add_noise_options(parser)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    add_parallel_options(parser)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out: skip the episodes OUT/episodes.jsonl already holds (the "
                             "settings must be the same)")
    parser.add_argument("--suite", choices=("paper", "altered"), default=None,
                        help="paper: the paper's rows (see --rows), IoU every 10 steps up to 35 %% coverage, "
                             "paired against MapEx on LaMa-LOS, always with the full profile (the table measures models and "
                             "planners); --planners / --predictor / --spad / --profile are ignored. altered: the same "
                             "on the eval floors altered with a fixed seed per scenario (dead ends hidden behind a "
                             "turn), with the dead-end entries, also paired against MapEx on the observed map")
    parser.add_argument("--rows", type=name_list, default="all",
                        help="with --suite paper or altered: comma-separated row names, or 'all'")


def prepare_output(out: Path, settings: dict, resume: bool) -> Path:
    """Check (or create) the output folder of a resumable run and return its journal, ``OUT/episodes.jsonl``.

    ``OUT/settings.json`` records the run's settings; a folder that holds episodes of another run is refused (the
    error names the settings that differ, with their recorded and new values), and one that holds episodes of
    this run only with ``resume``. A folder whose journal holds no episode has nothing to lose: it is reused.
    What the episodes ran is compared: where both settings hold the planners' whole configurations
    (``planner_configs``), the options that gave them (``planner_options``) may differ.

    Raises:
        ValueError: ``out`` is a file, holds episodes of other settings, or holds episodes without ``resume``.
    """
    from superex_deploy.parallel import read_journal

    check_output_folder(out)
    journal, recorded = out / "episodes.jsonl", out / "settings.json"
    if read_journal(journal):
        if not recorded.is_file():
            raise ValueError(f"{journal} has no settings.json beside it: its settings cannot be checked; choose "
                             f"another --out")
        old, new = json.loads(recorded.read_text()), json.loads(json.dumps(settings))
        differences = settings_differences(_what_ran(old), _what_ran(new))
        if differences:
            before = ("; its settings.json was written by a version before 0.2, before the settings held the "
                      "planners' and the sensing's configurations: finish it with that version"
                      if isinstance(old, dict) and "planner_configs" in new and "planner_configs" not in old else "")
            raise ValueError(f"{out} holds a run with other settings ({'; '.join(differences)}){before}; choose "
                             f"another --out, or rerun with its settings")
        if not resume:
            raise ValueError(f"{out} already holds a run ({journal}): pass --resume to finish it, or choose another "
                             f"--out")
    out.mkdir(parents=True, exist_ok=True)
    write_atomically(recorded, json.dumps(settings))
    return journal


def _what_ran(settings):
    """``settings`` without the options given where the planners' whole configurations are there (those say what
    ran: an option given at its default runs as one left out)."""
    if isinstance(settings, dict) and "planner_configs" in settings:
        return {key: value for key, value in settings.items() if key != "planner_options"}
    return settings


def run(args: argparse.Namespace) -> int:
    noise = noise_options(args)
    if args.suite in ("paper", "altered"):
        from superex_deploy.commands.paper_benchmark import run_paper

        if noise.on:
            raise ValueError(f"--suite {args.suite} runs the paper's noise-free protocol: drop --pose-noise, "
                             f"--lidar-noise and --spad-noise (or run without --suite)")

        return run_paper(args)
    from superex_deploy.evaluation.metrics import MAP_ERROR_KEYS
    from superex_deploy.evaluation.summary import summary_markdown, summary_table
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.maps import start_poses
    from superex_deploy.parallel import Interrupted, read_journal, run_tasks
    from superex_deploy.render import save_benchmark_plots

    names = eval_maps(args.maps)
    check_output_folder(args.out)
    planners = list(args.planners)
    unknown = [p for p in planners if p not in PLANNERS]
    if unknown:
        raise ValueError(f"unknown planner(s) {unknown}; choose from {', '.join(sorted(PLANNERS))}")
    check_jobs(args)
    if kind_of(args.predictor).reads_evidence and not args.spad:
        raise ValueError(f"--predictor {args.predictor} reads the SPAD evidence: add --spad")
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    options = planner_options(args.planner_option)
    from superex_deploy.pipeline import PROFILES, check_profile, resolve_profile

    instances = [make_planner(planner, **options) for planner in planners]  # a bad option fails here
    # One profile for the whole run, so that the planners are compared on the same pipeline: the default where every
    # planner can use it, else full.
    resolved = {resolve_profile(args.profile, instance, args.predictor) for instance in instances}
    profile_name = resolved.pop() if len(resolved) == 1 else "full"
    for instance in instances:
        check_profile(profile_name, instance, args.predictor)
    tasks = [ScenarioTask(map_name=name, start_index=k, start_rc=pose, planner=planner, predictor=args.predictor,
                          spad=args.spad, steps=args.steps, seed=args.seed, planner_options=options, iou_every=50,
                          profile=profile_name, noise=noise)
             for name in names for k, pose in enumerate(start_poses(name)) for planner in planners]
    keys = [f"{task.map_name}/{task.start_index}/{task.planner}" for task in tasks]
    from superex_deploy.evaluation.tasks import default_sensing_settings
    from superex_deploy.recording.metadata import planner_settings

    configs = {planner: planner_settings(instance) for planner, instance in zip(planners, instances)}
    settings = {"maps": names, "planners": planners, "planner_options": options, "planner_configs": configs,
                "predictor": args.predictor, "spad": args.spad,
                "sensing": default_sensing_settings(noise.spad) if args.spad else None,
                "steps": args.steps, "seed": args.seed, "profile": profile_name,
                "profile_settings": PROFILES[profile_name].to_json(), **noise.settings()}
    backend = make_backend(args)
    journal = prepare_output(args.out, settings, args.resume)
    try:
        results = run_tasks(run_scenario, tasks, keys, backend, journal, "episodes")
    except Interrupted as stop:
        stop.kept = (f"{len(read_journal(journal))} of {len(tasks)} episodes are in {journal}: rerun with --resume "
                     f"to finish")
        raise
    noisy = noise.settings()
    extra = ("path_length_m",) + (MAP_ERROR_KEYS if noisy else ())
    table = summary_table(results, args.steps, extra=extra)
    write_atomically(args.out / "results.json", json.dumps({"episodes": results, "summary": table,
                                                          "planner_options": options, "planner_configs": configs}))
    columns = [key for key in table[0] if key.startswith(("coverage@", "los_coverage@"))] if table else []
    table_text = summary_markdown(table, columns + ["auc_first_half", "auc", "final_iou", *extra])
    settings = "".join(f", {k}={v}" for k, v in options.items())
    write_atomically(
        args.out / "results.md",
        f"Predictor: {args.predictor}{', SPAD sensing' if args.spad else ''}{settings}, profile {profile_name}; "
        f"{''.join(f'{key} {value}, ' for key, value in noisy.items())}"
        f"{len(names)} maps, "
        f"{len(tasks) // max(len(planners), 1)} scenarios, {args.steps} steps, seed {args.seed}. Mean over "
        f"scenarios [bootstrap 95 % interval]; coverage in percent of the valid area, counting NLOS-carved cells "
        f"(los_: line of sight only); auc_first_half, auc: mean coverage over the first half of the steps, over all "
        f"of them; final_iou: the prediction's map IoU at the last evaluation; path_length_m: metres driven.\n\n"
        f"{table_text}")
    save_benchmark_plots(args.out, results)
    print(table_text)
    print(f"wrote {args.out / 'results.md'}, results.json, coverage.png, iou_vs_coverage.png")
    return 0
