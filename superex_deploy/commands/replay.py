"""``superex replay FILE --out DIR``: rerun a fresh explorer on a recorded episode's observations alone.

The explorer is rebuilt from the recording's metadata (the planner's configuration, predictor, seed, sensor model,
NLOS and explorer configuration) and given no map: it sees exactly the recorded observations. A recording made before
the planner's whole configuration was recorded holds the options given: the other fields are rebuilt at the defaults
of its version (:mod:`~superex_deploy.commands.recorded_config`). Its goals are compared with the recorded commands
step by step. Writes ``DIR/metrics.json`` (goals, per-stage timings, the comparison, anything that stopped the
reading, the final map frame) and ``DIR/map.npz`` (the explorer's final map and evidence, and its frame: ``shape``,
``resolution_m``, ``origin_xy``; a map that grows ends on a larger frame than the recording's first). A recording
without a single whole step is refused: there is nothing to compare. With ``--live`` the replayed steps are served
on a Foxglove WebSocket as they run (:mod:`superex_deploy.recording.live`), at the recording's stamps unless
``--live-pace`` says otherwise, and the last one ``--live-hold`` seconds more.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.commands.options import add_live_options
from superex_deploy.files import write_atomically
from superex_deploy.recording.live import live_view


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="an .mcap file written by `superex explore --record`")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--models", type=Path, default=None,
                        help="folder of exported models (default: the recording's, else the repository's exported/)")
    add_live_options(parser)


def explorer_arguments(metadata: dict, frame, models=None) -> dict:
    """The keyword arguments of :func:`superex_deploy.pipeline.build_explorer` that rebuild the explorer a
    recording's metadata describes on ``frame`` (the recording's first map frame, included as ``frame``): its
    planner (a Planner instance), predictor name, profile, SPAD sensor model and processing, ``models`` (default:
    the recording's), seed and explorer configuration. ``build_explorer(**explorer_arguments(metadata, frame))``.

    Raises:
        ValueError: metadata that names no planner or predictor, the oracle predictor (it reads the truth), or
            configurations this package cannot build.
    """
    from superex_deploy import pipeline
    from superex_deploy.onboard.prediction.registry import kind_of
    from superex_deploy.onboard.planning.motion import MotionConfig
    from superex_deploy.onboard.checks import from_cells, nested_configs, without_retired
    from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
    from superex_deploy.onboard.planning.planners import make_planner, planner_config
    from superex_deploy.onboard.nlos import NlosConfig
    from superex_deploy.onboard import ExplorerConfig, PredictionReuse, PredictionSchedule
    from superex_deploy.spad_types import SpadConfig, SpadNoise
    from superex_deploy.commands.recorded_config import previous_planner_options, recorded_explorer_fields

    try:
        planner_name, predictor_name = metadata["planner"], metadata["predictor"]
        options, seed = metadata.get("planner_options") or {}, int(metadata["seed"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"the recording's metadata lacks the planner, predictor or seed ({error})") from None
    if kind_of(predictor_name).reads_truth:
        raise ValueError(f"the recording used the {predictor_name} predictor, which reads the ground truth: it cannot "
                         f"be replayed")
    models = models or metadata.get("models")
    profile_name = metadata.get("profile", "full")
    if profile_name not in pipeline.PROFILES:
        raise ValueError(f"the recording used the profile {profile_name!r}, which this version does not have "
                         f"({', '.join(pipeline.PROFILES)})")
    profile = pipeline.PROFILES[profile_name]
    if "profile_settings" in metadata and _settings_as_now(metadata["profile_settings"], frame.resolution_m) \
            != profile.to_json():
        raise ValueError(f"the recording's profile {profile_name!r} was defined differently when it was recorded "
                         f"({metadata['profile_settings']}) than in this version ({profile.to_json()}): "
                         "a replay would not rebuild its explorer")
    if isinstance(metadata["seed"], bool) or seed != metadata["seed"] or seed < 0:
        raise ValueError(f"the recording's seed must be an integer >= 0, got {metadata['seed']!r}")
    try:
        # The planner's whole configuration as recorded; a recording made before it was recorded holds the options
        # given, the other fields at the defaults of its version (those that changed since: PREVIOUS_DEFAULTS).
        # A recording made before an option was retired carries it at its old default (accepted) or at another
        # value (refused, named); one made before an option counted metres carries cells (converted).
        if "planner_config" in metadata:
            options = metadata["planner_config"]
        elif isinstance(options, dict):
            options = previous_planner_options(planner_name, options)
        config = planner_config(planner_name)
        if config is not None and isinstance(options, dict):
            options = nested_configs(config, without_retired(config, from_cells(config, options, frame.resolution_m)))
        planner = make_planner(planner_name, **options)
    except ValueError as error:
        raise ValueError(f"the recording's planner or predictor cannot be rebuilt: {error}") from None
    try:
        # A recording made before the settings counted in metres carries cell counts: converted with its grid.
        explorer_fields = from_cells(ExplorerConfig, recorded_explorer_fields(metadata["explorer"]),
                                     frame.resolution_m)
        schedule = PredictionSchedule.from_json(explorer_fields.pop("prediction", {}))
        reuse = PredictionReuse(**from_cells(PredictionReuse, explorer_fields.pop("reuse", {}), frame.resolution_m))
        if isinstance(explorer_fields.get("scan_matching"), dict):
            explorer_fields["scan_matching"] = without_retired(ScanMatchingConfig, from_cells(
                ScanMatchingConfig, explorer_fields["scan_matching"], frame.resolution_m))
        motion = MotionConfig(**from_cells(MotionConfig, explorer_fields.pop("motion"), frame.resolution_m))
        cfg = ExplorerConfig(motion=motion, prediction=schedule, reuse=reuse, **explorer_fields)
        sensor = nlos_cfg = None
        if metadata.get("spad"):
            sensor = dict(metadata["sensor"])
            sensor = SpadConfig(**{**sensor, "noise": SpadNoise(**sensor["noise"])})
            nlos_cfg = NlosConfig.from_recorded(dict(metadata["nlos"]), frame.resolution_m)
    except KeyError as error:
        raise ValueError(f"the recording's configuration cannot be rebuilt: it lacks the field {error}") from None
    except (TypeError, ValueError) as error:
        raise ValueError(f"the recording's configuration cannot be rebuilt: a field has the wrong type or value "
                         f"({error})") from None
    return dict(frame=frame, planner=planner, predictor=predictor_name, profile=profile_name,
                spad=bool(metadata.get("spad")), models=models, seed=seed, cfg=cfg, sensor=sensor, nlos_cfg=nlos_cfg)


def _settings_as_now(settings, resolution_m: float):
    """A recording's profile settings in this version's form: a schedule written before the schedule's modes
    converted (``PredictionSchedule.from_json``), reuse counts of cells converted to square metres on the
    recording's grid of ``resolution_m`` metres per cell, fields added since filled in with their defaults (the
    values that behave as the version before them did)."""
    from dataclasses import asdict

    from superex_deploy.onboard import PredictionReuse, PredictionSchedule
    from superex_deploy.onboard.checks import from_cells
    from superex_deploy.pipeline import RealtimeProfile

    if not isinstance(settings, dict):
        return settings
    settings = {**RealtimeProfile().to_json(), **settings}
    for key in ("schedule", "simulated_schedule"):
        if isinstance(settings[key], dict):
            try:
                settings[key] = asdict(PredictionSchedule.from_json(settings[key]))
            except (TypeError, ValueError):
                pass  # left as recorded: it differs from this version's, which the caller reports
    if isinstance(settings["reuse"], dict):
        try:
            settings["reuse"] = from_cells(PredictionReuse, settings["reuse"], resolution_m)
        except ValueError:
            pass  # as above
    return settings


def run(args: argparse.Namespace) -> int:
    from superex_deploy.commands.options import check_output_folder
    from superex_deploy.pipeline import build_explorer
    from superex_deploy.recording import read_recording

    check_output_folder(args.out)
    recording = read_recording(args.recording, progress=True)
    if not recording.steps:
        why = recording.error or "a recording stopped before its first step"
        raise ValueError(f"{args.recording} holds no step to replay ({why})")
    if recording.error is not None:
        print(f"superex replay: warning: {recording.error}")
    arguments = explorer_arguments(recording.metadata, recording.frame, args.models)
    try:
        explorer = build_explorer(**arguments)
    except ValueError as error:
        raise ValueError(f"the recording's planner or predictor cannot be rebuilt: {error}") from None
    with explorer, live_view(args.live, args.live_every, "superex replay", pace_hz=args.live_pace,
                             hold_s=args.live_hold) as live:
        if explorer.scheduled is not None:
            # The predictions land where they landed in the recorded run (a never-waiting run: when its CPU had
            # finished them), computed inline, so that the replay is exact on any machine.
            explorer.follow_recorded_predictions([recorded.prediction_step for recorded in recording.steps])
        return _replay(args, recording, explorer, live)


def _replay(args, recording, explorer, live) -> int:
    from tqdm import tqdm

    from superex_deploy.onboard import STAGES

    goals, goal_steps, mismatches = [], [], []
    timings = {stage: [] for stage in STAGES}
    finished, status_reason = False, ("", "")
    for recorded in tqdm(recording.steps, desc=f"replay {args.recording.name}", unit="step"):
        command = explorer.step(recorded.observation)
        if live is not None:
            live.publish(recorded.observation, command, explorer)
        for stage in STAGES:
            timings[stage].append(command.timings_s[stage])
        if command.new_goal:
            goals.append(list(command.goal_rc))
            goal_steps.append(command.step)
        # A recording made before commands carried a status compares the goals and flags alone.
        status = (command.status, command.reason) if recorded.status is not None else (None, None)
        if (command.goal_rc, command.new_goal, command.finished, *status) != (
                recorded.goal_rc, recorded.new_goal, recorded.finished, recorded.status, recorded.reason):
            mismatches.append({"step": recorded.step, "recorded": recorded.goal_rc, "replayed": command.goal_rc,
                               **({"recorded_status": recorded.status, "replayed_status": command.status}
                                  if status != (recorded.status, recorded.reason) else {})})
        finished, status_reason = command.finished, (command.status, command.reason)
    per_stage = {stage: {"mean": float(np.mean(v)) if v else 0.0, "p50": float(np.median(v)) if v else 0.0,
                         "p99": float(np.percentile(v, 99)) if v else 0.0} for stage, v in timings.items()}
    step_total = np.sum([timings[stage] for stage in STAGES], axis=0) if recording.steps else np.zeros(0)
    metrics = {"recording": str(args.recording), "metadata": recording.metadata, "steps": len(recording.steps),
               "finished": finished, "status": status_reason[0], "reason": status_reason[1],
               "goals": {"steps": goal_steps, "cells": goals},
               "goals_match": not mismatches, "mismatches": mismatches[:20], "read_error": recording.error,
               "known_cells": int(explorer.mapper.known().sum()),
               "frame": {"shape": list(explorer.frame.shape), "resolution_m": explorer.frame.resolution_m,
                         "origin_xy": list(explorer.frame.origin_xy)},
               "step_s": {"mean": float(step_total.mean()) if step_total.size else 0.0,
                          "p50": float(np.median(step_total)) if step_total.size else 0.0,
                          "p99": float(np.percentile(step_total, 99)) if step_total.size else 0.0},
               "stage_s": per_stage}
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomically(args.out / "metrics.json", json.dumps(metrics))
    evidence = explorer.evidence if explorer.evidence is not None else np.zeros(0, np.float32)
    frame = explorer.frame  # the final grid's: a map that grows ends on another frame than the recording's first

    def save_map(part: Path) -> None:
        with open(part, "wb") as file:
            np.savez_compressed(file, observed=explorer.observed, carved=explorer.mapper.carved, evidence=evidence,
                                shape=np.asarray(frame.shape), resolution_m=frame.resolution_m,
                                origin_xy=np.asarray(frame.origin_xy))

    write_atomically(args.out / "map.npz", save_map)
    verdict = "goals match the recording" if not mismatches else f"{len(mismatches)} steps differ from the recording"
    print(f"replayed {len(recording.steps)} steps of {args.recording}: {len(goals)} goals, {verdict}")
    print(f"wrote {args.out / 'metrics.json'}, {args.out / 'map.npz'}")
    return 0 if not mismatches and recording.error is None else 1
