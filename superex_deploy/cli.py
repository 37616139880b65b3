"""Command-line interface: ``superex <command> ...``.

Each command lives in its own module under :mod:`superex_deploy.commands` with two functions,
``add_arguments(parser)`` and ``run(args) -> int``. Other installed packages add commands through the
entry-point group ``superex.commands`` (name -> module with the same two functions): that is how the torch-side
``superex train`` and ``superex export`` appear when the ``train`` extra is installed, while this package never
imports torch or :mod:`superex_train` itself.

Exit codes (the same for every command): 0 done; 1 a result that is not the expected one (``superex replay``: the
goals differ, or the recording was cut short), or an unexpected error (with its traceback); 2 a refused argument or
input, said in one line (``superex CMD: error: ...``; argparse's usage errors too); 130 stopped by SIGINT (Ctrl-C)
and 143 by SIGTERM, as a shell reports a process the signal ended, after one line on stderr saying what was kept.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from importlib.metadata import entry_points

COMMANDS = {
    "scan": "Simulate one SPAD scan on a map and write a figure of it",
    "explore": "Run one exploration episode and write metrics, a final plot and a GIF",
    "benchmark": "Run the exploration benchmark (maps x start poses x planners) in parallel",
    "replay": "Rerun the onboard explorer on a recorded episode (MCAP) and compare its goals",
    "convert-recording": "Rewrite a recording (MCAP) of an earlier format into the one superex replay reads",
    "offline": "Run the explorer open-loop on a robot's bag (ROS 1, ROS 2 or MCAP): map, goals, finished, timings",
    "node": "Run the ROS 2 exploration node on DDS (no ROS install): map, scans, tf in; Nav2 goals out",
    "robot-sim": "Run a simulated ROS 2 robot on DDS (LiDAR, SLAM stand-in, Nav2-like follower) for superex node",
    "warmup": "Compile the numba kernels once (cached on disk) and check the models load",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="superex", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help_text in COMMANDS.items():
        module = importlib.import_module(f"superex_deploy.commands.{name.replace('-', '_')}")
        command_parser = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(command_parser)
        command_parser.set_defaults(_module=module)
    for entry in sorted(entry_points(group="superex.commands"), key=lambda e: e.name):
        if entry.name in COMMANDS:
            continue
        try:
            module = entry.load()
        except ImportError as error:  # e.g. the train extra's torch is missing: say so instead of crashing
            sub.add_parser(entry.name, help=f"unavailable ({error}); install the extra that provides it")
            continue
        command_parser = sub.add_parser(entry.name, help=module.__doc__.strip().splitlines()[0]
                                        if module.__doc__ else entry.name)
        module.add_arguments(command_parser)
        command_parser.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``superex ARGV`` and return its exit code (see the module docstring); SIGINT and SIGTERM become
    :class:`~superex_deploy.parallel.Interrupted` while it runs."""
    from superex_deploy.parallel import interruption_in, stop_signals

    args = None
    with stop_signals():
        try:
            try:
                args = build_parser().parse_args(argv)
            except SystemExit as usage:  # --help (0), or a usage error argparse has printed (2)
                return 0 if usage.code is None else usage.code if isinstance(usage.code, int) else 2
            return _run(args)
        except KeyboardInterrupt as stop:  # Interrupted, or a Ctrl-C that came before the handlers
            return _stopped(args, stop)
        except Exception as error:  # a signal raised inside a C callback arrives wrapped (parallel.interruption_in)
            stop = interruption_in(error)
            if stop is None:
                raise
            return _stopped(args, stop)


def _stopped(args, stop: BaseException) -> int:
    """The one stderr line of a run a signal stopped; its exit code (128 + the signal's number)."""
    name, code = getattr(stop, "signal_name", "SIGINT"), getattr(stop, "exit_code", 130)
    kept = getattr(stop, "kept", "")
    command = "superex" if args is None else f"superex {args.command}"
    print(f"{command}: stopped by {name}{'; ' + kept if kept else ''}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    if not hasattr(args, "_module"):
        print(f"superex {args.command}: this command is unavailable; see `superex --help`", file=sys.stderr)
        return 2
    try:
        return int(args._module.run(args) or 0)
    except ValueError as error:
        print(f"superex {args.command}: error: {error}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as error:
        extra = {"torch": "train", "onnx": "train", "onnxscript": "train", "gymnasium": "gym",
                 "cyclonedds": "ros2"}.get(
            (error.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"superex {args.command}: error: this command needs {error.name!r}, which is not installed: "
              f"pip install 'superex[{extra}]'", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
