"""A map that grows: the explorer's grid extends as scans, SPAD frames or SLAM maps reach beyond it, so a robot
entering an unknown building needs no map size in advance (costmap_2d's static layer resizes to the map it is
given the same way).

Before a step integrates anything, the explorer works out the area it may touch (:func:`reach_of`: the pose, every
valid ray up to its range or ``range_max``, the SPAD frame's reach, a SLAM map's known cells: a SLAM package that
publishes a fixed 200 m square with a few metres known, as gmapping does, grows the grid to what is known) and, when that area plus
``margin_m`` is not inside its grid, moves to a larger grid (:func:`grown_frame`) on the same cell lattice: the old
cells keep their values at new indices (:func:`embed`), new cells are unknown. The margin keeps a band of unknown
cells between everything known and the grid's edge, so a frontier is never hidden by the edge. Memory is bounded by
what the robot has seen plus the margin and the growth step; past :func:`~superex_deploy.messages.max_map_cells`
the step is refused before anything is integrated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.messages import MapFrame, Observation, check_map_size, max_map_cells

__all__ = ["MapGrowth", "Regrid", "reach_of", "grown_frame", "regrid_for", "embed"]


@dataclass(frozen=True)
class MapGrowth(JsonConfig):
    """How the explorer's grid grows.

    Attributes:
        margin_m: unknown space kept between the farthest point a step can touch and the grid's edge (metres,
            >= 0).
        chunk_m: a side that must grow grows by at least this much more (metres, >= 0): fewer, larger growths,
            each of which copies the map.
    """

    margin_m: float = 2.0
    chunk_m: float = 5.0

    def __post_init__(self) -> None:
        for name in ("margin_m", "chunk_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value)
                                                                                      and value >= 0.0):
                raise ValueError(f"MapGrowth.{name} must be a finite number of metres >= 0, got {value!r}")


@dataclass(frozen=True)
class Regrid:
    """A move to a larger grid: the new frame and where the old grid lies in it.

    Attributes:
        frame: the new :class:`~superex_deploy.messages.MapFrame`.
        top, left: rows and columns added above and to the left (old cell ``(r, c)`` is new ``(r + top, c +
            left)``).
    """

    frame: MapFrame
    top: int
    left: int

    def cell(self, rc) -> tuple[int, int]:
        """An old cell's indices in the new grid."""
        return int(rc[0]) + self.top, int(rc[1]) + self.left

    def embed(self, array: np.ndarray, fill) -> np.ndarray:
        """``array`` (``[H, W, ...]`` on the old grid) on the new grid, ``fill`` elsewhere (same dtype)."""
        return embed(array, self.frame.shape, self.top, self.left, fill)


def embed(array: np.ndarray, shape: tuple[int, int], top: int, left: int, fill) -> np.ndarray:
    """A new array of ``shape`` (plus ``array``'s trailing axes) holding ``array`` at rows ``top:``, columns
    ``left:``, ``fill`` elsewhere, with ``array``'s dtype.

    Raises:
        ValueError: ``array`` does not fit at that place.
    """
    array = np.asarray(array)
    rows, cols = array.shape[:2]
    if top < 0 or left < 0 or top + rows > shape[0] or left + cols > shape[1]:
        raise ValueError(f"an array of shape {array.shape[:2]} does not fit in {tuple(shape)} at ({top}, {left})")
    out = np.full(tuple(shape) + array.shape[2:], fill, array.dtype)
    out[top:top + rows, left:left + cols] = array
    return out


