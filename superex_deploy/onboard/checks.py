"""The checks every planner config runs on its fields when it is built, so that a bad option stops a run
with one clear error naming it.

A planner's options reach its config from Python (``make_planner("upen", rrt_samples=100)``) or from the command
line, where ``--planner-option FIELD=VALUE`` turns numbers and true / false into Python values and leaves any other
text a string (``"x"``, ``"none"``); ``"nan"`` and ``"inf"`` become floats. Each check takes any of those and
either returns the field's value in its one type (integral floats such as ``2500.0`` become ``int``, integers
become ``float`` where a real is expected) or raises one ``ValueError`` that names the field, says what it takes
and shows what it got. No check lets a non-finite number through: a count or a distance of ``inf`` is never a
setting. :func:`in_cells`, :func:`cells_at_least` and :func:`cells_within` give a length's cells.
"""

from __future__ import annotations

import math
import numbers
from typing import Optional

__all__ = ["check_int", "check_real", "check_choice", "check_instance", "in_cells", "cells_at_least", "cells_within"]


def _number(value) -> Optional[float]:
    """``value`` as a float if it is a real number (not a bool, not a string) that a float holds, else None."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:  # an integer beyond float's range
        return None


def check_int(name: str, value, low: int, high: Optional[int] = None) -> int:
    """An integer in ``[low, high]`` (``high`` None: no upper bound); integral floats are accepted.

    Raises:
        ValueError: anything else (a bool, a string, a fraction, a non-finite number, out of range).
    """
    integer: Optional[int] = None
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        integer = int(value)
    else:
        number = _number(value)
        if number is not None and math.isfinite(number) and number == int(number):
            integer = int(number)
    if integer is None or integer < low or (high is not None and integer > high):
        upper = "" if high is None else f" and <= {high}"
        raise ValueError(f"{name} must be an integer >= {low}{upper}, got {value!r}")
    return integer


def check_real(name: str, value, low: Optional[float] = None, high: Optional[float] = None, *,
               low_open: bool = False, high_open: bool = False, allow_none: bool = False) -> Optional[float]:
    """A finite real number in the interval from ``low`` to ``high`` (None: unbounded; ``*_open``: the bound itself
    is excluded), or None when ``allow_none``.

    Raises:
        ValueError: anything else (a bool, a string, NaN, an infinity, out of range).
    """
    if value is None and allow_none:
        return None
    number = _number(value)
    ok = number is not None and math.isfinite(number)
    if ok and low is not None:
        ok = number > low if low_open else number >= low
    if ok and high is not None:
        ok = number < high if high_open else number <= high
    if not ok:
        if low is not None and high is not None:
            wanted = f"lie in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        elif low == 0 and low_open:
            wanted = "be positive and finite"
        elif low is not None:
            wanted = f"be finite and {'>' if low_open else '>='} {low:g}"
        else:
            wanted = "be a finite number"
        raise ValueError(f"{name} must {'be None or ' if allow_none else ''}{wanted}, got {value!r}")
    return number


def check_choice(name: str, value, choices: tuple[str, ...]) -> str:
    """One of the strings ``choices``.

    Raises:
        ValueError: anything else.
    """
    if not isinstance(value, str) or value not in choices:
        listed = ", ".join(repr(c) for c in choices[:-1]) + f" or {choices[-1]!r}" if len(choices) > 1 \
            else repr(choices[0])
        raise ValueError(f"{name} must be {listed}, got {value!r}")
    return value


def check_instance(name: str, value, kind: type, allow_none: bool = False):
    """An instance of ``kind`` (or None when ``allow_none``).

    Raises:
        ValueError: anything else.
    """
    if (value is None and allow_none) or isinstance(value, kind):
        return value
    raise ValueError(f"{name} must be a {kind.__name__}{' or None' if allow_none else ''}, got "
                     f"{type(value).__name__} {value!r}")


def in_cells(quantity: float, cell: float) -> float:
    """``quantity / cell`` (a length in metres and the cell size, or an area and the cell's area) rounded to 9
    decimals: a setting given as a multiple of the cell size is that many cells exactly (``1.0 / 0.1`` is
    9.999999999999998 in floating point)."""
    return round(float(quantity) / float(cell), 9)


def cells_at_least(quantity: float, cell: float) -> int:
    """The fewest whole cells of size ``cell`` (metres, or square metres for an area) that reach ``quantity`` (same
    unit, >= 0): ``ceil``, exact at multiples of the cell (1.0 m at 0.1 m is 10 cells, at 0.05 m 20)."""
    return int(math.ceil(in_cells(quantity, cell)))


def cells_within(quantity: float, cell: float) -> int:
    """The most whole cells of size ``cell`` that fit in ``quantity`` (same unit, >= 0): ``floor``, exact at multiples
    of the cell (0.3 m at 0.1 m is 3 cells, at 0.05 m 6)."""
    return int(math.floor(in_cells(quantity, cell)))
