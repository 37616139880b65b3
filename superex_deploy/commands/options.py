"""Command-line options shared by several commands (``superex explore``, ``superex benchmark`` and its paper suite,
``superex train data``): each declared, parsed and checked in one place.

Every value is checked where it enters, before a command creates any file or folder: numbers and lists by their
argparse ``type`` (the error names the option: ``argument --seed: must be an integer >= 0, got '-5'``), output
paths by :func:`check_output_folder` and :func:`check_output_file`, start cells by :func:`resolve_start`.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Iterable, Optional

from superex_deploy.onboard.planning.planners import PLANNERS
from superex_deploy.pipeline import DEFAULT_PROFILE, ENSEMBLE_PREDICTORS, PREDICTORS, PROFILES

__all__ = ["add_planner_option", "planner_options", "predictor_help", "add_profile_option", "add_parallel_options",
           "check_jobs", "make_backend", "positive_int", "non_negative_int", "name_list", "eval_maps",
           "check_output_folder", "check_output_file", "folders_made", "resolve_start", "START_CLEARANCE_M",
           "settings_differences", "add_noise_options", "load_floor", "parse_pose_noise", "parse_lidar_noise",
           "noise_options", "add_live_options"]


def _integer(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < low:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (argparse names the option in its error)."""
    return _integer(text, 1)


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (argparse names the option in its error)."""
    return _integer(text, 0)


def bounds_polygon(text: str):
    """argparse type: the exploration bounds ``"x1,y1 x2,y2 x3,y3 ..."`` (map-frame metres; at least 3 points, a
    polygon that does not cross itself), as an :class:`~superex_deploy.onboard.planning.bounds.ExplorationBounds`."""
    from superex_deploy.onboard.planning.bounds import parse_bounds

    try:
        return parse_bounds(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def name_list(text: str) -> list[str]:
    """argparse type: comma-separated names, at least one, none twice (empty items are skipped: ``a,b,``)."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected one or more comma-separated names, got {text!r}")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"names {', '.join(twice)} more than once in {text!r}")
    return names


def eval_maps(names: list[str]) -> list[str]:
    """``--maps`` (a :func:`name_list`) -> the bundled eval maps it names: ``["eval"]`` is all ten.

    Raises:
        ValueError: a name that is not a bundled eval map (only those have the benchmark's start poses).
    """
    from superex_deploy.maps import list_maps

    known = list_maps("eval")
    if list(names) == ["eval"]:
        return known
    unknown = [name for name in names if name not in known]
    if unknown:
        raise ValueError(f"--maps: not an eval map: {', '.join(unknown)} (only those have the benchmark's start "
                         f"poses); choose from 'eval' or {', '.join(known)}")
    return list(names)


def check_output_folder(path: Path, option: str = "--out") -> Path:
    """Refuse an output folder that cannot exist, creating nothing: ``path`` is a folder, or its nearest existing
    parent is a folder this process may write in (``mkdir(parents=True)`` will then make it).

    Raises:
        ValueError: naming ``option``, when ``path`` or one of its parents is a file, or the parent is read-only.
    """
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise ValueError(f"{option} {path} exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise ValueError(f"{option} {path}: the folder is not writable")
        return path
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{option} {path} cannot be created: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path} cannot be created: {parent} is not writable")
    return path


