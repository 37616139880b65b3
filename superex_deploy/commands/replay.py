"""``superex replay FILE --out DIR``: rerun a fresh explorer on a recorded episode's observations alone.

The explorer is rebuilt from the recording's metadata (the planner's configuration, predictor, seed, sensor model,
NLOS and explorer configuration, each read by its class's strict ``from_json``:
:func:`~superex_deploy.recording.metadata.explorer_arguments`) and given no map: it sees exactly the recorded
observations. A recording of an earlier format is refused, naming ``superex convert-recording``, which rewrites it.
Its goals are compared with the recorded commands step by step. Writes ``DIR/metrics.json`` (goals, per-stage
timings, the comparison, anything that stopped the reading, the final map frame) and ``DIR/map.npz`` (the explorer's final map and evidence, and its frame: ``shape``,
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


def run(args: argparse.Namespace) -> int:
    from superex_deploy.commands.options import check_output_folder
    from superex_deploy.pipeline import build_explorer
    from superex_deploy.recording import read_recording
    from superex_deploy.recording.metadata import explorer_arguments

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
