"""Command-line options shared by several commands (``superex explore``, ``superex benchmark`` and its paper suite,
``superex train data``): each declared, parsed and checked in one place.

Every value is checked where it enters, before a command creates any file or folder: numbers and lists by their
argparse ``type`` (the error names the option: ``argument --seed: must be an integer >= 0, got '-5'``), output
paths by :func:`check_output_folder` and :func:`check_output_file`, start cells by :func:`resolve_start`.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Iterable, Optional

from superex_deploy.pipeline import DEFAULT_PROFILE, PROFILES

__all__ = ["add_planner_option", "planner_options", "add_profile_option", "add_parallel_options", "check_jobs",
           "make_backend", "positive_int", "non_negative_int", "name_list", "eval_maps", "check_output_folder",
           "check_output_file", "folders_made", "resolve_start", "settings_differences"]


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


def resolve_start(map_arg: str, grid, start_index: int, pose: Optional[tuple[int, int]],
                  require_valid: bool = True) -> tuple[int, int]:
    """The start cell ``--start`` / ``--pose`` name on the map ``--map`` loaded as ``grid``.

    Args:
        map_arg: ``--map`` as given (a bundled map's name, or a file).
        grid: the loaded map.
        start_index: ``--start``, the index of a bundled eval map's start pose.
        pose: ``--pose ROW COL``, or None.
        require_valid: refuse a ``--pose`` outside the valid (inside-the-building) area.

    Raises:
        ValueError: a pose off the map, in a wall or (``require_valid``) outside the valid area; a ``--start``
            out of range; a map without start poses (a file, a train map) and no ``--pose``.
    """
    from superex_deploy.maps import list_maps, start_poses

    if pose is not None:
        start = grid.check_pose(pose)
        if require_valid and not grid.valid[start]:
            raise ValueError(f"--pose {start[0]} {start[1]} lies outside the valid (inside-the-building) area of map "
                             f"{grid.name!r}: nothing there could be explored")
        return start
    if str(map_arg) not in list_maps("eval"):
        raise ValueError(f"--map {map_arg} has no start poses (only the bundled eval maps do): give the start cell "
                         f"with --pose ROW COL")
    poses = start_poses(grid.name)
    if not 0 <= start_index < len(poses):
        raise ValueError(f"--start must lie in 0..{len(poses) - 1}, got {start_index}")
    return poses[start_index]


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
    parser.add_argument("--planner-option", action="append", default=[], metavar="FIELD=VALUE",
                        help="override a field of the planner's config, e.g. distance=euclidean for MapEx's "
                             "straight-line divisor (repeatable; numbers, true/false and none are converted)")


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


def add_profile_option(parser: argparse.ArgumentParser) -> None:
    """``--profile NAME`` (default None: :func:`superex_deploy.pipeline.resolve_profile` chooses)."""
    parser.add_argument("--profile", choices=tuple(PROFILES), default=None,
                        help="real-time settings of the onboard pipeline (superex_deploy.pipeline.PROFILES): "
                             "'full' runs everything inside each step, 'realtime' the measured asynchronous, cropped, "
                             f"one-member prediction (benchmarks/realtime). Default: {DEFAULT_PROFILE}, or full for "
                             "planners that read the ensemble's variance (mapex, upen) with a LaMa predictor")


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