def check_output_file(path: Path, option: str, made: Iterable[Path] = ()) -> Path:
    """Refuse an output file that cannot be written, creating nothing: ``path`` is not a folder and its folder
    exists (or is one of the folders ``made``, which the command creates first) and is writable.

    Raises:
        ValueError: naming ``option``.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder, not a file")
    folder = path.parent
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {path}: {folder} is a file, not a folder")
    if not folder.is_dir():
        if folder.resolve() not in {Path(m).resolve() for m in made}:
            raise ValueError(f"{option} {path}: the folder {folder} does not exist")
    elif not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path}: the folder {folder} is not writable")
    return path


def folders_made(out: Path) -> list[Path]:
    """``out`` and those of its parents that do not exist yet: what ``out.mkdir(parents=True)`` creates."""
    made, folder = [], Path(out)
    while not folder.exists() and folder != folder.parent:
        made.append(folder)
        folder = folder.parent
    return made


START_CLEARANCE_M = 0.5
"""How far from every wall a start drawn for a map without start poses lies (metres), where the map allows."""


def resolve_start(map_arg: str, grid, start_index: int, pose: Optional[tuple[int, int]],
                  require_valid: bool = True, seed: int = 0, command: str = "superex") -> tuple[int, int]:
    """The start cell ``--start`` / ``--pose`` name on the map ``--map`` loaded as ``grid``. A map without start
    poses (a user's file, a train map) and no ``--pose``: a cell drawn with ``seed`` from the largest free region,
    :data:`START_CLEARANCE_M` from the walls (:func:`~superex_deploy.maps.largest_region_start`), printed as
    ``command: ...`` so that the run can be repeated with ``--pose``.

    Args:
        map_arg: ``--map`` as given (a bundled map's name, or a file).
        grid: the loaded map.
        start_index: ``--start``, the index of a bundled eval map's start pose.
        pose: ``--pose ROW COL``, or None.
        require_valid: refuse a ``--pose`` outside the valid (inside-the-building) area.
        seed: the draw's seed (``--seed``).
        command: how the printed line starts.

    Raises:
        ValueError: a pose off the map, in a wall or (``require_valid``) outside the valid area; a ``--start``
            out of range; a map with no free valid cell to draw a start from.
    """
    import numpy as np

    from superex_deploy.maps import largest_region_start, list_maps, start_poses

    if pose is not None:
        start = grid.check_pose(pose)
        if require_valid and not grid.valid[start]:
            raise ValueError(f"--pose {start[0]} {start[1]} lies outside the valid (inside-the-building) area of map "
                             f"{grid.name!r}: nothing there could be explored")
        return start
    if str(map_arg) not in list_maps("eval"):
        start = largest_region_start(grid, np.random.default_rng(seed), START_CLEARANCE_M)
        print(f"{command}: --map {map_arg} has no start poses: start drawn from its largest free region (seed "
              f"{seed}): --pose {start[0]} {start[1]}", flush=True)
        return start
    poses = start_poses(grid.name)
    if not 0 <= start_index < len(poses):
        raise ValueError(f"--start must lie in 0..{len(poses) - 1}, got {start_index}")
    return poses[start_index]


def load_floor(map_arg: str, resolution_m: Optional[float], start_index: int, pose: Optional[tuple[int, int]],
               seed: int = 0, command: str = "superex"):
    """The floor ``--map`` names at ``--resolution`` metres per cell and the start cell on it: a bundled floor
    (0.1 m) at ``0.1 / K`` for an integer ``K`` up to 4 is upsampled (every cell ``K x K``: the same building on a
    SLAM grid), its start pose (``--start``) scaled to the block's centre cell; an image file is read at that
    resolution; None: the map's own. ``--pose`` is a cell of the floor as run.

    Raises:
        ValueError: a resolution that is not positive, a bundled floor at another resolution than 0.1 m / K, a
            ROS map_server YAML at another than its own, what :func:`resolve_start` refuses.
    """
    from pathlib import Path as _Path

    from superex_deploy.maps import list_maps, load_map
    from superex_deploy.sim.generated_floors import upsampled

    if resolution_m is not None and not (math.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"--resolution must be a positive number of metres, got {resolution_m}")
    bundled = str(map_arg) in set(list_maps("eval")) | set(list_maps("train"))
    if not bundled and resolution_m is not None and _Path(map_arg).suffix.lower() not in (".yaml", ".yml"):
        grid = load_map(map_arg, resolution_m)
        return grid, resolve_start(map_arg, grid, start_index, pose, seed=seed, command=command)
    grid = load_map(map_arg)
    factor = 1
    if resolution_m is not None and abs(resolution_m - grid.resolution_m) > 1e-9:
        ratio = grid.resolution_m / resolution_m
        factor = int(round(ratio))
        if not bundled or abs(ratio - factor) > 1e-6 or not 1 <= factor <= 4:
            raise ValueError(f"--resolution {resolution_m:g}: {map_arg} is a {grid.resolution_m:g} m map, which runs "
                             f"at {grid.resolution_m:g} m / K for K = 1..4 (bundled floors only; a file: its own)")
    if pose is not None or factor == 1:
        fine = upsampled(grid, factor) if factor > 1 else grid
        return fine, resolve_start(map_arg, fine, start_index, pose, seed=seed, command=command)
    start = resolve_start(map_arg, grid, start_index, None, seed=seed, command=command)
    return upsampled(grid, factor), (start[0] * factor + factor // 2, start[1] * factor + factor // 2)


def settings_differences(recorded, new, prefix: str = "") -> list[str]:
    """``"field: recorded X, now Y"`` for every field where two JSON settings differ (nested fields dotted:
    ``profile_settings.prediction.every_steps``); empty when they are equal."""
    if isinstance(recorded, dict) and isinstance(new, dict):
        differences = []
        for key in list(recorded) + [k for k in new if k not in recorded]:
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in new:
                differences.append(f"{name}: recorded {_short(recorded[key])}, now absent")
            elif key not in recorded:
                differences.append(f"{name}: not recorded, now {_short(new[key])}")
            else:
                differences += settings_differences(recorded[key], new[key], name)
        return differences
    return [] if recorded == new else [f"{prefix or 'settings'}: recorded {_short(recorded)}, now {_short(new)}"]


def _short(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def add_planner_option(parser: argparse.ArgumentParser) -> None:
    """``--planner-option FIELD=VALUE`` (repeatable; :func:`planner_options` parses it)."""
    from superex_deploy.onboard.planning.planners import SuperexConfig

    parser.add_argument("--planner-option", action="append", default=[], metavar="FIELD=VALUE",
                        help="override a field of the planner's config, e.g. distance=euclidean for MapEx's "
                             "straight-line divisor, or gain=path for the superex planner's count on the thresholded "
                             f"prediction (its default: gain={SuperexConfig.gain}) (repeatable; numbers, true/false "
                             "and none are converted)")


def planner_options(pairs: list[str]) -> dict:
    """``["field=value", ...]`` -> config overrides; ints, floats and true / false are converted, ``none`` becomes
    None (a field that takes None accepts it; the others name themselves in their error)."""
    options = {}
    for pair in pairs:
        field_name, separator, text = pair.partition("=")
        if not separator or not field_name.strip():
            raise ValueError(f"--planner-option takes FIELD=VALUE, got {pair!r}")
        value: object = text.strip()
        if text.strip().lower() in ("true", "false"):
            value = text.strip().lower() == "true"
        elif text.strip().lower() == "none":
            value = None  # e.g. IG-Hector's visibility=none: MapEx's code path
        else:
            for convert in (int, float):
                try:
                    value = convert(text)
                    break
                except ValueError:
                    pass
        options[field_name.strip()] = value
    return options


def predictor_help(names: Optional[Iterable[str]] = None) -> str:
    """``NAME: what it is`` for each predictor of ``names`` (None: every one of
    :data:`~superex_deploy.pipeline.PREDICTORS`), ``(needs --spad)`` after those that read the SPAD evidence: a
    ``--predictor`` option's help."""
    names = tuple(PREDICTORS) if names is None else names
    return "; ".join(f"{name}: {PREDICTORS[name].summary}"
                     + (" (needs --spad)" if PREDICTORS[name].reads_evidence else "") for name in names)


_VARIANCE_PLANNERS = tuple(name for name, planner in PLANNERS.items() if planner.reads_variance)


def add_profile_option(parser: argparse.ArgumentParser) -> None:
    """``--profile NAME`` (default None: :func:`superex_deploy.pipeline.resolve_profile` chooses)."""
    parser.add_argument("--profile", choices=tuple(PROFILES), default=None,
                        help="real-time settings of the onboard pipeline (superex_deploy.pipeline.PROFILES): "
                             "'full' runs everything inside each step, 'realtime' the measured asynchronous, cropped, "
                             f"one-member prediction (benchmarks/realtime). Default: {DEFAULT_PROFILE}, or full for "
                             f"planners that read the ensemble's variance ({', '.join(_VARIANCE_PLANNERS)}) with an "
                             f"ensemble predictor ({', '.join(ENSEMBLE_PREDICTORS)})")


def add_parallel_options(parser: argparse.ArgumentParser) -> None:
    """``--jobs``, ``--backend`` and ``--address``: where the episodes run (:func:`make_backend`)."""
    parser.add_argument("--jobs", type=positive_int, default=max(1, os.cpu_count() or 1),
                        help="worker processes (with --backend ray and no --address: CPUs of the local Ray instance)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local",
                        help="local: --jobs worker processes here; ray: Ray tasks (the ray extra), on a local Ray "
                             "instance with --jobs CPUs or on the cluster at --address; the results are the same")
    parser.add_argument("--address", default=None,
                        help="with --backend ray: the cluster to use ('auto', or HOST:PORT from `ray start --head`)")


def check_jobs(args: argparse.Namespace) -> None:
    """Raises ValueError unless ``--jobs`` is at least 1."""
    if args.jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {args.jobs}")


def make_backend(args: argparse.Namespace):
    """The backend ``--backend`` / ``--address`` / ``--jobs`` name (see :func:`add_parallel_options`)."""
    from superex_deploy.parallel import LocalBackend, RayBackend

    check_jobs(args)
    if args.backend == "ray":
        return RayBackend(address=args.address, num_cpus=None if args.address else args.jobs)
    if args.address is not None:
        raise ValueError("--address needs --backend ray")
    return LocalBackend(args.jobs)


# Noise of the simulated robot: off unless asked for, so the paper's protocol stays as it is.
MAX_POSE_SIGMA_M, MAX_POSE_SIGMA_DEG, MAX_LIDAR_SIGMA_M = 1.0, 45.0, 1.0
SPAD_NOISE_CHOICES = ("off", "realistic", "low")


def add_noise_options(parser: argparse.ArgumentParser) -> None:
    """``--pose-noise``, ``--lidar-noise`` and ``--spad-noise`` (:func:`noise_options` parses and checks them)."""
    parser.add_argument("--pose-noise", default=None, metavar="SIGMA_M,SIGMA_DEG",
                        help="localisation error: white jitter of SIGMA_M metres (per axis) and SIGMA_DEG degrees, "
                             "plus a bounded drift with the distance driven (superex_deploy.sim.noise.pose); the "
                             "robot then moves continuously and follows each path from where it believes it is. "
                             "0,0: off (the default)")
    parser.add_argument("--lidar-noise", default=None, metavar="SIGMA_M[,DROPOUT,SPURIOUS]",
                        help="LiDAR range noise of SIGMA_M metres, with dropouts and spurious short returns at "
                             "DROPOUT and SPURIOUS per ray (default 0.01 and 0.001; superex_deploy.sim.noise.lidar). "
                             "The explorer's map is calibrated to SIGMA_M (OccupancyConfig.range_sigma_m), as a "
                             "robot's would be to its LiDAR. 0: off (the default)")
    parser.add_argument("--spad-noise", default="off", choices=SPAD_NOISE_CHOICES,
                        help="the SPAD LiDAR's photon budget (superex_deploy.spad_types.SPAD_PRESETS): off (the "
                             "paper's noise-free model), realistic (indoors), low (weak laser, daylight); the "
                             "onboard detection threshold follows it. Needs --spad")


def _numbers(option: str, text: str, shape: str, counts: tuple[int, ...]) -> list[float]:
    parts = [part.strip() for part in str(text).split(",")]
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) not in counts or not all(value == value and abs(value) != float("inf") for value in values):
        raise ValueError(f"{option} takes {shape} (finite numbers separated by commas), got {text!r}")
    return values


def parse_pose_noise(text: Optional[str]) -> Optional[tuple[float, float]]:
    """``"SIGMA_M,SIGMA_DEG"`` -> ``(sigma_m, sigma_deg)``; None for None or all zeros (off).

    Raises:
        ValueError: not two numbers, or a sigma outside ``[0, MAX_POSE_SIGMA_M]`` m / ``[0, MAX_POSE_SIGMA_DEG]``
            degrees.
    """
    if text is None:
        return None
    sigma_m, sigma_deg = _numbers("--pose-noise", text, "SIGMA_M,SIGMA_DEG", (2,))
    if not 0.0 <= sigma_m <= MAX_POSE_SIGMA_M:
        raise ValueError(f"--pose-noise: SIGMA_M must lie in [0, {MAX_POSE_SIGMA_M:g}] metres, got {sigma_m:g}")
    if not 0.0 <= sigma_deg <= MAX_POSE_SIGMA_DEG:
        raise ValueError(f"--pose-noise: SIGMA_DEG must lie in [0, {MAX_POSE_SIGMA_DEG:g}] degrees, got {sigma_deg:g}")
    return None if sigma_m == 0.0 and sigma_deg == 0.0 else (sigma_m, sigma_deg)


def parse_lidar_noise(text: Optional[str]) -> Optional[tuple[float, float, float]]:
    """``"SIGMA_M"`` or ``"SIGMA_M,DROPOUT,SPURIOUS"`` -> ``(sigma_m, dropout, spurious)``; None for None, ``"0"``
    or all zeros (off). SIGMA_M alone takes the default rates (:meth:`LidarNoise.from_sigma
    <superex_deploy.sim.noise.lidar.LidarNoise.from_sigma>`).

    Raises:
        ValueError: not one or three numbers, a sigma outside ``[0, MAX_LIDAR_SIGMA_M]``, a probability outside
            ``[0, 1)``.
    """
    from superex_deploy.sim.noise.lidar import DEFAULT_DROPOUT_PROB, DEFAULT_SPURIOUS_PROB

    if text is None:
        return None
    values = _numbers("--lidar-noise", text, "SIGMA_M or SIGMA_M,DROPOUT,SPURIOUS", (1, 3))
    if len(values) == 1:
        if values[0] == 0.0:
            return None
        values += [DEFAULT_DROPOUT_PROB, DEFAULT_SPURIOUS_PROB]
    sigma_m, dropout, spurious = values
    if not 0.0 <= sigma_m <= MAX_LIDAR_SIGMA_M:
        raise ValueError(f"--lidar-noise: SIGMA_M must lie in [0, {MAX_LIDAR_SIGMA_M:g}] metres, got {sigma_m:g}")
    for name, value in (("DROPOUT", dropout), ("SPURIOUS", spurious)):
        if not 0.0 <= value < 1.0:
            raise ValueError(f"--lidar-noise: {name} is a probability per ray in [0, 1), got {value:g}")
    return None if sigma_m == dropout == spurious == 0.0 else (sigma_m, dropout, spurious)


def noise_options(args: argparse.Namespace):
    """The noise the command line asks for, checked, as one :class:`~superex_deploy.sim.noise.model.SimNoise`
    (unseeded: an episode seeds it, :meth:`SimNoise.seeded <superex_deploy.sim.noise.model.SimNoise.seeded>`);
    ``noise.settings()`` is what a run records.

    Raises:
        ValueError: a malformed value (see :func:`parse_pose_noise`, :func:`parse_lidar_noise`), or
            ``--spad-noise`` other than off without ``--spad``.
    """
    from superex_deploy.sim.noise.model import SimNoise

    spad_noise = getattr(args, "spad_noise", "off")
    if spad_noise not in SPAD_NOISE_CHOICES:
        raise ValueError(f"--spad-noise must be one of {', '.join(SPAD_NOISE_CHOICES)}, got {spad_noise!r}")
    if spad_noise != "off" and not getattr(args, "spad", False):
        raise ValueError(f"--spad-noise {spad_noise} sets the SPAD LiDAR's photon budget: add --spad")
    return SimNoise.from_sigmas(parse_pose_noise(getattr(args, "pose_noise", None)),
                                parse_lidar_noise(getattr(args, "lidar_noise", None)), spad_noise)


def _live_address(text: str) -> tuple[str, int]:
    from superex_deploy.recording.live import parse_address

    try:
        return parse_address(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (value >= 0.0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a number of seconds >= 0, got {text!r}")
    return value


def _hertz(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (value >= 0.0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a rate in Hz >= 0 (0: as fast as possible), got {text!r}")
    return value


def add_live_options(parser: argparse.ArgumentParser) -> None:
    """``--live [HOST:PORT]`` (a Foxglove WebSocket of the episode's topics while it runs; default address
    127.0.0.1:8765), ``--live-every SECONDS`` (the maps' rate on it, in the observations' seconds), ``--live-pace
    HZ`` (how fast the steps go while served; default None: at the observations' stamps in real time) and
    ``--live-hold SECONDS`` (how long the last state stays served after the run; default
    :data:`~superex_deploy.recording.live.DEFAULT_HOLD_S`)."""
    from superex_deploy.recording.live import DEFAULT_ADDRESS, DEFAULT_HOLD_S

    parser.add_argument("--live", nargs="?", const=DEFAULT_ADDRESS, default=None, type=_live_address,
                        metavar="HOST:PORT",
                        help="serve the map, scan, pose, path, goal, prediction and SPAD evidence live on a Foxglove "
                             "WebSocket while the episode runs (ROS 2 messages, the topics of --record; open "
                             f"ws://{DEFAULT_ADDRESS[0]}:{DEFAULT_ADDRESS[1]} in Foxglove); default address "
                             f"{DEFAULT_ADDRESS[0]}:{DEFAULT_ADDRESS[1]}, port 0: any free port; needs the live "
                             "extra: pip install 'superex[live]'")
    parser.add_argument("--live-every", type=_seconds, default=0.5, metavar="SECONDS",
                        help="with --live: publish the maps, the prediction, the evidence and the SPAD frame at most "
                             "once per this many seconds of simulated time (and at the last step; 0: every step); "
                             "the small topics go out every step (default 0.5)")
    parser.add_argument("--live-pace", type=_hertz, default=None, metavar="HZ",
                        help="with --live: run at most this many steps a second, so that a viewer can follow (0: as "
                             "fast as possible, as without --live); default: the observations' clock in real time: a "
                             "simulated episode at its sensor's rate (one step per 0.1 s of simulated time: 10 Hz), "
                             "a replay at its recording's stamps")
    parser.add_argument("--live-hold", type=_seconds, default=DEFAULT_HOLD_S, metavar="SECONDS",
                        help="with --live: once the run is over (its outputs written), serve its last state this many "
                             "seconds more, also to a client that connects meanwhile; Ctrl-C ends it at once (0: stop "
                             f"with the run; default {DEFAULT_HOLD_S:g}). No client holds the command: one that stops "
                             "reading loses messages, and is not waited for at the end")
