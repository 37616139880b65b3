"""``superex offline BAG --out DIR``: run the explorer open-loop on a robot's recording, before putting it on the robot.

Reads a ROS 1 bag, a ROS 2 bag or an MCAP file (:mod:`superex_deploy.recording.bags`: the laser scans, the pose from
``/tf`` or a pose / odometry topic, optionally a SLAM map), feeds every usable scan to an explorer as the robot
would, and writes what it answered, as it goes (a run stopped anyhow keeps what it did):

* ``DIR/commands.csv``: per scan, the stamp (seconds since the first scan), the step, the goal (map-frame metres,
  empty without one), ``finished``, ``new_goal``, the step's time per stage (milliseconds), and the command's
  ``status`` and ``reason``; a row is appended (and flushed) at every step;
* ``DIR/map.npz``: the explorer's map (``observed``, int8: -1 unknown, 0 free, 1 wall, row 0 at the top) and
  its frame (``shape``, ``resolution_m``, ``origin_xy``); ``DIR/map.png``: the final map drawn;
* ``DIR/summary.json``: the topics, frames and settings used (``usable_range_m`` among them), scans read and skipped
  (and why), the bad messages skipped by topic and the first of them listed with their stamps, the accepted scan
  matches, ``finished`` (at the end, and the stamp it first held), the last command's ``status`` and ``reason``,
  step-time percentiles, ``interrupted`` when a signal stopped the run and ``error`` when the bag broke mid-way
  (the files then hold the steps done), ``complete`` once the whole bag ran. ``summary.json`` and ``map.npz`` are
  rewritten every :data:`SUMMARY_EVERY_S` seconds while the run goes.

Options (besides the topics and frames, see ``--help``):

* ``--usable-range METRES``: the explorer's usable range (``OccupancyConfig.usable_range_m``, default 20 m): a
  no-return reading (``+inf``, ``range_max`` and above: a SICK LMS codes no echo as 81.83 m) or a return beyond it
  clears free space up to it and never lowers a wall; ``--range-sigma METRES``: the LiDAR's range noise
  (``OccupancyConfig.range_sigma_m``, default 0: exact);
* ``--max-extrapolation SECONDS`` (default 0.1): a transform or pose message held at most this far beyond its data
  (a scan stamped just after the newest /tf); ``--max-pose-age SECONDS`` (default 0.5): a pose topic's messages
  are interpolated within this far of a scan;
* ``--deskew``: each ray's pose at ``stamp + i * time_increment`` (a scan taken while the robot turns);
* ``--stamps arrival``: the bag's receive times instead of the header stamps (a driver without a clock stamps
  every scan 0, which is otherwise refused); a warning is printed;
* ``--profile``, ``--bounds``, ``--record FILE.mcap`` as ``superex explore`` has them (the recording replays with
  ``superex replay``).

The explorer's grid covers everything the bag shows (every sensor position and laser return up to the usable range,
and the SLAM maps) plus ``--margin-m``, at ``--resolution`` (default: the SLAM map's where the learned models serve
it, else the nearest they do: a real 0.0504 m SLAM map gets a 0.05 m grid it is resampled onto; 0.1 m without a
map). It runs on the
robot's clock with ``--finish-after`` seconds without a frontier before ``finished`` (explore_lite's progress
timeout).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from superex_deploy.commands.options import (add_planner_option, add_profile_option, bounds_polygon,
                                             check_output_file, check_output_folder, folders_made, planner_options,
                                             predictor_help)
from superex_deploy.files import write_atomically
from superex_deploy.onboard.mapping.log_odds import OccupancyConfig
from superex_deploy.onboard.planning.planners import PLANNERS
from superex_deploy.onboard.prediction.registry import PREDICTORS
from superex_deploy.onboard.prediction.scale import servable_resolution

STAGES_MS = ("scan", "map_update", "frontiers", "prediction", "scoring", "path")
SUMMARY_EVERY_S = 10.0
"""How often (seconds of wall time) ``summary.json`` and ``map.npz`` are rewritten while a run goes."""
HEADER = ["stamp_s", "step", "goal_x_m", "goal_y_m", "finished", "new_goal", *(f"{stage}_ms" for stage in STAGES_MS),
          "step_ms", "status", "reason"]


def bag_predictors() -> tuple[str, ...]:
    """The predictors a bag can feed (:data:`~superex_deploy.onboard.prediction.registry.PREDICTORS` but those that
    read the SPAD evidence or the ground truth: a bag has neither)."""
    return tuple(name for name, kind in PREDICTORS.items() if not kind.reads_evidence and not kind.reads_truth)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    default_range = OccupancyConfig().usable_range_m
    parser.add_argument("bag", type=Path, help="a ROS 1 .bag, a ROS 2 bag folder (SQLite or MCAP) or an .mcap file")
    parser.add_argument("--out", required=True, type=Path,
                        help="the output folder: commands.csv, map.npz, map.png, summary.json (written as the run "
                             "goes)")
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
                        help="the explorer's cell size in metres (default: the SLAM map's where the models serve it, "
                             "else the nearest they do, e.g. 0.05 for a 0.0504 m map; 0.1 without a map)")
    parser.add_argument("--margin-m", type=float, default=2.0,
                        help="room around what the bag shows, in metres (default: 2)")
    parser.add_argument("--usable-range", type=float, default=default_range, metavar="METRES",
                        help="the usable range (OccupancyConfig.usable_range_m): a reading without a return (inf, "
                             "range_max and above, e.g. a SICK LMS's 81.83 m) or a return beyond it clears free "
                             f"space up to it and never lowers a wall (default: {default_range:g})")
    parser.add_argument("--range-sigma", type=float, default=OccupancyConfig().range_sigma_m, metavar="METRES",
                        help="the LiDAR's range noise (standard deviation; OccupancyConfig.range_sigma_m; default: 0, "
                             "exact ranges)")
    parser.add_argument("--max-extrapolation", type=float, default=0.1, metavar="SECONDS",
                        help="hold a transform or pose at most this far beyond its data, e.g. a scan stamped just "
                             "after the newest /tf (default: 0.1; 0: tf2's rule, never)")
    parser.add_argument("--max-pose-age", type=float, default=0.5, metavar="SECONDS",
                        help="a pose topic's messages are used (interpolated) within this far of a scan (default: "
                             "0.5)")
    parser.add_argument("--deskew", action="store_true",
                        help="give each ray its own pose, at stamp + i * time_increment (a scan taken while the robot "
                             "turns); scans without a time_increment are used as they are")
    parser.add_argument("--stamps", choices=("header", "arrival"), default="header",
                        help="header: the messages' header stamps (default); arrival: the bag's receive times, for a "
                             "driver without a clock (its scans all stamped 0 are refused otherwise)")
    parser.add_argument("--finish-after", type=float, default=5.0, metavar="SECONDS",
                        help="seconds without a reachable frontier before `finished` (default: 5)")
    parser.add_argument("--planner", default="nearest", help=" | ".join(PLANNERS))
    add_planner_option(parser)
    parser.add_argument("--predictor", default="observed", choices=bag_predictors(),
                        help=f"{predictor_help(bag_predictors())} (the bag has no SPAD frames)")
    add_profile_option(parser)
    parser.add_argument("--bounds", type=bounds_polygon, default=None, metavar='"X,Y X,Y X,Y ..."',
                        help="explore only inside this polygon (map-frame metres, at least 3 corners, quoted): "
                             "frontiers outside it are ignored; it must contain the first scan's position")
    parser.add_argument("--record", type=Path, default=None, metavar="FILE",
                        help="also write every observation and command to this MCAP file (`superex replay FILE` "
                             "reruns the explorer on it; Foxglove opens it); its folder must exist or be --out")
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


def _check(args: argparse.Namespace) -> None:
    """Every option's own rule, before the bag is opened or anything is created."""
    def number(option: str, value, low: float, strict: bool, unit: str) -> None:
        if value is not None and not (math.isfinite(value) and (value > low if strict else value >= low)):
            raise ValueError(f"{option} must be {'a positive number' if strict else f'>= {low:g}'} {unit}, got {value}")

    number("--finish-after", args.finish_after, 0.0, False, "seconds")
    number("--resolution", args.resolution, 0.0, True, "of metres")
    number("--margin-m", args.margin_m, 0.0, False, "metres")
    number("--usable-range", args.usable_range, 0.0, True, "of metres")
    number("--range-sigma", args.range_sigma, 0.0, False, "metres")
    number("--max-extrapolation", args.max_extrapolation, 0.0, False, "seconds")
    number("--max-pose-age", args.max_pose_age, 0.0, True, "of seconds")
    if args.limit is not None and args.limit < 1:
        raise ValueError(f"--limit must be >= 1, got {args.limit}")


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import PROFILES, build_explorer, check_profile, resolve_profile
    from superex_deploy.recording.bags import BagTopics, read_bag

    _check(args)
    out = check_output_folder(args.out)
    if args.record is not None:
        check_output_file(args.record, "--record", made=folders_made(out))
    options = planner_options(args.planner_option)
    planner = make_planner(args.planner, **options)
    profile_name = resolve_profile(args.profile, planner, args.predictor)
    check_profile(profile_name, planner, args.predictor)
    topics = BagTopics(scan_topic=args.scan_topic, pose_source=args.pose_source, map_topic=args.map_topic,
                       map_frame=args.map_frame, base_frame=args.base_frame, max_pose_age_s=args.max_pose_age,
                       max_extrapolation_s=args.max_extrapolation, stamps=args.stamps, deskew=args.deskew,
                       usable_range_m=args.usable_range)
    reading, observations = read_bag(args.bag, topics)
    try:
        # --resolution (checked > 0 above), else the SLAM map's where the models serve it, else the nearest they do
        # (a 0.0504 m map gets a 0.05 m grid it is resampled onto), else 0.1 m.
        resolution = args.resolution or (servable_resolution(reading.map_resolution_m)
                                         if reading.map_resolution_m else 0.1)
        frame = frame_for(reading.extent_xy, resolution, args.margin_m, reading.map_origin_xy)
        if args.bounds is not None:
            args.bounds.check_contains(*reading.first_xy)
        cfg = PROFILES[profile_name].explorer_config("robot")
        cfg = dataclasses.replace(cfg, finish_after_s=float(args.finish_after), bounds=args.bounds,
                                  occupancy=dataclasses.replace(cfg.occupancy, usable_range_m=float(args.usable_range),
                                                                range_sigma_m=float(args.range_sigma)))
        explorer = build_explorer(frame, planner, args.predictor, profile=profile_name, models=args.models, cfg=cfg)
    except BaseException:
        observations.close()  # the bag
        raise
    if args.stamps == "arrival":
        print("superex offline: warning: --stamps arrival: every message is stamped with the time the bag received "
              "it, which lags the measurement by the transport's delay", file=sys.stderr, flush=True)
    print(f"superex offline: {args.bag} -> {out}: scans {reading.scan_topic}, pose {reading.pose_source}, "
          f"map {reading.map_topic or '-'}; grid {frame.shape[0]} x {frame.shape[1]} at {frame.resolution_m:.6g} m, "
          f"usable range {args.usable_range:g} m; profile {profile_name}", flush=True)
    settings = {"profile": profile_name, "options": options, "cfg": cfg, "frame": frame, "topics": topics}
    return _run(args, out, reading, observations, explorer, planner, settings)


