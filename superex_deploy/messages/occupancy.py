"""What a robot's localisation and mapping stack gives an exploration node: a SLAM map and the pose's uncertainty.

* :class:`OccupancyGridMessage` is ``nav_msgs/OccupancyGrid``: int8 cells, ``-1`` unknown, ``0..100`` the
  probability of occupancy in percent, row-major from the grid's lower-left corner (row 0 is the *bottom* row, as
  ROS has it; SuperEx's own grids have row 0 at the top: :meth:`OccupancyGridMessage.in_frame` turns one into the
  other).
* :class:`PoseCovariance` is the ``(x, y, yaw)`` block of ``geometry_msgs/PoseWithCovariance``'s 6x6 covariance
  (metres and radians), the uncertainty of the pose an :class:`~superex_deploy.messages.Observation` carries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.messages.frame import MapFrame
from superex_deploy.messages.limits import check_finite, check_map_size, check_point_xy, check_stamp

__all__ = ["OccupancyGridMessage", "PoseCovariance", "OCCUPANCY_UNKNOWN", "SYMMETRY_RTOL", "same_resolution"]

OCCUPANCY_UNKNOWN = -1
"""The value of an unknown cell in a ``nav_msgs/OccupancyGrid``."""

SYMMETRY_RTOL = 1e-6
"""How far a :class:`PoseCovariance` may stray from symmetry and from positive semi-definiteness, relative to its
largest entry: a few float32 roundings (float32's epsilon is 1.2e-7)."""

_LATTICE_TOLERANCE_CELLS = 1e-6
"""How far (cells) an occupancy grid's origin may lie from the frame's lattice, plus the float32 rounding of the
resolution over the distance between the origins (see :meth:`OccupancyGridMessage.in_frame`)."""


_FLOAT32_EPS = float(np.finfo(np.float32).eps)

ORIGIN_YAW_TOLERANCE = 1e-6
"""The largest origin yaw (radians) an :class:`OccupancyGridMessage` accepts as unrotated."""


def same_resolution(a_m: float, b_m: float) -> bool:
    """Whether two resolutions (metres per cell) are the same grid's: equal once rounded to float32, as ROS sends
    ``info.resolution`` (0.05 arrives as 0.05000000074505806)."""
    return bool(np.float32(a_m) == np.float32(b_m))


@dataclass(frozen=True, eq=False)
class OccupancyGridMessage:
    """A map published by SLAM or a costmap (``nav_msgs/OccupancyGrid``), in the map frame.

    Attributes:
        resolution_m: metres per cell (``info.resolution``).
        width: cells per row (``info.width``, along ``+x``).
        height: rows (``info.height``, along ``+y``).
        origin_xy: map-frame position (metres) of the lower-left corner of cell ``(0, 0)`` (``info.origin``; a
            rotated origin is not supported: SLAM maps are published axis-aligned).
        data: int8 ``[height * width]``, row-major from the bottom row: ``-1`` unknown, ``0..100`` occupancy
            probability in percent.
        stamp_s: the header's stamp (seconds), or None. The explorer takes a message as a new map when it is
            another object with another stamp than the step before's (a robot hands the latest map to every step
            until SLAM publishes the next: a goal reached on a map that has not changed since is not yet known to be
            resolved).
        origin_yaw: the yaw of ``info.origin`` (radians): only 0 (within 1e-6 rad) is accepted; a rotated map is
            refused here, so that the API, ``superex offline`` and the node refuse it alike.
    """

    resolution_m: float
    width: int
    height: int
    origin_xy: tuple[float, float]
    data: np.ndarray
    stamp_s: Optional[float] = None
    origin_yaw: float = 0.0

    def __post_init__(self) -> None:
        if self.stamp_s is not None:
            object.__setattr__(self, "stamp_s", check_stamp("occupancy grid stamp_s", self.stamp_s))
        yaw = check_finite("occupancy grid origin_yaw", self.origin_yaw)
        if abs(yaw) > ORIGIN_YAW_TOLERANCE:
            raise ValueError(f"a SLAM map with a rotated origin is not supported (nav_msgs/OccupancyGrid info.origin "
                             f"has a yaw of {yaw:.3g} rad): SLAM packages publish axis-aligned maps; publish the "
                             f"map unrotated and put the rotation in the map frame's transform")
        object.__setattr__(self, "origin_yaw", 0.0)
        resolution = check_finite("occupancy grid resolution_m", self.resolution_m)
        if resolution <= 0.0:
            raise ValueError(f"occupancy grid resolution_m must be positive, got {resolution}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"occupancy grid {name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        check_map_size((self.height, self.width), resolution, "the occupancy grid")
        origin = check_point_xy("occupancy grid origin_xy", self.origin_xy)
        data = np.asarray(self.data)
        if data.dtype != np.int8 or data.shape != (self.height * self.width,):
            raise ValueError(f"occupancy grid data must be int8 [height * width] = [{self.height * self.width}], "
                             f"got {data.dtype} {data.shape}")
        if data.size and (data.min() < OCCUPANCY_UNKNOWN or data.max() > 100):
            raise ValueError("occupancy grid data may hold only -1 (unknown) and 0..100 (occupancy in percent)")
        data = data.copy()
        data.flags.writeable = False
        object.__setattr__(self, "resolution_m", resolution)
        object.__setattr__(self, "origin_xy", origin)
        object.__setattr__(self, "data", data)

    def same_map(self, previous: Optional["OccupancyGridMessage"]) -> bool:
        """Whether this message is the map ``previous`` was (the same object, or both stamped alike): a robot hands
        the latest map to every step until SLAM publishes the next."""
        return previous is not None and (self is previous or (self.stamp_s is not None
                                                              and self.stamp_s == previous.stamp_s))

    def known_extent_xy(self) -> Optional[tuple[float, float, float, float]]:
        """``(x_min, y_min, x_max, y_max)`` (metres, map frame) of the message's known cells (not -1), or None when
        every cell is unknown; computed once. A gmapping-style map of a fixed 200 m square with a few metres known
        grows a growing explorer to its known part only."""
        if "_known_extent" not in self.__dict__:
            known = (self.data != OCCUPANCY_UNKNOWN).reshape(self.height, self.width)
            rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
            extent = None
            if rows.size:
                (x0, y0), res = self.origin_xy, self.resolution_m
                extent = (x0 + cols[0] * res, y0 + rows[0] * res, x0 + (cols[-1] + 1) * res, y0 + (rows[-1] + 1) * res)
            object.__setattr__(self, "_known_extent", extent)
        return self.__dict__["_known_extent"]

    @classmethod
    def from_frame_grid(cls, frame: MapFrame, grid: np.ndarray) -> "OccupancyGridMessage":
        """The message of an int8 ``[H, W]`` grid in ``frame`` (row 0 at the top, values ``-1`` or ``0..100``)."""
        grid = np.asarray(grid)
        if grid.dtype != np.int8 or grid.shape != tuple(frame.shape):
            raise ValueError(f"grid must be int8 {tuple(frame.shape)}, got {grid.dtype} {grid.shape}")
        return cls(resolution_m=frame.resolution_m, width=frame.shape[1], height=frame.shape[0],
                   origin_xy=frame.origin_xy, data=np.ascontiguousarray(grid[::-1]).reshape(-1))

    def in_frame(self, frame: MapFrame) -> np.ndarray:
        """int8 ``[H, W]`` occupancy (``-1`` unknown, ``0..100``) of ``frame``'s cells, row 0 at the top; frame cells
        outside the message are unknown, message cells outside the frame are dropped.

        A message of the frame's resolution (equal once both are rounded to float32, the type of
        ``nav_msgs/MapMetaData.resolution``: :func:`same_resolution`) whose origin lies on the frame's cell lattice
        (a whole number of cells away, within 1e-6 cells plus the float32 rounding of the resolution over that
        distance) is copied cell for cell (a fresh array). Any other (a 0.05 m SLAM map for a 0.1 m explorer, or an origin between
        its cells) is resampled: a frame cell takes the largest value of the message cells whose centres fall in it
        (a wall in any of them makes it a wall; unknown only where all are unknown, as ``-1`` is the smallest value),
        and a frame cell that holds no message cell's centre (a coarser message) the value of the message cell
        under its own centre (a read-only array, kept for the next call with the same frame).
        """
        on_lattice = self._lattice_cells(frame)
        if on_lattice is None:
            # A robot hands the latest map to every step until SLAM publishes the next: resampled once per frame
            # (tens of ms for a map of millions of cells), and read-only, as the message's own data.
            memo = self.__dict__.get("_resampled_for")
            if memo is None or memo[0] != frame:
                out = self._resampled(frame)
                out.flags.writeable = False
                memo = (frame, out)
                object.__setattr__(self, "_resampled_for", memo)
            return memo[1]
        dx, dy = on_lattice  # the message's cell (0, 0) is frame column dx, row from the bottom dy
        height, width = frame.shape
        out = np.full((height, width), OCCUPANCY_UNKNOWN, np.int8)
        bottom_up = self.data.reshape(self.height, self.width)
        rows = slice(max(0, -dy), min(self.height, height - dy))
        cols = slice(max(0, -dx), min(self.width, width - dx))
        if rows.start >= rows.stop or cols.start >= cols.stop:
            return out
        # frame row (from the top) of message row m (from the bottom): height - 1 - (dy + m)
        top = height - 1 - (dy + rows.stop - 1)
        bottom = height - 1 - (dy + rows.start)
        out[top:bottom + 1, cols.start + dx:cols.stop + dx] = bottom_up[rows, cols][::-1]
        return out

    def _resampled(self, frame: MapFrame) -> np.ndarray:
        """:meth:`in_frame` for a message of another resolution or off the frame's lattice."""
        height, width = frame.shape
        res_f, res_m = frame.resolution_m, self.resolution_m
        (fx, fy), (mx, my) = frame.origin_xy, self.origin_xy
        out = np.full(height * width, OCCUPANCY_UNKNOWN, np.int8)
        # Every message cell's centre, into the frame cell holding it (columns and rows from the bottom).
        col = np.floor((mx + (np.arange(self.width) + 0.5) * res_m - fx) / res_f).astype(np.int64)
        row = np.floor((my + (np.arange(self.height) + 0.5) * res_m - fy) / res_f).astype(np.int64)
        keep_c, keep_r = (col >= 0) & (col < width), (row >= 0) & (row < height)
        if keep_c.any() and keep_r.any():
            cells = ((height - 1 - row[keep_r])[:, None] * width + col[keep_c][None, :]).reshape(-1)
            values = self.data.reshape(self.height, self.width)[np.ix_(keep_r, keep_c)].reshape(-1)
            np.maximum.at(out, cells, values)
            hit = np.zeros(height * width, bool)
            hit[cells] = True
        else:
            hit = np.zeros(height * width, bool)
        # Frame cells no message centre fell in: the message cell under the frame cell's centre, if any.
        mcol = np.floor((fx + (np.arange(width) + 0.5) * res_f - mx) / res_m).astype(np.int64)
        mrow = np.floor((fy + (np.arange(height) + 0.5) * res_f - my) / res_m).astype(np.int64)  # from the bottom
        inside_c, inside_r = (mcol >= 0) & (mcol < self.width), (mrow >= 0) & (mrow < self.height)
        out = out.reshape(height, width)
        hit = hit.reshape(height, width)
        rows_top = np.flatnonzero(inside_r[::-1])  # frame rows from the top whose centre lies in the message
        cols = np.flatnonzero(inside_c)
        if rows_top.size and cols.size:
            sampled = self.data.reshape(self.height, self.width)[mrow[::-1][rows_top][:, None], mcol[cols][None, :]]
            area = np.ix_(rows_top, cols)
            out[area] = np.where(hit[area], out[area], sampled)
        return out

    def lattice_offset(self, frame: MapFrame) -> tuple[int, int]:
        """``(columns, rows)`` from ``frame``'s origin to the message's (its cell ``(0, 0)`` is frame column
        ``columns``, frame row ``rows`` counted from the bottom), for a message :meth:`in_frame` copies cell for
        cell.

        Raises:
            ValueError: another resolution, or an origin off the frame's lattice (:meth:`in_frame` resamples those).
        """
        if not same_resolution(self.resolution_m, frame.resolution_m):
            raise ValueError(f"the occupancy grid's resolution {self.resolution_m} m differs from the map frame's "
                             f"{frame.resolution_m} m")
        cells = self._lattice_cells(frame)
        if cells is None:
            raise ValueError(f"the occupancy grid's origin {self.origin_xy} m is not a whole number of cells from the "
                             f"map frame's {frame.origin_xy} m")
        return cells

    def _lattice_cells(self, frame: MapFrame):
        """``(columns, rows)`` of :meth:`lattice_offset`, or None for a message of another resolution or off the
        frame's lattice."""
        if not same_resolution(self.resolution_m, frame.resolution_m):
            return None
        shift = [(m - f) / frame.resolution_m for m, f in zip(self.origin_xy, frame.origin_xy)]
        cells = [round(s) for s in shift]
        # A resolution sent as float32 is off by up to half a float32 ulp: over |s| cells that is |s| ulps of s.
        if any(abs(s - c) > _LATTICE_TOLERANCE_CELLS + 4 * _FLOAT32_EPS * abs(s) for s, c in zip(shift, cells)):
            return None
        return int(cells[0]), int(cells[1])


@dataclass(frozen=True, eq=False)
class PoseCovariance:
    """The uncertainty of a planar pose: the covariance of ``(x, y, yaw)``.

    Attributes:
        matrix: float64 ``[3, 3]``, symmetric and positive semi-definite; units m^2, m rad and rad^2 (the
            ``x, y, yaw`` rows and columns of ``geometry_msgs/PoseWithCovariance.covariance``: indices 0, 1, 5 of
            its 6x6). A matrix symmetric to float32's precision (up to :data:`SYMMETRY_RTOL` of its largest entry)
            is accepted and stored as the mean of it and its transpose; eigenvalues down to minus that much count
            as zero.

    Raises:
        ValueError: another shape, a NaN or infinite entry, an asymmetric matrix, a negative variance, a matrix
            that is not positive semi-definite.
    """

    matrix: np.ndarray

    def __post_init__(self) -> None:
        try:
            matrix = np.array(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"pose covariance must be a [3, 3] matrix of numbers over (x, y, yaw), got "
                             f"{type(self.matrix).__name__}") from None
        if matrix.shape != (3, 3):
            raise ValueError(f"pose covariance must be a [3, 3] matrix over (x, y, yaw), got shape {matrix.shape}")
        if not np.all(np.isfinite(matrix)):
            raise ValueError(f"pose covariance must be finite, got {matrix.tolist()}")
        scale = float(np.max(np.abs(matrix)))
        # A covariance computed in float32 (or sent as float32 by a ROS stack) is symmetric to float32's precision
        # only: asymmetry up to SYMMETRY_RTOL of its largest entry is rounding, and the mean of the two is kept.
        asymmetry = float(np.max(np.abs(matrix - matrix.T)))
        if asymmetry > SYMMETRY_RTOL * scale:
            raise ValueError(f"pose covariance must be symmetric: entries differ from their transposes by up to "
                             f"{asymmetry:.3g} (largest entry {scale:.3g})")
        matrix = 0.5 * (matrix + matrix.T)
        if np.any(np.diag(matrix) < 0.0):
            raise ValueError(f"pose covariance must have non-negative variances, got {np.diag(matrix).tolist()}")
        lowest = float(np.linalg.eigvalsh(matrix)[0])
        if lowest < -SYMMETRY_RTOL * scale:
            raise ValueError(f"pose covariance must be positive semi-definite, got an eigenvalue of {lowest:.3g}")
        matrix.flags.writeable = False
        object.__setattr__(self, "matrix", matrix)

    @classmethod
    def from_sigmas(cls, sigma_xy_m: float, sigma_yaw_rad: float) -> "PoseCovariance":
        """Independent errors: ``sigma_xy_m`` on ``x`` and on ``y`` (metres), ``sigma_yaw_rad`` on the heading."""
        sigma_xy_m = check_finite("sigma_xy_m", sigma_xy_m)
        sigma_yaw_rad = check_finite("sigma_yaw_rad", sigma_yaw_rad)
        if sigma_xy_m < 0.0 or sigma_yaw_rad < 0.0:
            raise ValueError(f"sigmas must be >= 0, got {sigma_xy_m} m and {sigma_yaw_rad} rad")
        return cls(np.diag([sigma_xy_m ** 2, sigma_xy_m ** 2, sigma_yaw_rad ** 2]))

    @classmethod
    def from_ros(cls, covariance36) -> "PoseCovariance":
        """From ``geometry_msgs/PoseWithCovariance.covariance`` (36 row-major values over x, y, z, roll, pitch,
        yaw)."""
        full = np.asarray(covariance36, np.float64)
        if full.shape not in ((36,), (6, 6)):
            raise ValueError(f"a ROS pose covariance has 36 values, got shape {full.shape}")
        index = [0, 1, 5]
        return cls(full.reshape(6, 6)[np.ix_(index, index)])

    @property
    def sigma_xy_m(self) -> float:
        """The position's standard deviation along its worst direction (metres): the root of the largest
        eigenvalue of the ``(x, y)`` block."""
        return float(math.sqrt(max(0.0, np.linalg.eigvalsh(self.matrix[:2, :2])[-1])))

    @property
    def sigma_yaw_rad(self) -> float:
        """The heading's standard deviation (radians)."""
        return float(math.sqrt(self.matrix[2, 2]))
