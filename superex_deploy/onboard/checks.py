"""The checks every planner config runs on its fields when it is built, so that a bad option stops a run
with one clear error naming it.

A planner's options reach its config from Python (``make_planner("upen", rrt_samples=100)``) or from the command
line, where ``--planner-option FIELD=VALUE`` turns numbers and true / false into Python values and leaves any other
text a string (``"x"``, ``"none"``); ``"nan"`` and ``"inf"`` become floats. Each check takes any of those and
either returns the field's value in its one type (integral floats such as ``2500.0`` become ``int``, integers
become ``float`` where a real is expected) or raises one ``ValueError`` that names the field, says what it takes
and shows what it got. No check lets a non-finite number through: a count or a distance of ``inf`` is never a
setting. A config whose options were retired (:func:`retires`) refuses them by name, and one whose options counted
cells and now take metres (:func:`renames`) names the new field; :func:`from_cells` converts a recorded config of
the old names with its grid's cell size, :func:`nested_configs` turns a recorded config's nested objects back into
their dataclasses, and :func:`in_cells`, :func:`cells_at_least` and :func:`cells_within` give a length's cells.
"""

from __future__ import annotations

import functools
import dataclasses
import math
import numbers
import typing
from types import MappingProxyType
from typing import Mapping, Optional

__all__ = ["check_int", "check_real", "check_choice", "check_instance", "retires", "without_retired", "renames",
           "from_cells", "nested_configs", "in_cells", "cells_at_least", "cells_within"]


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


def _refuse_retired(config_class, names, advice: str) -> None:
    named = sorted(set(names) & set(config_class.RETIRED))
    if named:
        many = len(named) > 1
        raise ValueError(f"{config_class.__name__}: the option{'s' if many else ''} "
                         f"{', '.join(repr(name) for name in named)} {'were' if many else 'was'} retired (measured, "
                         f"with a negative result: {config_class.RETIRED_WHERE}); {advice}")


def retires(where: str, **old_defaults):
    """Class decorator of a config dataclass whose options ``old_defaults`` (name: the value it had by default)
    were retired after the measurement ``where`` (a documentation page): building the class with one of them
    raises one ``ValueError`` naming it as retired, instead of Python's ``TypeError`` for an unknown argument. The
    class keeps them as ``RETIRED`` for :func:`without_retired`."""
    def decorate(cls):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            _refuse_retired(cls, kwargs, "leave it out")
            init(self, *args, **kwargs)

        cls.__init__ = __init__
        cls.RETIRED = MappingProxyType(dict(old_defaults))
        cls.RETIRED_WHERE = where
        return cls
    return decorate


def without_retired(config_class, values: Mapping[str, object]) -> dict:
    """``values`` (the fields of a configuration recorded by an earlier version, e.g. in a recording) without the
    options ``config_class`` retired that hold their old default: with those the recorded run behaved as this
    version does.

    Raises:
        ValueError: a retired option at another value (a run this version cannot reproduce), named.
    """
    retired = getattr(config_class, "RETIRED", {})
    changed = [name for name in values if name in retired and values[name] != retired[name]]
    if changed:
        _refuse_retired(config_class, changed, "this version cannot reproduce a run that used it")
    return {name: value for name, value in values.items() if name not in retired}


UNITS = {1: "metres", 2: "square metres"}
"""The unit of a renamed field, by the power of the cell size its old cell count is multiplied with."""


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


def renames(**new_fields):
    """Class decorator of a config dataclass whose options counted cells and now take metres: ``new_fields`` maps
    each old name to ``(new name, power)``, the new value being the old one times the cell size to that power (1: a
    length in metres, 2: an area in square metres). Building the class with an old name raises one ``ValueError``
    naming the new field, instead of Python's ``TypeError`` for an unknown argument, so a setting never silently
    changes meaning with the grid. The class keeps them as ``RENAMED`` for :func:`from_cells`."""
    def decorate(cls):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            named = sorted(set(kwargs) & set(new_fields))
            if named:
                said = "; ".join(f"{old!r} was renamed to {new_fields[old][0]} ({UNITS[new_fields[old][1]]}: the old "
                                 f"value times the cell size{'' if new_fields[old][1] == 1 else ' squared'})"
                                 for old in named)
                raise ValueError(f"{cls.__name__}: the option {said}")
            init(self, *args, **kwargs)

        cls.__init__ = __init__
        cls.RENAMED = MappingProxyType(dict(new_fields))
        return cls
    return decorate


def from_cells(config_class, values: Mapping[str, object], resolution_m: float) -> dict:
    """``values`` (the fields of a configuration recorded by an earlier version, e.g. in a recording) with every option
    ``config_class`` renamed (:func:`renames`) converted to its new field on a grid of ``resolution_m`` metres per
    cell; the converted value gives back the recorded cell count (:func:`cells_at_least`, :func:`cells_within`).

    Raises:
        ValueError: an old name beside its new one, or an old value that is not a number >= 0, named.
    """
    renamed = getattr(config_class, "RENAMED", {})
    converted = dict(values)
    for old, (new, power) in renamed.items():
        if old not in converted:
            continue
        if new in converted:
            raise ValueError(f"{config_class.__name__}: both {old!r} and its new name {new!r} are given")
        count = check_real(f"{config_class.__name__}: {old}", converted.pop(old), 0.0)
        converted[new] = round(count * float(resolution_m) ** power, 12)
    return converted


def nested_configs(config_class, values: Mapping[str, object]) -> dict:
    """``values`` (the fields of a ``config_class`` recorded as JSON, e.g. a recording's ``planner_config``) with each
    object that holds a field whose type is a config dataclass (``VisibilityConfig``, ``Optional[VisibilityConfig]``)
    made that dataclass again (its own nested objects too); the other values as they are.

    Raises:
        ValueError: a nested object with fields its dataclass does not take, named.
    """
    hints = typing.get_type_hints(config_class)
    converted = dict(values)
    for name, value in values.items():
        if not isinstance(value, Mapping) or name not in hints:
            continue
        kinds = [kind for kind in (typing.get_args(hints[name]) or (hints[name],)) if dataclasses.is_dataclass(kind)]
        if len(kinds) == 1:
            try:
                converted[name] = kinds[0](**nested_configs(kinds[0], value))
            except TypeError as error:
                raise ValueError(f"{config_class.__name__}.{name}: {error}") from None
    return converted
