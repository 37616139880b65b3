"""The map frame: the grid the explorer keeps its map in (:class:`MapFrame`), planar poses (:class:`Pose2D`) and
the turn from map-frame headings to grid angles (:func:`grid_angles`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from superex_deploy.messages.limits import check_finite, check_heading, check_map_size, check_point_xy

__all__ = ["MapFrame", "Pose2D", "grid_angles"]


def grid_angles(yaw: float, robot_angles: np.ndarray) -> np.ndarray:
    """float64 grid angles (towards ``+row``, see :mod:`superex_deploy.geometry`) of rays at ``robot_angles``
    (counter-clockwise from the heading) from a robot with map-frame heading ``yaw``: negated after adding."""
    return -(yaw + np.asarray(robot_angles, np.float64))


@dataclass(frozen=True)
class MapFrame:
    """The grid the explorer keeps its map in (``nav_msgs/MapMetaData``).

    Attributes:
        shape: ``(rows, cols)`` of the grid (at most :func:`max_map_cells` cells).
        resolution_m: metres per cell (at least :data:`MIN_RESOLUTION_M`).
        origin_xy: map-frame position (metres) of the grid's lower-left corner.
    """

    shape: tuple[int, int]
    resolution_m: float
    origin_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        try:
            shape = tuple(int(n) for n in self.shape)
            integral = all(int(n) == n for n in self.shape)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"shape must be a (rows, cols) pair of integers, got {self.shape!r}") from None
        if len(shape) != 2 or min(shape) < 1 or not integral:
            raise ValueError(f"shape must be a positive (rows, cols) pair of integers, got {self.shape!r}")
        resolution = check_finite("resolution_m", self.resolution_m)
        if resolution <= 0.0:
            raise ValueError(f"resolution_m must be positive, got {resolution}")
        origin = check_point_xy("origin_xy", self.origin_xy)
        check_map_size(shape, resolution, "the map frame")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "resolution_m", resolution)
        object.__setattr__(self, "origin_xy", origin)

    @classmethod
    def around(cls, x: float, y: float, resolution_m: float, size_m: float = 10.0,
               lattice_xy: tuple[float, float] = (0.0, 0.0)) -> "MapFrame":
        """A square frame of at least ``size_m`` metres a side centred near the map-frame point ``(x, y)``, its
        cell corners on the lattice through ``lattice_xy`` (a SLAM map's origin, so that its cells line up): the
        first frame of an explorer whose map grows (:class:`~superex_deploy.onboard.ExplorerConfig`'s
        ``growth``)."""
        resolution_m = check_finite("resolution_m", resolution_m)
        size_m = check_finite("size_m", size_m)
        if resolution_m <= 0.0 or size_m <= 0.0:
            raise ValueError(f"resolution_m and size_m must be positive, got {resolution_m} and {size_m}")
        cells = int(math.ceil(size_m / resolution_m))
        lx, ly = check_point_xy("lattice_xy", lattice_xy)
        left = lx + math.floor((check_finite("x", x) - lx) / resolution_m - cells / 2) * resolution_m
        bottom = ly + math.floor((check_finite("y", y) - ly) / resolution_m - cells / 2) * resolution_m
        return cls((cells, cells), resolution_m, (left, bottom))

    def grid_yx(self, x: float, y: float) -> tuple[float, float]:
        """Continuous grid position ``(y down, x right)`` in cells of the map-frame point ``(x, y)`` (metres)."""
        return (self.shape[0] - (y - self.origin_xy[1]) / self.resolution_m,
                (x - self.origin_xy[0]) / self.resolution_m)

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """The cell ``(row, col)`` holding the map-frame point ``(x, y)`` (cells include their lower ``x`` and ``y``
        edges); it may lie outside the grid."""
        return (self.shape[0] - 1 - int(math.floor((y - self.origin_xy[1]) / self.resolution_m)),
                int(math.floor((x - self.origin_xy[0]) / self.resolution_m)))

    def locate(self, x: float, y: float) -> tuple[tuple[float, float], tuple[int, int]]:
        """Where a sensor at the map-frame point ``(x, y)`` sits on the grid: its continuous ``(y down, x right)``
        position in cells, kept inside its cell, and the cell :meth:`cell_of` gives.

        Cells include their lower map-frame edges; the grid's ``y`` axis points down, so a point on a cell's lower
        edge has the grid position of the cell below: it is moved just inside (one ulp), so that rays start in the
        cell the point belongs to.

        Raises:
            ValueError: the point lies outside the grid.
        """
        cell = self.cell_of(x, y)
        if not self.contains(cell):
            raise ValueError(f"pose ({x}, {y}) m lies outside the map (cell {cell}, grid {self.shape}, origin "
                             f"{self.origin_xy} m)")
        gy, gx = self.grid_yx(x, y)
        return (min(gy, float(np.nextafter(cell[0] + 1.0, 0.0))), gx), cell

    def centre_xy(self, rc) -> tuple[float, float]:
        """Map-frame position (metres) of the centre of cell ``rc = (row, col)``."""
        return (self.origin_xy[0] + (float(rc[1]) + 0.5) * self.resolution_m,
                self.origin_xy[1] + (self.shape[0] - float(rc[0]) - 0.5) * self.resolution_m)

    def centres_xy(self, cells) -> np.ndarray:
        """float64 ``[N, 2]`` map-frame ``(x, y)`` of the centres of int ``[N, 2]`` ``(row, col)`` cells."""
        cells = np.asarray(cells, np.float64).reshape(-1, 2)
        return np.stack([self.origin_xy[0] + (cells[:, 1] + 0.5) * self.resolution_m,
                         self.origin_xy[1] + (self.shape[0] - cells[:, 0] - 0.5) * self.resolution_m], axis=1)

    def contains(self, rc) -> bool:
        """Whether cell ``rc`` lies inside the grid."""
        return 0 <= rc[0] < self.shape[0] and 0 <= rc[1] < self.shape[1]


@dataclass(frozen=True)
class Pose2D:
    """A planar pose in the map frame (``geometry_msgs/Pose2D``).

    Attributes:
        x, y: position (metres, finite).
        yaw: heading (radians, counter-clockwise from ``+x``): finite with ``|yaw| <= MAX_ABS_YAW``, stored
            normalised to ``(-pi, pi]`` (a heading already there is kept unchanged).
    """

    x: float
    y: float
    yaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("x", "y"):
            object.__setattr__(self, name, check_finite(f"pose.{name}", getattr(self, name)))
        object.__setattr__(self, "yaw", check_heading("pose.yaw", self.yaw))
