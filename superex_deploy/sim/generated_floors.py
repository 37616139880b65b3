"""Office floors of any size, drawn from a seed: rows of rooms along corridors, joined by cross corridors.

The KTH floors are at most about 130 m x 45 m; a robot's building may be larger, and a SLAM map of it finer.
:func:`generate_floor` draws one in metres and rasterises it at any resolution, so that the same building can be
run at 0.1, 0.05 and 0.025 m (the step-time benchmark's large floor, ``scripts/bench_realtime.py --fine``) and
tests can build floors the project never saw.

Layout, from the top: bands of *room row, corridor, room row* separated by walls (room depths drawn, then
stretched so that the bands fill the height), each row cut into rooms of random width, each room with one door onto its corridor (at a random place along it); ``cross_corridors`` vertical
corridors at random places join every corridor (the room rows leave their strip free). Everything inside the
outer wall is valid (:attr:`~superex_deploy.maps.OccupancyGrid.valid`); every free cell is reachable from every
other one (tested).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.checks import check_int, check_real

__all__ = ["FloorLayout", "generate_floor", "upsampled", "named_floor"]


@dataclass(frozen=True)
class FloorLayout(JsonConfig):
    """The shape of a generated floor (metres).

    Attributes:
        width_m, height_m: the building's outer size.
        corridor_m: corridor width.
        room_depth_m: ``(low, high)`` of a room row's depth (drawn per band).
        room_width_m: ``(low, high)`` of a room's width along its corridor.
        wall_m: wall thickness.
        door_m: door width.
        cross_corridors: vertical corridors joining the bands' corridors (at least 1).

    Raises:
        ValueError: a length that is not positive and finite, a range whose low end exceeds its high end, a floor
            too small for one band of rooms, fewer than one cross corridor.
    """

    width_m: float = 96.0
    height_m: float = 64.0
    corridor_m: float = 2.0
    room_depth_m: tuple[float, float] = (4.0, 7.0)
    room_width_m: tuple[float, float] = (3.0, 8.0)
    wall_m: float = 0.2
    door_m: float = 1.0
    cross_corridors: int = 2

    def __post_init__(self) -> None:
        for name in ("width_m", "height_m", "corridor_m", "wall_m", "door_m"):
            check_real(f"FloorLayout.{name}", getattr(self, name), 0.0, low_open=True)
        for name in ("room_depth_m", "room_width_m"):
            low, high = (check_real(f"FloorLayout.{name}", v, 0.0, low_open=True) for v in getattr(self, name))
            if low > high:
                raise ValueError(f"FloorLayout.{name}: low end {low} exceeds high end {high}")
        if self.door_m >= self.room_width_m[0]:
            raise ValueError(f"FloorLayout: door_m ({self.door_m}) must be narrower than the narrowest room "
                             f"({self.room_width_m[0]} m)")
        check_int("FloorLayout.cross_corridors", self.cross_corridors, 1)
        band = 2 * self.room_depth_m[1] + self.corridor_m + 4 * self.wall_m
        if self.height_m < band or self.width_m < self.cross_corridors * (self.corridor_m + self.room_width_m[1]):
            raise ValueError(f"FloorLayout: a {self.width_m} m x {self.height_m} m floor is too small for one band "
                             f"of rooms ({band} m high) and {self.cross_corridors} cross corridor(s)")


def _rectangles(layout: FloorLayout, rng: np.random.Generator) -> list[tuple[float, float, float, float]]:
    """The free rectangles ``(x0, y0, x1, y1)`` (metres from the top-left corner): rooms, doors, corridors."""
    w, t = layout.wall_m, layout.corridor_m
    width, height = layout.width_m, layout.height_m
    spacing = (width - 2 * w) / layout.cross_corridors
    crosses = [w + spacing * (i + rng.uniform(0.25, 0.75)) - t / 2 for i in range(layout.cross_corridors)]
    free, corridors = [], []
    # The bands' room depths, drawn until the next band would not fit, then stretched to fill the height.
    depths, used = [], w
    while True:
        pair = (rng.uniform(*layout.room_depth_m), rng.uniform(*layout.room_depth_m))
        if used + sum(pair) + t + 3 * w > height:
            break
        depths.append(pair)
        used += sum(pair) + t + 3 * w
    if not depths:
        raise ValueError("FloorLayout: no band of rooms fits")
    stretch = 1.0 + (height - used) / sum(sum(pair) for pair in depths)
    y = w
    for depth_a, depth_b in depths:
        depth_a, depth_b = depth_a * stretch, depth_b * stretch
        corridor_y = y + depth_a + w
        corridors.append(corridor_y)
        free.append((w, corridor_y, width - w, corridor_y + t))
        for row_y0, row_y1, door_y0, door_y1 in ((y, y + depth_a, y + depth_a, corridor_y),
                                                 (corridor_y + t + w, corridor_y + t + w + depth_b, corridor_y + t,
                                                  corridor_y + t + w)):
            spans, x = [], w
            for cross in crosses:  # the room row leaves each cross corridor's strip (and its walls) free
                spans.append((x, cross - w))
                x = cross + t + w
            spans.append((x, width - w))
            for x0, x1 in spans:
                x = x0
                while x1 - x >= layout.room_width_m[0]:
                    room = min(rng.uniform(*layout.room_width_m), x1 - x)
                    if x1 - (x + room + w) < layout.room_width_m[0]:
                        room = x1 - x  # the last room takes what is left
                    free.append((x, row_y0, x + room, row_y1))
                    door = x + rng.uniform(0.0, room - layout.door_m)
                    free.append((door, door_y0, door + layout.door_m, door_y1))
                    x += room + w
        y = corridor_y + t + w + depth_b + w
    for cross in crosses:
        free.append((cross, corridors[0], cross + t, corridors[-1] + t))
    return free


def generate_floor(layout: FloorLayout = FloorLayout(), resolution_m: float = 0.1, seed: int = 0) -> OccupancyGrid:
    """A floor drawn from ``seed`` (the same building at every resolution), rasterised at ``resolution_m``: a cell
    is free where its centre lies in a room, door or corridor, a wall elsewhere inside the building.

    Raises:
        ValueError: a bad layout (see :class:`FloorLayout`), a resolution that is not positive and finite or
            leaves a wall or door less than one cell wide.
    """
    if not isinstance(layout, FloorLayout):
        raise ValueError(f"layout must be a FloorLayout, got {type(layout).__name__}")
    resolution_m = check_real("resolution_m", resolution_m, 0.0, low_open=True)
    if resolution_m > min(layout.wall_m, layout.door_m / 2):
        raise ValueError(f"a {resolution_m} m grid cannot draw {layout.wall_m} m walls and {layout.door_m} m doors: "
                         f"use at most {min(layout.wall_m, layout.door_m / 2)} m")
    rng = np.random.default_rng(seed)
    rows, cols = int(round(layout.height_m / resolution_m)), int(round(layout.width_m / resolution_m))
    centre_y = (np.arange(rows) + 0.5) * resolution_m
    centre_x = (np.arange(cols) + 0.5) * resolution_m
    free = np.zeros((rows, cols), bool)
    for x0, y0, x1, y1 in _rectangles(layout, rng):
        r = slice(int(np.searchsorted(centre_y, y0)), int(np.searchsorted(centre_y, y1)))
        c = slice(int(np.searchsorted(centre_x, x0)), int(np.searchsorted(centre_x, x1)))
        free[r, c] = True
    name = f"generated-{layout.width_m:g}x{layout.height_m:g}m-seed{seed}@{resolution_m:g}m"
    return OccupancyGrid(~free, np.ones((rows, cols), bool), resolution_m, name)


def upsampled(grid: OccupancyGrid, factor: int) -> OccupancyGrid:
    """``grid`` with every cell a ``factor`` x ``factor`` block at ``resolution / factor`` (the same building on
    a finer grid: a SLAM resolution).

    Raises:
        ValueError: ``factor`` not an integer >= 1.
    """
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    block = np.ones((factor, factor), bool)
    return OccupancyGrid(np.kron(grid.occupied, block), np.kron(grid.valid, block), grid.resolution_m / factor,
                         f"{grid.name}@x{factor}" if factor > 1 else grid.name)


def named_floor(spec: str) -> tuple[OccupancyGrid, tuple[int, int]]:
    """A floor and its start cell by name, for the benchmarks: ``MAP`` (a bundled eval map, its first benchmark
    start), ``MAP@xK`` (the same upsampled ``K`` times, the start in the same place), ``generated`` or
    ``generated@RES`` (:func:`generate_floor` with the default layout and seed 0 at ``RES`` metres, 0.1 by default;
    the start drawn from its largest free region with seed 0, at the same place at every resolution).

    Raises:
        ValueError: an unknown map, a malformed spec.
    """
    from superex_deploy.maps import largest_region_start, load_map, start_poses

    name, _, suffix = str(spec).partition("@")
    if name == "generated":
        try:
            resolution_m = float(suffix) if suffix else 0.1
            factor = int(round(0.1 / resolution_m))
        except (ValueError, ZeroDivisionError):
            raise ValueError(f"a generated floor's spec is 'generated' or 'generated@RES', got {spec!r}") from None
        if factor < 1 or abs(factor * resolution_m - 0.1) > 1e-9:
            raise ValueError(f"a generated floor's resolution must be 0.1 m divided by an integer, got {spec!r}")
        base = generate_floor(FloorLayout(), 0.1, 0)
        start = largest_region_start(base, np.random.default_rng(0), 0.5)
        grid = base if factor == 1 else generate_floor(FloorLayout(), 0.1 / factor, 0)
    else:
        if suffix and not (suffix.startswith("x") and suffix[1:].isdigit() and int(suffix[1:]) >= 1):
            raise ValueError(f"a bundled floor's spec is 'MAP' or 'MAP@xK' (K an integer >= 1), got {spec!r}")
        factor = int(suffix[1:]) if suffix else 1
        start = start_poses(name)[0]
        grid = upsampled(load_map(name), factor)
    return grid, (int(start[0]) * factor + factor // 2, int(start[1]) * factor + factor // 2)
