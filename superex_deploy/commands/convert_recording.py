"""``superex convert-recording OLD.mcap NEW.mcap``: rewrite a recording of an earlier format (``superex explore
--record`` or ``superex node`` of a version up to 0.2) into the format ``superex replay`` reads: its metadata
converted (:mod:`superex_deploy.recording.convert`), every message copied as it is. A file that is no recording, or
one already of this format, is refused in one line."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="an .mcap file of an earlier recording format")
    parser.add_argument("out", type=Path, help="the converted .mcap file to write (its folder must exist)")


def run(args: argparse.Namespace) -> int:
    from superex_deploy.recording.convert import convert_recording
    from superex_deploy.recording.schemas import FORMAT_VERSION

    messages, error = convert_recording(args.recording, args.out)
    if error is not None:
        print(f"superex convert-recording: warning: {args.recording}: {error}; the messages before it are copied")
    print(f"wrote {args.out}: {args.recording} in recording format {FORMAT_VERSION!r}, {messages} messages copied")
    return 0
