"""``superex explore``: one exploration episode, written as metrics.json, final.png and episode.gif."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from superex_deploy.commands._options import (add_noise_options, add_planner_option, add_profile_option,
                                               noise_options, noise_settings, planner_options)
from superex_deploy.pipeline import PREDICTORS, PROFILES, check_profile, make_predictor, make_sensing, resolve_profile


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--map", required=True, help="bundled map name or an image / ROS YAML path")
    parser.add_argument("--start", type=int, default=0, help="index of the eval map's start pose (0-3)")
    parser.add_argument("--pose", type=int, nargs=2, metavar=("ROW", "COL"), help="start cell instead of --start")
    parser.add_argument("--planner", default="nearest", help="nearest | hector | upen | mapex | superex")
    add_planner_option(parser)
    parser.add_argument("--predictor", default="observed", choices=PREDICTORS,
                        help="observed: unknown = free (honest baseline); oracle: ground truth (upper bound only); "
                             "lama_los: the line-of-sight LaMa ensemble; lama_bp: the LaMa ensemble that also reads "
                             "the Pix2Pix-filtered back-projection (needs --spad); evidence: the Pix2Pix evidence "
                             "alone, no LaMa (needs --spad)")
    parser.add_argument("--models", type=Path, default=None,
                        help="folder of exported models with manifest.json (default: the repository's exported/)")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--spad", action="store_true",
                        help="also scan with the SPAD LiDAR every step and merge its carved free space "
                             "(coverage is reported with and without carving)")
    parser.add_argument("--gif-every", type=int, default=5, help="record a GIF frame every N steps")
    parser.add_argument("--record", type=Path, default=None, metavar="FILE",
                        help="also write every observation and command to this MCAP file (ROS 2 messages; "
                             "`superex replay FILE` reruns the explorer on it)")
    add_profile_option(parser)
    add_noise_options(parser)
    parser.add_argument("--out", required=True, type=Path)


def recording_metadata(grid, args, options: dict, sensing, explorer_cfg) -> dict:
    """What a replay needs to rebuild the explorer of this run (JSON values); ``sensing``: the episode's
    :class:`~superex_deploy.sim.sensing.SpadSensing` or None (recorded under ``sensor`` and ``nlos``)."""
    from dataclasses import asdict

    return {"map": grid.name, "planner": args.planner, "planner_options": options, "predictor": args.predictor,
            "seed": args.seed, "spad": sensing is not None,
            "models": None if args.models is None else str(Path(args.models).resolve()),
            "sensor": None if sensing is None else asdict(sensing.spad),
            "nlos": None if sensing is None else asdict(sensing.nlos_cfg),
            "explorer": asdict(explorer_cfg), "profile": args.profile,
            "profile_settings": PROFILES[args.profile].to_json()}


def resolve_start(grid, start_index: int, pose):
    from superex_deploy.maps import start_poses

    if pose is not None:
        start = grid.check_pose(pose)
        if not grid.valid[start]:
            raise ValueError(f"--pose {start[0]} {start[1]} lies outside the valid (inside-the-building) area of map "
                             f"{grid.name!r}: nothing there could be explored")
        return start
    poses = start_poses(grid.name)
    if not 0 <= start_index < len(poses):
        raise ValueError(f"--start must lie in 0..{len(poses) - 1}, got {start_index}")
    return poses[start_index]


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from superex_deploy.onboard.planners import make_planner
    from superex_deploy.maps import load_map
    from superex_deploy.messages import MapFrame
    from superex_deploy.recording import EpisodeRecorder
    from superex_deploy.render import GifRecorder, save_episode_figure
    from superex_deploy.sim.episode import run_episode

    from superex_deploy.benchmarking import with_noise, with_spad_noise

    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    noise = noise_options(args)
    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out} exists and is not a folder")
    grid = load_map(args.map)
    start = resolve_start(grid, args.start, args.pose)
    options = planner_options(args.planner_option)
    planner = make_planner(args.planner, **options)
    args.profile = resolve_profile(args.profile, planner, args.predictor)
    profile = check_profile(args.profile, planner, args.predictor)
    sensing = with_spad_noise(make_sensing(args.predictor, args.spad, args.seed, args.models, profile),
                              noise["spad_noise"])
    predictor = make_predictor(args.predictor, grid, args.models, profile)
    cfg = with_noise(profile.episode_config(), noise["pose_noise"], noise["lidar_noise"], args.seed)
    if args.record is not None and args.predictor == "oracle":
        raise ValueError("--record: the oracle predictor reads the ground truth, so no replay could rerun it; "
                         "record with another predictor")
    from superex_deploy.commands.warmup import numba_cache_is_warm

    if not numba_cache_is_warm():
        print("superex explore: first run here: compiling the numba kernels (about half a minute, once; numba caches "
              "them; `superex warmup` does it ahead)", file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    record = None
    if args.record is not None:
        explorer_cfg = cfg.explorer
        metadata = recording_metadata(grid, args, options, sensing, explorer_cfg)
        metadata.update(noise_settings(noise))  # the simulator's noise, where on (the sensor model is in "sensor")
        record = EpisodeRecorder(args.record, MapFrame(grid.shape, grid.resolution_m), metadata)
    recorder = GifRecorder(every=args.gif_every)
    try:
        with tqdm(total=args.steps, desc=f"{grid.name} {args.planner}", unit="step") as bar:
            def on_step(state):
                recorder(state)
                bar.update(1)

            def on_observation(observation, command, explorer):
                record.write(observation, command, explorer.observed)

            result = run_episode(grid, start, planner, predictor, steps=args.steps, seed=args.seed, cfg=cfg,
                                 on_step=on_step, sensing=sensing,
                                 on_observation=None if record is None else on_observation)
        if record is not None:
            record.write_map(result.final_observed)
            record.close()
    except BaseException:
        if record is not None:
            record.abort()
        raise
    metrics = result.to_json()
    metrics["profile"] = args.profile
    metrics.update(noise_settings(noise))
    (args.out / "metrics.json").write_text(json.dumps(metrics))
    save_episode_figure(args.out / "final.png", grid, result)
    recorder.save(args.out / "episode.gif")
    coverage = result.coverage[-1] if len(result.coverage) else 0.0
    print(f"{grid.name} start {start} {args.planner}: {len(result.coverage)} steps, coverage {coverage:.1%}, "
          f"path {metrics['path_length_m'][-1] if metrics['path_length_m'] else 0:.1f} m"
          f"{' (explored: no frontier left)' if result.finished else ''}")
    if noise_settings(noise):
        print(f"with noise {noise_settings(noise)}: {result.collisions} collisions, {result.true_walls_held_free} true "
              f"wall cells held free, {result.true_walls_carved} carved, explorer-map wall IoU "
              f"{result.explorer_map_iou:.3f}")
    print(f"wrote {args.out / 'metrics.json'}, {args.out / 'final.png'}, {args.out / 'episode.gif'}"
          f"{', ' + str(args.record) if record is not None else ''}")
    return 0
