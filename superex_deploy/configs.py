"""Configurations as JSON: one way for every configuration dataclass to write itself out and to be read back.

A configuration class takes :class:`JsonConfig` as its base (``class MotionConfig(JsonConfig)`` under
``@dataclass(frozen=True)``) and gains :meth:`~JsonConfig.to_json` and :meth:`~JsonConfig.from_json`, symmetric:
``type(c).from_json(c.to_json()) == c`` for every configuration ``c``, also through ``json.dumps`` and
``json.loads`` (``tests/test_config_json.py`` checks it for each class). :func:`to_json` and :func:`from_json` do
the same for any dataclass.

What is written: a dataclass is an object of its ``__init__`` fields (a nested configuration by its own
``to_json``), a tuple or list a list, an enum its value, a numpy number a Python number, a path a string; None,
booleans, numbers and strings stay as they are. What is read is strict: an object with a field the class does not
have is refused with one ``ValueError`` that names the class and the field; a field left out takes its default
(one without a default is refused, named); a value of the wrong type or range gets the class's own error from its
``__post_init__``. Values are rebuilt by the field's type annotation (``typing.get_type_hints``): a nested
configuration (also ``Optional[...]``) from its object, a ``tuple[float, ...]`` or ``tuple[int, int]`` from its
list, an enum from its value.

This module sits in the package's base layer (it imports nothing of the package), so that a configuration of any
layer can take it as its base.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import numbers
import types
import typing
from pathlib import PurePath
from typing import Any, Mapping

import numpy as np

__all__ = ["JsonConfig", "to_json", "from_json"]


def to_json(config) -> dict:
    """The ``__init__`` fields of the dataclass instance ``config`` as JSON values (see the module docstring).

    Raises:
        TypeError: ``config`` is not a dataclass instance, or a field holds a value JSON cannot hold, named.
    """
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        raise TypeError(f"to_json takes a dataclass instance, got {type(config).__name__}")
    return {f.name: _value_to_json(getattr(config, f.name), f"{type(config).__name__}.{f.name}")
            for f in dataclasses.fields(config) if f.init}


def _value_to_json(value, where: str):
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, enum.Enum):
        return _value_to_json(value.value, where)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        own = getattr(value, "to_json", None)
        return own() if callable(own) else to_json(value)
    if isinstance(value, (tuple, list)):
        return [_value_to_json(item, f"{where}[{i}]") for i, item in enumerate(value)]
    if isinstance(value, np.ndarray):
        return _value_to_json(value.tolist(), where)
    if isinstance(value, Mapping):
        return {str(key): _value_to_json(item, f"{where}[{key!r}]") for key, item in value.items()}
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"{where}: a {type(value).__name__} cannot be written as JSON ({value!r:.80})")


def from_json(cls, data: Mapping[str, Any]):
    """The instance of the dataclass ``cls`` that the JSON object ``data`` describes (see the module docstring).

    Raises:
        ValueError: ``data`` is not an object, holds a field ``cls`` does not have, or lacks one without a default
            (each named with the class), or a value the class refuses (its own error).
    """
    name = cls.__name__
    if not isinstance(data, Mapping):
        raise ValueError(f"{name}.from_json takes a JSON object, got {type(data).__name__} {data!r:.80}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [key for key in data if key not in fields]
    if unknown:
        many = len(unknown) > 1
        raise ValueError(f"{name} has no field{'s' if many else ''} {', '.join(repr(k) for k in unknown)} (its "
                         f"fields: {', '.join(fields)})")
    missing = [key for key, f in fields.items() if key not in data and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ValueError(f"{name}.from_json: the field{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(repr(k) for k in missing)} must be given")
    hints = _hints(cls)
    values = {key: _value_from_json(hints.get(key), value) for key, value in data.items()}
    try:
        return cls(**values)
    except TypeError as error:  # a check in __post_init__ that fails on a value of the wrong type
        raise ValueError(f"{name}: {error}") from None


@functools.lru_cache(maxsize=None)
def _hints(cls) -> dict:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an annotation that does not resolve at run time: its values are read as they are
        return {}


def _value_from_json(hint, value):
    """``value`` rebuilt as the type ``hint`` says where it can be; as it is otherwise (the class checks it)."""
    if hint is None or value is None:
        return value
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Union or (hasattr(types, "UnionType") and origin is types.UnionType):
        for kind in args:
            if kind is not type(None) and _fits(kind, value):
                return _value_from_json(kind, value)
        return value
    if origin is tuple or hint is tuple:
        if not isinstance(value, (list, tuple)):
            return value
        if not args:  # a bare ``tuple``: lists inside it become tuples too
            return tuple(_value_from_json(tuple, item) if isinstance(item, list) else item for item in value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_value_from_json(args[0], item) for item in value)
        if len(args) == len(value):
            return tuple(_value_from_json(kind, item) for kind, item in zip(args, value))
        return tuple(value)
    if origin is list and isinstance(value, list):
        return [_value_from_json(args[0] if args else None, item) for item in value]
    if origin is dict and isinstance(value, Mapping):
        return {key: _value_from_json(args[1] if len(args) == 2 else None, item) for key, item in value.items()}
    if not isinstance(hint, type):
        return value
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, Mapping):
            return value
        own = getattr(hint, "from_json", None)
        return own(value) if callable(own) else from_json(hint, value)
    if issubclass(hint, enum.Enum):
        return _enum(hint, value)
    if issubclass(hint, PurePath) and isinstance(value, str):
        return hint(value)
    return value


def _fits(kind, value) -> bool:
    """Whether ``value`` (a JSON value, not None) has the shape of the type ``kind`` (one member of a union)."""
    origin = typing.get_origin(kind) or kind
    if not isinstance(origin, type):
        return True
    if dataclasses.is_dataclass(origin):
        return isinstance(value, Mapping)
    if issubclass(origin, (tuple, list)):
        return isinstance(value, (list, tuple))
    if issubclass(origin, enum.Enum):
        return isinstance(_enum(origin, value), origin)
    if origin is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    return isinstance(value, origin)


def _enum(kind, value):
    """The member of the enum ``kind`` whose value is ``value``, or that ``str`` writes as ``value``
    (``"GraphOptimization.ALL"``, as ``RealtimeProfile.to_json`` writes it); ``value`` itself if none is."""
    if isinstance(value, kind):
        return value
    try:
        return kind(value)
    except (ValueError, TypeError):
        pass
    if isinstance(value, str) and value.startswith(f"{kind.__name__}.") and value.split(".", 1)[1] in kind.__members__:
        return kind.__members__[value.split(".", 1)[1]]
    return value


class JsonConfig:
    """Base of a configuration dataclass: :meth:`to_json` and :meth:`from_json` (see the module docstring)."""

    __slots__ = ()

    def to_json(self) -> dict:
        """The configuration's ``__init__`` fields as JSON values (:func:`to_json`)."""
        return to_json(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]):
        """The configuration that ``data`` (what :meth:`to_json` wrote) describes (:func:`from_json`).

        Raises:
            ValueError: a field the class does not have, one without a default left out (named with the class),
                or a value the class refuses (its own error).
        """
        return from_json(cls, data)