class _Progress:
    """What the run has done: ``commands.csv`` appended and flushed at every step, the summary and the map
    rewritten every :data:`SUMMARY_EVERY_S` seconds and at the end."""

    def __init__(self, out: Path, args, reading, explorer, settings: dict) -> None:
        self.out, self.args, self.reading, self.explorer, self.settings = out, args, reading, explorer, settings
        self.steps, self.step_ms, self.finished_at, self.command = 0, [], None, None
        self.matches = {"attempted": 0, "accepted": 0}
        self.whole_bag = False
        self._file = open(out / "commands.csv", "w", newline="")
        self._csv = csv.writer(self._file)
        self._csv.writerow(HEADER)
        self._file.flush()
        self._next = time.monotonic() + SUMMARY_EVERY_S

    def step(self, command, total_ms: float) -> None:
        self.steps += 1
        self.command = command
        self.step_ms.append(total_ms)
        if command.finished and self.finished_at is None:
            self.finished_at = command.stamp_s
        match = self.explorer.scan_match
        if match is not None:
            self.matches["attempted"] += 1
            self.matches["accepted"] += int(bool(match.accepted))
        goal = command.goal_xy
        self._csv.writerow([f"{command.stamp_s:.6f}", command.step, "" if goal is None else f"{goal[0]:.3f}",
                            "" if goal is None else f"{goal[1]:.3f}", int(command.finished), int(command.new_goal),
                            *(f"{1e3 * command.timings_s.get(stage, 0.0):.3f}" for stage in STAGES_MS),
                            f"{total_ms:.3f}", command.status, command.reason])
        self._file.flush()
        if time.monotonic() >= self._next:
            self.write(final=False)
            self._next = time.monotonic() + SUMMARY_EVERY_S

    def write(self, final: bool, interrupted: bool = False, error=None) -> None:
        """The map and the summary as they are now (``final``: also the map's picture, and the CSV closed)."""
        from superex_deploy.render import save_map_image

        observed, frame = self.explorer.observed, self.settings["frame"]

        def save_npz(part: Path) -> None:
            with open(part, "wb") as file:
                np.savez_compressed(file, observed=observed, shape=np.asarray(frame.shape),
                                    resolution_m=frame.resolution_m, origin_xy=np.asarray(frame.origin_xy))

        write_atomically(self.out / "map.npz", save_npz)
        if final:
            self._file.close()
            write_atomically(self.out / "map.png", lambda part: save_map_image(observed, part))
        write_atomically(self.out / "summary.json", json.dumps(self.summary(final, interrupted, error), indent=2)
                         + "\n")

    def summary(self, final: bool, interrupted: bool, error) -> dict:
        args, reading, command, topics = self.args, self.reading, self.command, self.settings["topics"]
        occupancy, frame = self.settings["cfg"].occupancy, self.settings["frame"]
        times = np.asarray(self.step_ms) if self.step_ms else np.zeros(1)
        bounds = None if args.bounds is None else [list(point) for point in args.bounds.points]
        return {
            "bag": str(args.bag), "scan_topic": reading.scan_topic, "pose_source": reading.pose_source,
            "map_topic": reading.map_topic, "map_frame": args.map_frame, "base_frame": args.base_frame,
            "planner": args.planner, "predictor": args.predictor, "profile": self.settings["profile"],
            "finish_after_s": args.finish_after, "usable_range_m": occupancy.usable_range_m,
            "range_sigma_m": occupancy.range_sigma_m, "max_extrapolation_s": topics.max_extrapolation_s,
            "max_pose_age_s": topics.max_pose_age_s, "stamps": topics.stamps, "deskew": topics.deskew,
            "bounds": bounds, "record": None if args.record is None else str(args.record),
            "frame": {"shape": list(frame.shape), "resolution_m": frame.resolution_m,
                      "origin_xy": list(frame.origin_xy)},
            "steps": self.steps, "expected_scans": reading.expected_scans, "scans_skipped": reading.skipped,
            "mirrored_scans": reading.mirrored, "deskewed_scans": reading.deskewed, "late_maps": reading.late_maps,
            "messages_skipped": reading.messages_skipped, "bad_messages": reading.bad_messages,
            "scan_match": dict(self.matches), "first_stamp_s": reading.first_stamp_s,
            "finished": bool(command is not None and command.finished), "first_finished_stamp_s": self.finished_at,
            "status": None if command is None else command.status,
            "reason": None if command is None else command.reason,
            "step_ms": {"mean": float(times.mean()), "p50": float(np.percentile(times, 50)),
                        "p99": float(np.percentile(times, 99)), "max": float(times.max())},
            "interrupted": interrupted, "error": None if error is None else str(error),
            "complete": self.whole_bag,
        }


