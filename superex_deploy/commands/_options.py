"""Command-line options shared by several commands (``superex explore``, ``superex benchmark`` and its paper suite,
``superex train data``): each declared, parsed and checked in one place."""

from __future__ import annotations

import argparse
import os

from superex_deploy.pipeline import DEFAULT_PROFILE, PROFILES

__all__ = ["add_planner_option", "planner_options", "add_profile_option", "add_parallel_options", "check_jobs",
           "make_backend"]


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
    parser.add_argument("--jobs", type=int, default=max(1, os.cpu_count() or 1),
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
