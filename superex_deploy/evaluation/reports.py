"""A benchmark's outputs: Markdown tables, JSON and figures, each file written whole or not at all
(:func:`superex_deploy.files.write_atomically`: an interrupted run never leaves half a report beside the
committed ones)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence, Union

from superex_deploy.files import write_atomically

__all__ = ["markdown_table", "write_text", "write_json", "read_json", "pyplot", "save_figure"]

PathLike = Union[str, Path]


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]], align: Union[str, Sequence[str]] = "-"
                   ) -> list[str]:
    """The lines of a Markdown table (no trailing newlines): ``| a | b |``, the rule, one line per row.

    Args:
        header: the column titles.
        rows: the cells of each row, already formatted (``str()`` is applied to each).
        align: one rule cell for every column (``"-"``, ``"---:"``...) or one per column; ``"-"`` is written
            ``---``.
    """
    rules = [align] * len(header) if isinstance(align, str) else list(align)
    if len(rules) != len(header):
        raise ValueError(f"{len(rules)} alignments for {len(header)} columns")
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" if r == "-" else r for r in rules) + "|"]
    for row in rows:
        row = [str(cell) for cell in row]
        if len(row) != len(header):
            raise ValueError(f"a row of {len(row)} cells in a table of {len(header)} columns: {row}")
        lines.append("| " + " | ".join(row) + " |")
    return lines


def write_text(path: PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically, its folder made first; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_atomically(path, text)


def write_json(path: PathLike, data: Any, indent: Optional[int] = 1, newline: bool = False) -> Path:
    """Write ``json.dumps(data, indent=indent)`` (plus a final newline with ``newline``) to ``path`` atomically,
    its folder made first; returns the path. NaN is written as JSON's ``NaN`` extension, as :mod:`json` does."""
    return write_text(path, json.dumps(data, indent=indent) + ("\n" if newline else ""))


def read_json(path: PathLike) -> Any:
    """The JSON in ``path``."""
    return json.loads(Path(path).read_text())


def pyplot():
    """:mod:`matplotlib.pyplot` on the Agg backend (figures to files, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: PathLike, dpi: int = 90, close: bool = True) -> Path:
    """Save the matplotlib figure ``fig`` to ``path`` atomically (its format from the suffix), its folder made
    first; closes it unless ``close`` is False."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, lambda part: fig.savefig(part, dpi=dpi, format=path.suffix.lstrip(".") or None))
    if close:
        pyplot().close(fig)
    return path
