"""Files written whole or not at all: a reader (or a run resumed after a kill) never sees half a file."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Union

__all__ = ["TEMPORARY_SUFFIX", "write_atomically"]

TEMPORARY_SUFFIX = ".part"
"""Appended to a file's name while it is being written (``results.json.part``)."""


def write_atomically(path: Union[str, os.PathLike], content: Union[str, bytes, Callable[[Path], None]]) -> Path:
    """Write ``path`` through a temporary file beside it (``PATH.part``), synced to disk, then renamed over it.

    Args:
        path: the file to write (its folder must exist).
        content: text, bytes, or a function that writes the temporary file at the path it is given (e.g.
            ``lambda part: torch.save(state, part)``).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OSError: or whatever else writing raised, unchanged; the temporary file is removed and ``path`` keeps its
            previous content.
    """
    path = Path(path)
    part = path.with_name(path.name + TEMPORARY_SUFFIX)
    try:
        if isinstance(content, str):
            part.write_text(content)
        elif isinstance(content, (bytes, bytearray, memoryview)):
            part.write_bytes(content)
        else:
            content(part)
        with open(part, "rb+") as written:
            os.fsync(written.fileno())
        os.replace(part, path)
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    return path
