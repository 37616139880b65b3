"""``superex offline BAG --out DIR``: run the explorer open-loop on a robot's recording, before putting it on the robot.

Reads a ROS 1 bag, a ROS 2 bag or an MCAP file (:mod:`superex_deploy.recording.bags`: the laser scans, the pose from
``/tf`` or a pose / odometry topic, optionally a SLAM map), feeds every usable scan to an explorer as the robot
would, and writes what it answered:

* ``DIR/commands.csv``: per scan, the stamp (seconds since the first scan), the step, the goal (map-frame metres,
  empty without one), ``finished``, ``new_goal``, the step's time per stage (milliseconds), and the command's
  ``status`` and ``reason``;
* ``DIR/map.npz``: the explorer's final map (``observed``, int8: -1 unknown, 0 free, 1 wall, row 0 at the top) and
  its frame (``shape``, ``resolution_m``, ``origin_xy``); ``DIR/map.png``: the map drawn;
* ``DIR/summary.json``: the topics and frames used, scans read and skipped (and why), ``finished`` (at the end,
  and the stamp it first held), the last command's ``status`` and ``reason``, step-time percentiles, and ``interrupted`` when a signal stopped the run (the
  files then hold the steps done).

The explorer's grid covers everything the bag shows (every sensor position and laser return, and the SLAM maps) plus
``--margin-m``, at ``--resolution`` (default: the SLAM map's, else 0.1 m). It runs on the robot's clock with
``--finish-after`` seconds without a frontier before ``finished`` (explore_lite's progress timeout).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import time
from pathlib import Path

import numpy as np

from superex_deploy.commands.options import add_planner_option, check_output_folder, planner_options
from superex_deploy.files import write_atomically

STAGES_MS = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="a ROS 1 .bag, a ROS 2 bag folder (SQLite or MCAP) or an .mcap file")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--scan-topic", default=None, help="sensor_msgs/LaserScan topic (default: the only one)")
    parser.add_argument("--pose-source", default="auto",
                        help="tf, a PoseWithCovarianceStamped or Odometry topic, or auto (default: a "
                             "PoseWithCovarianceStamped topic, else /tf when it holds the map frame, else an Odometry "
                             "topic)")
    parser.add_argument("--map-topic", default=None,
                        help="nav_msgs/OccupancyGrid topic (default: the only one, if any; '' for none)")
    parser.add_argument("--map-frame", default="map", help="the fixed frame of the poses (default: map)")
    parser.add_argument("--base-frame", default="base_link", help="the robot's frame (default: base_link)")
    parser.add_argument("--resolution", type=float, default=None,
                        help="the explorer's cell size in metres (default: the SLAM map's, else 0.1)")
    parser.add_argument("--margin-m", type=float, default=2.0,
                        help="room around what the bag shows, in metres (default: 2)")
    parser.add_argument("--finish-after", type=float, default=5.0, metavar="SECONDS",
                        help="seconds without a reachable frontier before `finished` (default: 5)")
    parser.add_argument("--planner", default="nearest", help="nearest | hector | upen | mapex | superex")
    add_planner_option(parser)
    parser.add_argument("--predictor", default="observed", choices=("observed", "lama_los"),
                        help="observed, or lama_los (the bag has no SPAD frames)")
    parser.add_argument("--models", type=Path, default=None, help="folder of exported models (default: installed)")
    parser.add_argument("--limit", type=int, default=None, help="read at most this many scans")


def frame_for(extent_xy, resolution_m: float, margin_m: float, lattice_xy=None):
    """The :class:`~superex_deploy.messages.MapFrame` holding ``extent_xy`` ``(x_min, y_min, x_max, y_max)`` (metres)
    plus ``margin_m``, with its origin on the lattice of ``lattice_xy`` (a SLAM map's origin) when given.

    Raises:
        ValueError: a non-positive resolution, a negative margin, a frame beyond the map size limits.
    """
    from superex_deploy.messages import MapFrame

    if not (math.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"--resolution must be a positive number of metres, got {resolution_m}")
    if not (math.isfinite(margin_m) and margin_m >= 0):
        raise ValueError(f"--margin-m must be >= 0, got {margin_m}")
    x0, y0, x1, y1 = extent_xy
    anchor = lattice_xy or (0.0, 0.0)
    left = anchor[0] + math.floor((x0 - margin_m - anchor[0]) / resolution_m) * resolution_m
    bottom = anchor[1] + math.floor((y0 - margin_m - anchor[1]) / resolution_m) * resolution_m
    cols = int(math.ceil((x1 + margin_m - left) / resolution_m)) + 1
    rows = int(math.ceil((y1 + margin_m - bottom) / resolution_m)) + 1
    return MapFrame((rows, cols), resolution_m, (left, bottom))


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import PROFILES, build_explorer, resolve_profile
    from superex_deploy.recording.bags import BagTopics, read_bag

    if not (math.isfinite(args.finish_after) and args.finish_after >= 0):
        raise ValueError(f"--finish-after must be >= 0 seconds, got {args.finish_after}")
    if args.resolution is not None and not (math.isfinite(args.resolution) and args.resolution > 0):
        raise ValueError(f"--resolution must be a positive number of metres, got {args.resolution}")
    if not (math.isfinite(args.margin_m) and args.margin_m >= 0):
        raise ValueError(f"--margin-m must be >= 0, got {args.margin_m}")
    if args.limit is not None and args.limit < 1:
        raise ValueError(f"--limit must be >= 1, got {args.limit}")
    out = check_output_folder(args.out)
    options = planner_options(args.planner_option)
    planner = make_planner(args.planner, **options)
    profile_name = resolve_profile(None, planner, args.predictor)
    topics = BagTopics(scan_topic=args.scan_topic, pose_source=args.pose_source, map_topic=args.map_topic,
                       map_frame=args.map_frame, base_frame=args.base_frame)
    reading, observations = read_bag(args.bag, topics)
    try:
        resolution = args.resolution or reading.map_resolution_m or 0.1  # --resolution: checked > 0 above
        frame = frame_for(reading.extent_xy, resolution, args.margin_m, reading.map_origin_xy)
    except BaseException:
        observations.close()  # the bag
        raise
    out.mkdir(parents=True, exist_ok=True)
    cfg = dataclasses.replace(PROFILES[profile_name].explorer_config("robot"), finish_after_s=float(args.finish_after))
    explorer = build_explorer(frame, planner, args.predictor, profile=profile_name, models=args.models, cfg=cfg)
    print(f"superex offline: {args.bag} -> {out}: scans {reading.scan_topic}, pose {reading.pose_source}, "
          f"map {reading.map_topic or '-'}; grid {frame.shape[0]} x {frame.shape[1]} at {frame.resolution_m} m",
          flush=True)
    rows, step_ms, finished_at, command = [], [], None, None
    interrupted = None
    try:
        from tqdm import tqdm

        for observation in tqdm(observations, desc="superex offline", unit="scan", mininterval=1.0):
            clock = time.perf_counter()
            command = explorer.step(observation)
            step_ms.append(1e3 * (time.perf_counter() - clock))
            if command.finished and finished_at is None:
                finished_at = command.stamp_s
            rows.append(_row(command, step_ms[-1]))
            if args.limit is not None and len(rows) >= args.limit:
                break
    except KeyboardInterrupt as stop:
        interrupted = stop
    finally:
        explorer.close()
    _write(out, args, reading, frame, explorer, rows, step_ms, command, finished_at, interrupted is not None)
    if interrupted is not None:
        interrupted.kept = f"wrote the {len(rows)} steps done to {out}"
        raise interrupted
    print(f"superex offline: {len(rows)} steps, finished {command is not None and command.finished}"
          f"{'' if finished_at is None else f' (first at {finished_at:.2f} s)'}, step time p99 "
          f"{np.percentile(step_ms, 99) if step_ms else 0:.1f} ms; wrote {out}")
    return 0


def _row(command, total_ms: float) -> list:
    goal = command.goal_xy
    return [f"{command.stamp_s:.6f}", command.step, "" if goal is None else f"{goal[0]:.3f}",
            "" if goal is None else f"{goal[1]:.3f}", int(command.finished), int(command.new_goal),
            *(f"{1e3 * command.timings_s.get(stage, 0.0):.3f}" for stage in STAGES_MS), f"{total_ms:.3f}",
            command.status, command.reason]


def _write(out: Path, args, reading, frame, explorer, rows, step_ms, command, finished_at, interrupted) -> None:
    from superex_deploy.render import save_map_image

    table = io.StringIO()
    writer = csv.writer(table)
    writer.writerow(["stamp_s", "step", "goal_x_m", "goal_y_m", "finished", "new_goal",
                     *(f"{stage}_ms" for stage in STAGES_MS), "step_ms", "status", "reason"])
    writer.writerows(rows)
    write_atomically(out / "commands.csv", table.getvalue())
    observed = explorer.observed
    def save_npz(part: Path) -> None:
        with open(part, "wb") as file:
            np.savez_compressed(file, observed=observed, shape=np.asarray(frame.shape),
                                resolution_m=frame.resolution_m, origin_xy=np.asarray(frame.origin_xy))

    write_atomically(out / "map.npz", save_npz)
    write_atomically(out / "map.png", lambda part: save_map_image(observed, part))
    times = np.asarray(step_ms) if step_ms else np.zeros(1)
    summary = {
        "bag": str(args.bag), "scan_topic": reading.scan_topic, "pose_source": reading.pose_source,
        "map_topic": reading.map_topic, "map_frame": args.map_frame, "base_frame": args.base_frame,
        "planner": args.planner, "predictor": args.predictor, "finish_after_s": args.finish_after,
        "frame": {"shape": list(frame.shape), "resolution_m": frame.resolution_m, "origin_xy": list(frame.origin_xy)},
        "steps": len(rows), "scans_skipped": reading.skipped,
        "first_stamp_s": reading.first_stamp_s,
        "finished": bool(command is not None and command.finished), "first_finished_stamp_s": finished_at,
        "status": None if command is None else command.status, "reason": None if command is None else command.reason,
        "step_ms": {"mean": float(times.mean()), "p50": float(np.percentile(times, 50)),
                    "p99": float(np.percentile(times, 99)), "max": float(times.max())},
        "interrupted": interrupted,
    }
    write_atomically(out / "summary.json", json.dumps(summary, indent=2) + "\n")
