"""Limits on what enters the messages (map size, time stamps, headings) and the checks that apply them."""

from __future__ import annotations

import math
import os

import numpy as np

__all__ = ["MAX_MAP_CELLS", "MAX_MAP_CELLS_ENV", "MIN_RESOLUTION_M", "MAX_STAMP_S", "MAX_ABS_YAW", "max_map_cells",
           "check_map_size", "check_stamp", "check_finite", "check_point_xy", "check_float32", "check_heading"]

MAX_MAP_CELLS = 25_000_000
"""Default limit on a map's cells (rows x cols); see :func:`max_map_cells`."""
MAX_MAP_CELLS_ENV = "SUPEREX_MAX_MAP_CELLS"
"""The environment variable that replaces :data:`MAX_MAP_CELLS` (a positive integer)."""
MIN_RESOLUTION_M = 1e-3
"""The finest map resolution accepted (metres per cell)."""
MAX_STAMP_S = float(2 ** 31 - 1)
"""The latest time stamp accepted (seconds): the largest ``int32`` seconds of a ROS 2 time."""
MAX_ABS_YAW = 1e6
"""The largest heading magnitude accepted (radians) before normalisation to ``(-pi, pi]``."""


def check_finite(name: str, value) -> float:
    """``value`` as a finite Python float; ``name`` names it in the error.

    Raises:
        ValueError: ``value`` is not a real number, or not finite.
    """
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def check_point_xy(name: str, value) -> tuple[float, float]:
    """A finite map-frame point ``(x, y)`` (metres) as a tuple of floats."""
    try:
        point = tuple(check_finite(name, v) for v in value)
    except TypeError:
        raise ValueError(f"{name} must be an (x, y) pair, got {value!r}") from None
    if len(point) != 2:
        raise ValueError(f"{name} must be an (x, y) pair, got {value!r}")
    return point


def check_float32(name: str, value) -> float:
    """``value`` rounded to float32, as a Python float (finite)."""
    value = check_finite(name, value)
    with np.errstate(over="ignore"):  # too large for float32: inf, refused below
        rounded = np.float32(value)
    if not np.isfinite(rounded):
        raise ValueError(f"{name} = {value} does not fit a float32")
    return float(rounded)


def max_map_cells() -> int:
    """The limit on a map's cells: ``$SUPEREX_MAX_MAP_CELLS`` if set, else :data:`MAX_MAP_CELLS`.

    Raises:
        ValueError: the environment variable is set but not a positive integer.
    """
    text = os.environ.get(MAX_MAP_CELLS_ENV, "").strip()
    if not text:
        return MAX_MAP_CELLS
    try:
        limit = int(text)
    except ValueError:
        limit = 0
    if limit < 1:
        raise ValueError(f"{MAX_MAP_CELLS_ENV} must be a positive integer (a number of map cells), got {text!r}")
    return limit


def check_map_size(shape, resolution_m: float, what: str = "the map") -> None:
    """Refuse a map of more than :func:`max_map_cells` cells or finer than :data:`MIN_RESOLUTION_M`.

    Args:
        shape: ``(rows, cols)`` (positive integers).
        resolution_m: metres per cell (finite, > 0).
        what: how the message names the map.

    Raises:
        ValueError: naming the limit and how to change it.
    """
    rows, cols = (int(n) for n in shape)
    limit = max_map_cells()
    if rows * cols > limit:
        raise ValueError(f"{what} has {rows} x {cols} = {rows * cols:,} cells, more than the limit of {limit:,} "
                         f"cells; set the environment variable {MAX_MAP_CELLS_ENV} to raise it (memory grows by "
                         f"about 100 bytes per cell)")
    if resolution_m < MIN_RESOLUTION_M:
        raise ValueError(f"{what} has a resolution of {resolution_m} m per cell, finer than the limit of "
                         f"{MIN_RESOLUTION_M} m: the planner's neighbourhoods (robot radius, wall-cost range) are "
                         f"counted in cells and would not fit in memory")


def check_stamp(name: str, value) -> float:
    """A time stamp (seconds) as a float: finite, ``>= 0`` and at most :data:`MAX_STAMP_S`.

    Raises:
        ValueError: any other value.
    """
    value = check_finite(name, value)
    if not 0.0 <= value <= MAX_STAMP_S:
        raise ValueError(f"{name} must lie in [0, {MAX_STAMP_S:.0f}] seconds (a ROS time: int32 seconds since "
                         f"the epoch), got {value}")
    return value


def check_heading(name: str, value) -> float:
    """A yaw (radians) normalised to ``(-pi, pi]``; one there already is returned unchanged."""
    value = check_finite(name, value)
    if -math.pi < value <= math.pi:
        return value
    if abs(value) > MAX_ABS_YAW:
        raise ValueError(f"{name} must satisfy |yaw| <= {MAX_ABS_YAW:g} rad (beyond, a float64 angle has no "
                         f"usable direction), got {value}")
    value = math.remainder(value, math.tau)  # exact; in [-pi, pi]
    return math.pi if value <= -math.pi else value