def reach_of(obs: Observation, spad_reach_m: float = 0.0) -> tuple[float, float, float, float]:
    """``(x_min, y_min, x_max, y_max)`` (metres, map frame) of what ``obs`` can change: its pose, the end of every
    valid ray of its scan (a return, or ``range_max`` for no return; invalid readings are skipped), ``spad_reach_m``
    around the pose when it carries a SPAD frame, and the extent of its SLAM map's known cells."""
    x, y = obs.pose.x, obs.pose.y
    xs, ys = [x], [y]
    if obs.scan is not None:
        scan = obs.scan
        ranges = scan.ranges.astype(np.float64)
        valid = ~np.isnan(ranges) & (ranges >= scan.range_min)
        if valid.any():
            reach = np.minimum(ranges[valid], scan.range_max)
            angles = obs.pose.yaw + scan.angles()[valid]
            ex, ey = x + reach * np.cos(angles), y + reach * np.sin(angles)
            xs += [float(ex.min()), float(ex.max())]
            ys += [float(ey.min()), float(ey.max())]
    if obs.spad is not None and spad_reach_m > 0.0:
        xs += [x - spad_reach_m, x + spad_reach_m]
        ys += [y - spad_reach_m, y + spad_reach_m]
    grid = obs.occupancy_grid
    known = None if grid is None else grid.known_extent_xy()
    if known is not None:
        xs += [known[0], known[2]]
        ys += [known[1], known[3]]
    return min(xs), min(ys), max(xs), max(ys)


def grown_frame(frame: MapFrame, reach_xy, growth: MapGrowth, align: int = 1) -> Optional[Regrid]:
    """The grid ``frame`` must grow to so that ``reach_xy`` plus ``growth.margin_m`` lies inside it, or None when it
    does already. A side that grows gains ``growth.chunk_m`` more; the new origin stays on ``frame``'s lattice, and
    the rows added above and the columns added to the left are multiples of ``align`` (the planning's blocks keep
    their cells: :mod:`~superex_deploy.onboard.planning.coarse`).

    Raises:
        ValueError: the grown grid would exceed the map size limit
            (:func:`~superex_deploy.messages.check_map_size`).
    """
    if isinstance(align, bool) or not isinstance(align, (int, np.integer)) or align < 1:
        raise ValueError(f"align must be an integer >= 1 (cells), got {align!r}")
    res = frame.resolution_m
    rows, cols = frame.shape
    ox, oy = frame.origin_xy
    x0, y0, x1, y1 = reach_xy
    margin, chunk = growth.margin_m, growth.chunk_m
    # Cells (columns from the left edge, rows from the bottom edge) the reach plus the margin needs.
    try:
        need_left = math.floor((x0 - margin - ox) / res)
        need_right = math.ceil((x1 + margin - ox) / res)
        need_bottom = math.floor((y0 - margin - oy) / res)
        need_top = math.ceil((y1 + margin - oy) / res)
        extra = math.ceil(chunk / res - 1e-9)
    except OverflowError:  # a reach, margin or chunk of ~1e300 m (a garbage pose): infinitely many cells
        raise ValueError(f"the explorer's growing map would have to reach x {x0:.3g}..{x1:.3g} m, y {y0:.3g}..{y1:.3g} "
                         f"m (margin {margin:.3g} m, chunk {chunk:.3g} m): beyond the map size limit of "
                         f"{max_map_cells():,} cells") from None
    left = -(-(-need_left + extra) // align) * align if need_left < 0 else 0
    right = need_right - cols + extra if need_right > cols else 0
    bottom = -need_bottom + extra if need_bottom < 0 else 0
    top = -(-(need_top - rows + extra) // align) * align if need_top > rows else 0
    if not (left or right or bottom or top):
        return None
    shape = (rows + top + bottom, cols + left + right)
    check_map_size(shape, res, "the explorer's growing map")
    grown = MapFrame(shape, res, (ox - left * res, oy - bottom * res))
    return Regrid(frame=grown, top=top, left=left)


def regrid_for(frame: MapFrame, obs: Observation, spad_processing, growth: MapGrowth,
               align: int = 1) -> Optional[Regrid]:
    """The larger grid than ``frame`` that observation ``obs`` needs (:func:`grown_frame`, ``align`` as there), or
    None: its scan's reach, and its SPAD frame's where ``spad_processing`` (a
    :class:`~superex_deploy.onboard.nlos.processing.SpadProcessing`, or None) processes one."""
    spad_reach_m = 0.0
    if spad_processing is not None and obs.spad is not None:
        spad_reach_m = spad_processing.reach_cells(frame.resolution_m) * frame.resolution_m
    return grown_frame(frame, reach_of(obs, spad_reach_m), growth, align)
