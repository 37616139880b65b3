"""Command-line options shared by several commands (``superex benchmark`` and its paper suite, ``superex explore``,
``superex train data``), declared and checked in one place."""

from __future__ import annotations

import argparse

__all__ = ["make_backend"]


def make_backend(args: argparse.Namespace):
    """The backend ``--backend`` / ``--address`` / ``--jobs`` name."""
    from superex_deploy.parallel import LocalBackend, RayBackend

    if args.jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
    if args.backend == "ray":
        return RayBackend(address=args.address, num_cpus=None if args.address else args.jobs)
    if args.address is not None:
        raise ValueError("--address needs --backend ray")
    return LocalBackend(args.jobs)
