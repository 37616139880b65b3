"""Continuous motion of the simulated robot when its belief is not the truth (the world's kinematics with pose
noise: :meth:`World.apply <superex_deploy.sim.world.World.apply>` drives with :func:`drive_belief_relative`).

The robot follows the commanded path from where it *believes* it is: a waypoint the robot believes at map-frame
``w`` lies, seen from the robot, at ``R(-yaw_b) (w - b)`` (``b``: the believed position, ``yaw_b`` the believed
heading); the robot drives there, so in the world it reaches ``t + R(yaw_t - yaw_b) (w - b)`` (``t``, ``yaw_t``: the
true pose). A belief error thus becomes a true displacement (a belief one cell east of the truth drives the robot
one cell west of the path). The path's first waypoint is the centre of the believed cell, where the robot already
is: the believed polyline runs from ``b`` through the following waypoints.

The robot is a point in the grid (its cell, as the planner's map sees it). It drives at most ``budget_m`` metres
along the polyline, its heading turning to the direction of each segment it drives (the heading of the last
segment, unchanged without motion). A segment that enters a wall cell or leaves the map stops the robot just
before it, at the last free position (a collision).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import Pose2D

__all__ = ["Drive", "drive_belief_relative", "first_blocked"]

_STOP_BEFORE_M = 1e-6
"""A robot stopped by a wall stands this far before the wall's face along its segment (metres)."""


@dataclass(frozen=True)
class Drive:
    """What one motion did.

    Attributes:
        pose: the true pose after it.
        metres: metres driven.
        collided: True when a wall (or the map's edge) stopped the robot.
    """

    pose: Pose2D
    metres: float
    collided: bool


def _free(grid: OccupancyGrid, x: float, y: float) -> bool:
    """Whether the map-frame point ``(x, y)`` (origin at the grid's lower-left corner) lies in a free cell."""
    row = grid.shape[0] - 1 - int(math.floor(y / grid.resolution_m))
    col = int(math.floor(x / grid.resolution_m))
    return grid.is_free((row, col))


def first_blocked(grid: OccupancyGrid, start_xy, end_xy) -> float | None:
    """Where the segment from ``start_xy`` to ``end_xy`` (map-frame metres, the grid's lower-left corner at the
    origin) first enters a cell that is not free (a wall, or outside the grid).

    Cells include their lower ``x`` and ``y`` edges (as :meth:`MapFrame.cell_of
    <superex_deploy.messages.MapFrame.cell_of>` has them); a segment through a cell corner crosses the ``x`` edge
    first, so it is stopped when either cell beside the corner is a wall.

    Returns:
        The segment parameter ``s`` in ``[0, 1]`` of the entry (0 when the start is not free), or None when the
        whole segment stays in free cells.
    """
    res = grid.resolution_m
    x0, y0 = float(start_xy[0]) / res, float(start_xy[1]) / res
    dx, dy = float(end_xy[0]) / res - x0, float(end_xy[1]) / res - y0
    ix, iy = int(math.floor(x0)), int(math.floor(y0))
    rows = grid.shape[0]

    def free(ix: int, iy: int) -> bool:
        return grid.is_free((rows - 1 - iy, ix))

    if not free(ix, iy):
        return 0.0
    step_x, step_y = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
    next_x = ((ix + 1 - x0) / dx if dx > 0 else (ix - x0) / dx) if dx != 0 else math.inf
    next_y = ((iy + 1 - y0) / dy if dy > 0 else (iy - y0) / dy) if dy != 0 else math.inf
    delta_x = abs(1.0 / dx) if dx != 0 else math.inf
    delta_y = abs(1.0 / dy) if dy != 0 else math.inf
    end_ix, end_iy = int(math.floor(x0 + dx)), int(math.floor(y0 + dy))
    while (ix, iy) != (end_ix, end_iy):
        if next_x <= next_y:
            s, ix, next_x = next_x, ix + step_x, next_x + delta_x
        else:
            s, iy, next_y = next_y, iy + step_y, next_y + delta_y
        if s > 1.0:
            break
        if not free(ix, iy):
            return max(0.0, min(1.0, s))
    return None


def drive_belief_relative(grid: OccupancyGrid, truth: Pose2D, belief: Pose2D, path_xy: np.ndarray,
                          budget_m: float) -> Drive:
    """Drive the true robot along the commanded path relative to its belief (see the module docstring).

    Args:
        grid: the ground truth (its map frame has the origin at the lower-left corner).
        truth: the robot's true pose (in a free cell).
        belief: the pose the robot believes it has (the one its explorer planned from).
        path_xy: float ``[N, 2]`` map-frame waypoints, the first one at the believed cell's centre.
        budget_m: metres to drive at most (>= 0).

    Returns:
        The :class:`Drive`.
    """
    path_xy = np.asarray(path_xy, np.float64).reshape(-1, 2)
    turn = truth.yaw - belief.yaw
    cos_t, sin_t = math.cos(turn), math.sin(turn)
    offsets = path_xy[1:] - (belief.x, belief.y)
    targets = np.stack([truth.x + cos_t * offsets[:, 0] - sin_t * offsets[:, 1],
                        truth.y + sin_t * offsets[:, 0] + cos_t * offsets[:, 1]], axis=1)
    x, y, yaw = truth.x, truth.y, truth.yaw
    left, driven = float(budget_m), 0.0
    for tx, ty in targets:
        if left <= 0.0:
            break
        length = math.hypot(tx - x, ty - y)
        if length == 0.0:
            continue
        fraction = min(1.0, left / length)
        end = (x + fraction * (tx - x), y + fraction * (ty - y))
        heading = math.atan2(ty - y, tx - x)
        blocked = first_blocked(grid, (x, y), end)
        if blocked is not None:
            reach = max(0.0, blocked * fraction * length - _STOP_BEFORE_M)
            stop = (x + reach / length * (tx - x), y + reach / length * (ty - y))
            if reach > 0.0 and _free(grid, *stop):
                x, y, driven = stop[0], stop[1], driven + reach
                yaw = heading
            return Drive(Pose2D(x, y, yaw), driven, True)
        x, y, yaw = end[0], end[1], heading
        driven += fraction * length
        left -= fraction * length
    return Drive(Pose2D(x, y, yaw), driven, False)
