"""``superex explore``: one exploration episode of a named pipeline (``--pipeline``, default ``superex``: the superex
planner on the LaMa-BP ensemble with SPAD sensing, the realtime profile; ``--planner``, ``--predictor``, ``--spad``
and ``--profile`` override its parts), written as metrics.json, final.png and episode.gif; with ``--live``
also served while it runs on a Foxglove WebSocket (:mod:`superex_deploy.recording.live`), paced for a viewer (at the
simulated sensor's 10 Hz unless ``--live-pace`` says otherwise), its last state served ``--live-hold`` seconds more
after the outputs are written (Ctrl-C ends that), and stopped however the run ends, without waiting for a client that
stopped reading.

Stopped by SIGINT or SIGTERM, it keeps what the steps done so far hold: ``metrics.json`` with their series, marked
``"interrupted": "SIGINT"`` (or ``"SIGTERM"``), and with ``--record`` a valid recording of every whole step, which
``superex replay`` reads like any other.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from superex_deploy.commands.options import (add_live_options, add_noise_options, add_planner_option,
                                             add_profile_option, bounds_polygon, check_output_file,
                                             check_output_folder, folders_made, load_floor,
                                             noise_options, non_negative_int, planner_options,
                                             predictor_help, resolve_start)
from superex_deploy.onboard.planning.planners import PLANNERS
from superex_deploy.onboard.prediction.registry import kind_of
from superex_deploy.pipeline import (DEFAULT_PIPELINE, PIPELINES, PREDICTORS, build_explorer,
                                     check_profile, make_sensing, resolve_profile)
from superex_deploy.recording.live import live_view
from superex_deploy.spad_types import SpadConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--map", required=True, help="bundled map name or an image / ROS YAML path")
    parser.add_argument("--start", type=non_negative_int, default=0,
                        help="index of the eval map's start pose (0-3); a map file or a train map needs --pose")
    parser.add_argument("--pose", type=int, nargs=2, metavar=("ROW", "COL"), help="start cell instead of --start")
    parser.add_argument("--pipeline", default=DEFAULT_PIPELINE, choices=tuple(PIPELINES), metavar="NAME",
                        help="the named pipeline to run (superex_deploy.pipeline.PIPELINES: its planner, predictor, "
                             f"SPAD sensing and profile; --planner, --predictor, --spad / --no-spad and --profile "
                             f"override its parts): {', '.join(PIPELINES)}. Default: {DEFAULT_PIPELINE} (the superex "
                             "planner on the LaMa-BP ensemble with SPAD carving and Pix2Pix evidence, the realtime "
                             "profile); nearest: the nearest frontier on the observed map")
    parser.add_argument("--planner", default=None,
                        help=f"{' | '.join(PLANNERS)} (default: the pipeline's)")
    add_planner_option(parser)
    parser.add_argument("--predictor", default=None, choices=tuple(PREDICTORS),
                        help=f"{predictor_help()}. Default: the pipeline's")
    parser.add_argument("--models", type=Path, default=None,
                        help="folder of exported models with manifest.json (default: the repository's exported/)")
    parser.add_argument("--resolution", type=float, default=None, metavar="METRES",
                        help="the floor's cell size: a bundled floor (0.1 m) at 0.1 / K (K = 2..4: upsampled, a SLAM "
                             "grid, its start cell scaled), an image at this many metres per pixel (default: the "
                             "map's own)")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--spad", action=argparse.BooleanOptionalAction, default=None,
                        help=f"also scan with the SPAD LiDAR every step ({SpadConfig.n_rays} rays, "
                             f"{SpadConfig.n_secondary} secondary rays per wall hit) and merge its carved free space "
                             "(coverage is reported with and without carving); --no-spad: line of sight only. "
                             "Default: the pipeline's")
    parser.add_argument("--gif-every", type=non_negative_int, default=5,
                        help="record a GIF frame every N steps; 0: no GIF (episode.gif is not written)")
    parser.add_argument("--record", type=Path, default=None, metavar="FILE",
                        help="also write every observation and command to this MCAP file (ROS 2 messages; "
                             "`superex replay FILE` reruns the explorer on it); its folder must exist or be --out")
    parser.add_argument("--bounds", type=bounds_polygon, default=None, metavar='"X,Y X,Y X,Y ..."',
                        help="explore only inside this polygon (map-frame metres, at least 3 corners, quoted): "
                             "frontiers outside it are ignored, coverage is also reported inside it, and the episode "
                             "ends when no reachable frontier is left inside; it must contain the start")
    parser.add_argument("--return-to-start", action="store_true",
                        help="once exploration is finished, drive back to the start before ending the episode")
    add_profile_option(parser)
    add_noise_options(parser)
    add_live_options(parser)
    parser.add_argument("--out", required=True, type=Path)


def chosen_pipeline(args: argparse.Namespace, options: dict):
    """The named pipeline ``args.pipeline`` (:data:`~superex_deploy.pipeline.PIPELINES`) with the parts the command
    line gives in place of its own: fills ``args.planner``, ``args.predictor`` and ``args.spad`` left out (None)
    with the pipeline's, and ``args.profile`` with its profile where the planner and predictor are its own, else
    with :func:`~superex_deploy.pipeline.resolve_profile`'s for them (the default profile where the planner can use
    it, ``full`` where it reads the ensemble's variance). Returns ``(pipeline, planner)``: the table's entry and the
    planner made with ``options`` (``--planner-option``).

    Raises:
        ValueError: an unknown planner, an option it does not have.
    """
    from superex_deploy.onboard.planning.planners import make_planner

    pipeline = PIPELINES[args.pipeline]
    args.planner = pipeline.planner if args.planner is None else args.planner
    args.predictor = pipeline.predictor if args.predictor is None else args.predictor
    args.spad = pipeline.spad if args.spad is None else bool(args.spad)
    planner = make_planner(args.planner, **options)
    if args.profile is None:
        own = (args.planner, args.predictor) == (pipeline.planner, pipeline.predictor)
        args.profile = pipeline.profile if own else resolve_profile(None, planner, args.predictor)
    return pipeline, planner


def with_operations(cfg, bounds, return_to_start: bool):
    """The episode config ``cfg`` with the explorer's exploration ``bounds`` (an
    :class:`~superex_deploy.onboard.planning.bounds.ExplorationBounds` or None) and ``return_to_start`` (``cfg``
    itself where neither is set: a run without them is configured as before)."""
    if bounds is None and not return_to_start:
        return cfg
    from dataclasses import replace

    return replace(cfg, explorer=replace(cfg.explorer, bounds=bounds, return_to_start=bool(return_to_start)))


def summary_line(result) -> str:
    """The one line ``superex explore`` ends with: the last command's status and reason, the steps, the coverage
    (and the coverage inside the bounds, where set)."""
    coverage = result.coverage[-1] if len(result.coverage) else 0.0
    inside = "" if result.coverage_in_bounds is None or not len(result.coverage_in_bounds) else \
        f", coverage inside the bounds {result.coverage_in_bounds[-1]:.1%}"
    reason = f" ({result.reason})" if result.reason else ""
    return f"status {result.status}{reason}: {result.steps} steps, coverage {coverage:.1%}{inside}"


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from superex_deploy.messages import MapFrame

    # Every check first: nothing is created before the last of them.
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    options = planner_options(args.planner_option)
    pipeline, planner = chosen_pipeline(args, options)  # before the noise: --spad-noise needs the SPAD
    noise = noise_options(args).seeded(args.seed)
    check_output_folder(args.out)
    if args.record is not None:
        check_output_file(args.record, "--record", made=folders_made(args.out))
    grid, start = load_floor(args.map, args.resolution, args.start, args.pose, seed=args.seed,
                             command="superex explore")
    profile = check_profile(args.profile, planner, args.predictor)
    sensing = noise.sensing(make_sensing(args.predictor, args.spad, args.seed, args.models, profile))
    if sensing is not None and not pipeline.carving:  # the ablation without carving: the evidence as with it
        if args.record is not None:
            raise ValueError(f"--record: the {pipeline.name} pipeline turns the carving off, which a replay does not "
                             f"rerun; record another pipeline")
        sensing = replace(sensing, skips=replace(sensing.skips, carving=True))
    cfg = noise.episode_config(profile.episode_config(clock="robot"))
    cfg = with_operations(cfg, args.bounds, args.return_to_start)
    if args.bounds is not None:  # the start inside the polygon, before anything is created
        args.bounds.check_contains(*MapFrame(grid.shape, grid.resolution_m).centre_xy(start))
    if args.record is not None and kind_of(args.predictor).reads_truth:
        raise ValueError(f"--record: the {args.predictor} predictor reads the ground truth, so no replay could rerun "
                         f"it; record with another predictor")
    # The last check (a port in use); the episode runs paced (--live-pace), and the hold (--live-hold) comes after
    # its outputs are written.
    with live_view(args.live, args.live_every, "superex explore", pace_hz=args.live_pace,
                   hold_s=args.live_hold) as live:
        return _explore(args, grid, start, options, planner, sensing, cfg, noise, live)


def _explore(args, grid, start, options, planner, sensing, cfg, noise, live) -> int:
    """The episode and its outputs, after every check."""
    from superex_deploy.messages import MapFrame
    from superex_deploy.recording import EpisodeRecorder
    from superex_deploy.recording.metadata import recording_metadata
    from superex_deploy.render import GifRecorder

    # The robot's clock: a step never waits for the predictor (a recording keeps when each prediction landed, and a
    # replay follows it); the sessions get the worker's share of this machine's cores.
    from superex_deploy.onboard.prediction.inference import available_cores

    explorer = build_explorer(MapFrame(grid.shape, grid.resolution_m), planner, args.predictor, profile=args.profile,
                              cores=available_cores(), spad=False if sensing is None else sensing.processing(),
                              models=args.models, seed=args.seed, cfg=cfg.explorer, grid=grid)
    from superex_deploy.commands.warmup import numba_cache_is_warm

    if args.spad and not numba_cache_is_warm():  # the SPAD kernels are the slow ones to compile
        print("superex explore: first run here: compiling the numba kernels (about half a minute, once; numba caches "
              "them; `superex warmup` does it ahead)", file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    gif = GifRecorder(every=args.gif_every) if args.gif_every else None
    done = _StepsDone()
    record = None
    try:
        if args.record is not None:
            metadata = recording_metadata(
                map_name=grid.name, planner_name=args.planner, planner=planner, planner_options=options,
                predictor=args.predictor, seed=args.seed, sensor=None if sensing is None else sensing.spad,
                nlos_cfg=None if sensing is None else sensing.nlos_cfg, explorer_cfg=cfg.explorer,
                profile=args.profile, models=args.models)
            metadata.update(noise.settings())  # the simulator's noise, where on (the sensor model: "sensor")
            record = EpisodeRecorder(args.record, MapFrame(grid.shape, grid.resolution_m), metadata)
        result = _run_episode(args, grid, start, explorer, cfg, sensing, gif, done, record, live)
        if record is not None:
            record.write_map(result.final_observed)
            record.close()
    except BaseException as error:
        from superex_deploy.parallel import interruption_in

        explorer.close()  # where the episode did not start (a recording that could not be opened)
        # parallel.Interrupted (SIGINT, SIGTERM), a Ctrl-C, or a signal wrapped by a C callback: keep the steps done.
        stop = error if isinstance(error, KeyboardInterrupt) else interruption_in(error)
        if stop is None:
            if record is not None:
                record.abort()
            raise
        stop.kept = _keep_interrupted(args, grid, start, done, record, getattr(stop, "signal_name", "SIGINT"))
        if stop is error:
            raise
        raise stop from None
    from superex_deploy.parallel import signals_deferred

    with signals_deferred():  # a signal now waits until every output is whole, then ends the run as usual
        return _write_outputs(args, grid, start, result, gif, record, noise.settings())


def _run_episode(args, grid, start, explorer, cfg, sensing, gif, done, record, live):
    from tqdm import tqdm

    from superex_deploy.evaluation.episodes import run_episode

    with tqdm(total=args.steps, desc=f"{grid.name} {args.planner}", unit="step") as bar:
        def on_step(state):
            if gif is not None:
                gif(state)
            done.poses.append(list(state.pose))
            done.coverage.append(round(state.coverage, 6))
            bar.update(1)

        def on_observation(observation, command, explorer):
            if command.new_goal:
                done.goals["steps"].append(command.step)
                done.goals["cells"].append(list(command.goal_rc))
            if record is not None:
                record.write(observation, command, explorer.observed, explorer.frame)
            if live is not None:
                live.publish(observation, command, explorer)

        return run_episode(grid, start, explorer=explorer, steps=args.steps, seed=args.seed, cfg=cfg,
                           on_step=on_step, sensing=sensing, on_observation=on_observation)


class _StepsDone:
    """What the steps of an episode stopped by a signal leave for its metrics."""

    def __init__(self):
        self.poses: list = []
        self.coverage: list = []
        self.goals: dict = {"steps": [], "cells": []}


def _keep_interrupted(args, grid, start, done: _StepsDone, record, signal_name: str) -> str:
    """Close the recording up to its last whole step and write the partial metrics; returns what was kept."""
    from superex_deploy.files import write_atomically

    kept = []
    if record is not None and record.steps_written == 0:  # nothing to replay: a file would only be refused
        record.abort()
        kept.append(f"no whole step was recorded, so {args.record} was not written")
    elif record is not None:
        record.close()
        kept.append(f"{args.record} holds the {record.steps_written} whole steps recorded (replayable)")
    steps = len(done.coverage)
    metrics = {"interrupted": signal_name, "map": grid.name, "planner": args.planner, "predictor": args.predictor,
               "seed": args.seed, "start_rc": list(start), "steps": steps, "finished": False,
               "final_coverage": done.coverage[-1] if steps else 0.0, "coverage": done.coverage,
               "poses": done.poses, "goals": {"steps": [s for s in done.goals["steps"] if s < steps],
                                              "cells": [c for s, c in zip(done.goals["steps"], done.goals["cells"])
                                                        if s < steps]},
               "pipeline": args.pipeline, "spad": args.spad, "profile": args.profile}
    write_atomically(args.out / "metrics.json", json.dumps(metrics))
    kept.append(f"{args.out / 'metrics.json'} holds the {steps} steps done, marked interrupted")
    return "; ".join(kept)


def _write_outputs(args, grid, start, result, gif, record, noise: dict) -> int:
    from superex_deploy.render import save_episode_figure

    metrics = result.to_json()
    metrics.update(pipeline=args.pipeline, spad=args.spad, profile=args.profile)
    metrics.update(noise)
    (args.out / "metrics.json").write_text(json.dumps(metrics))
    save_episode_figure(args.out / "final.png", grid, result)
    written = [args.out / "metrics.json", args.out / "final.png"]
    if gif is not None:
        written.append(gif.save(args.out / "episode.gif"))
    if record is not None:
        written.append(args.record)
    coverage = result.coverage[-1] if len(result.coverage) else 0.0
    print(f"{grid.name} start {start} {args.planner}: {len(result.coverage)} steps, coverage {coverage:.1%}, "
          f"path {metrics['path_length_m'][-1] if metrics['path_length_m'] else 0:.1f} m"
          f"{' (explored: no frontier left)' if result.finished else ''}")
    if noise:
        print(f"with noise {noise}: {result.collisions} collisions, {result.true_walls_held_free} true wall cells held "
              f"free, {result.true_walls_carved} carved, explorer-map wall IoU {result.explorer_map_iou:.3f}")
    print(f"wrote {', '.join(str(path) for path in written)}")
    print(summary_line(result))
    return 0