def _recorder(args, frame, planner, settings):
    from superex_deploy.recording import EpisodeRecorder
    from superex_deploy.recording.metadata import recording_metadata

    metadata = recording_metadata(map_name=f"bag:{Path(args.bag).name}", planner_name=args.planner, planner=planner,
                                  planner_options=settings["options"], predictor=args.predictor, seed=0, sensor=None,
                                  nlos_cfg=None, explorer_cfg=settings["cfg"], profile=settings["profile"],
                                  models=args.models)
    metadata["bag"] = str(args.bag)
    return EpisodeRecorder(args.record, frame, metadata)


def _run(args, out: Path, reading, observations, explorer, planner, settings) -> int:
    from tqdm import tqdm

    interrupted, failure = None, None
    total = reading.expected_scans + reading.late_maps_expected
    total = total if args.limit is None else min(args.limit, total)
    try:
        out.mkdir(parents=True, exist_ok=True)
        progress = _Progress(out, args, reading, explorer, settings)
        record = None if args.record is None else _recorder(args, settings["frame"], planner, settings)
    except BaseException:
        explorer.close()
        observations.close()
        raise
    try:
        with tqdm(total=total, desc="superex offline", unit="scan", mininterval=1.0) as bar:
            for observation in observations:
                clock = time.perf_counter()
                command = explorer.step(observation)
                progress.step(command, 1e3 * (time.perf_counter() - clock))
                if record is not None:
                    record.write(observation, command, explorer.observed, explorer.frame)
                bar.update(1)
                if args.limit is not None and progress.steps >= args.limit:
                    break
            else:
                progress.whole_bag = True
    except KeyboardInterrupt as stop:
        interrupted = stop
    except ValueError as error:  # the bag broke mid-way, or the explorer refused an observation: keep what ran
        failure = error
    except BaseException as error:
        from superex_deploy.parallel import interruption_in

        interrupted = interruption_in(error)  # a signal wrapped by a C callback
        if interrupted is None:
            if record is not None:
                record.abort()
            raise  # a crash: commands.csv and the last summary hold what ran
    finally:
        explorer.close()
        observations.close()
    from superex_deploy.parallel import signals_deferred

    with signals_deferred():  # a signal now waits until every output is whole, then ends the run as usual
        if record is not None:
            if record.steps_written:
                record.write_map(explorer.observed)
                record.close()
            else:
                record.abort()
        progress.write(final=True, interrupted=interrupted is not None, error=failure)
    if interrupted is not None:
        interrupted.kept = f"wrote the {progress.steps} steps done to {out}"
        raise interrupted from None
    if failure is not None:
        raise ValueError(f"{failure} (the {progress.steps} steps done are in {out})") from None
    if args.deskew and progress.steps and not reading.deskewed:
        print("superex offline: warning: --deskew: no scan carries a time_increment, none was de-skewed",
              file=sys.stderr)
    command = progress.command
    print(f"superex offline: {progress.steps} steps, finished {command is not None and command.finished}"
          f"{'' if progress.finished_at is None else f' (first at {progress.finished_at:.2f} s)'}, accepted scan "
          f"matches {progress.matches['accepted']}, step time p99 "
          f"{np.percentile(progress.step_ms, 99) if progress.step_ms else 0:.1f} ms; wrote {out}"
          f"{'' if record is None else f' and {args.record}'}")
    return 0
