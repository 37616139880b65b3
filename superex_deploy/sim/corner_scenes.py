"""Scenes of one L-shaped wall in a closed room, drawn from a seed: the carving's property test and benchmark
(tests/test_carving_corners.py, scripts/bench_carving_corners.py) look at wall corners and the steps of oblique
walls from every orientation, turn, thickness and distance, on either side.

A corner is where space carving's normals are least sure (the interior test rejects corner cells, but the cells
next to them, and every step of a rasterised oblique wall, still carve); the KTH floors hold few oblique walls,
so a property over them rarely meets one.
"""

from __future__ import annotations

import numpy as np

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.checks import check_int

__all__ = ["ROOM_CELLS", "l_corner_scene"]

ROOM_CELLS = 220
"""Side of the closed square room (cells of 0.1 m: 22 m), walls two cells thick."""


def _bar(shape: tuple[int, int], start: np.ndarray, angle: float, length: float, thickness: float) -> np.ndarray:
    """bool ``shape``: the cells whose centres lie in the ``thickness`` x ``length`` rectangle (cells) leaving
    ``start`` (row, col) along ``angle`` (radians, from the column axis towards rows), half a thickness behind it."""
    rows, cols = np.mgrid[:shape[0], :shape[1]] + 0.5
    dy, dx = rows - start[0], cols - start[1]
    along = dy * np.sin(angle) + dx * np.cos(angle)
    across = -dy * np.cos(angle) + dx * np.sin(angle)
    return (along >= -thickness / 2) & (along <= length) & (np.abs(across) <= thickness / 2)


def l_corner_scene(seed: int) -> tuple[OccupancyGrid, tuple[int, int]]:
    """A closed room (0.1 m cells, :data:`ROOM_CELLS` square) holding one L-shaped wall, and a robot cell.

    The corner lies in the middle 30 % of the room; arms 1.5-8 m long and 0.1-0.3 m thick leave it at any
    orientation, turning by a right angle (70 % of scenes) or by any angle from 17 to 160 degrees, either way; the
    robot stands on a free cell 2-10 m from the corner, on whichever side the draw puts it.

    Returns:
        ``(grid, (row, col))``, the same for the same ``seed`` (an int >= 0).
    """
    seed = check_int("seed", seed, 0)
    rng = np.random.default_rng(seed)
    walls = np.zeros((ROOM_CELLS, ROOM_CELLS), bool)
    walls[:2], walls[-2:], walls[:, :2], walls[:, -2:] = True, True, True, True
    corner = rng.uniform(0.35 * ROOM_CELLS, 0.65 * ROOM_CELLS, 2)
    angle = rng.uniform(0, 2 * np.pi)
    turn = (np.pi / 2 if rng.random() < 0.7 else rng.uniform(0.3, 2.8)) * rng.choice([-1, 1])
    thickness = rng.uniform(1.0, 3.0)
    for arm_angle, length in zip((angle, angle + turn), rng.uniform(15, 80, 2)):
        walls |= _bar(walls.shape, corner, arm_angle, length, thickness)
    grid = OccupancyGrid(walls, ~walls, 0.1, f"L corner {seed}")
    free = np.argwhere(~walls[4:-4, 4:-4]) + 4
    distance = np.hypot(*(free + 0.5 - corner).T)
    candidates = free[(distance > 20) & (distance < 100)]
    return grid, tuple(int(v) for v in candidates[rng.integers(len(candidates))])
