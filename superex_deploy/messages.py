"""What passes between a robot (or the simulator) and the onboard explorer: SI units, ROS-like fields.

Both sides import this module; it holds no ground truth and reads none.

Frames
------
The **map frame** is ROS's: ``x`` east, ``y`` north (up on the image), yaw counter-clockwise from ``+x``, metres and
radians. Its grid (:class:`MapFrame`) is ``[row, col]`` with row 0 at the *top* of the image, as everywhere in
SuperEx; ``origin_xy`` is the map-frame position of the grid's lower-left corner (ROS ``map_server``'s ``origin``).
Cell ``(r, c)`` covers ``x in [ox + c res, ox + (c + 1) res)`` and ``y in [oy + (H - r - 1) res, oy + (H - r) res)``.

Internally the grid geometry (:mod:`superex_deploy.geometry`) uses continuous ``(y, x)`` in cells with ``y`` *down*
and angles measured towards ``+row``; a map-frame heading ``phi`` is the grid angle ``-phi``.

Limits
------
What enters here is refused with one ``ValueError`` before anything is allocated or integrated:

* **Map size**: a grid of more than :func:`max_map_cells` cells (default :data:`MAX_MAP_CELLS`, 25 million: 5000 x
  5000 cells, 500 m square at 0.1 m; the environment variable ``SUPEREX_MAX_MAP_CELLS`` raises or lowers it), or a
  resolution finer than :data:`MIN_RESOLUTION_M` (1 mm: the planner's per-cell neighbourhoods, robot radius and
  wall-cost range, are counted in cells, and at 0.1 mm the wall-cost disc alone holds 4e8 cells). The map loader
  (:func:`superex_deploy.maps.load_map`) applies the same rule to an image's header before decoding its pixels.
* **Time stamps** (:func:`check_stamp`): finite, ``>= 0`` and at most :data:`MAX_STAMP_S` (``2**31 - 1`` s: the
  ``int32`` seconds of a ROS 2 ``builtin_interfaces/Time``, so that every observation can be recorded).
* **Headings** (:class:`Pose2D`): finite and ``|yaw| <= MAX_ABS_YAW`` (1e6 rad; beyond, a float64 angle is
  coarser than 1e-10 rad and its direction is noise), normalised to ``(-pi, pi]`` (a yaw already there is kept
  bit for bit).

Precision
---------
Fields that ``sensor_msgs/LaserScan`` holds as ``float32`` (angles, range limits, ranges) are stored at float32
precision here too, so that a recorded observation (see :mod:`superex_deploy.recording`) is bit-identical to the
one the explorer saw.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

__all__ = ["MapFrame", "Pose2D", "LaserScan", "SpadFrame", "Observation", "Command", "grid_angles",
           "MAX_MAP_CELLS", "MAX_MAP_CELLS_ENV", "MIN_RESOLUTION_M", "MAX_STAMP_S", "MAX_ABS_YAW", "max_map_cells",
           "check_map_size", "check_stamp"]

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


def grid_angles(yaw: float, robot_angles: np.ndarray) -> np.ndarray:
    """float64 grid angles (towards ``+row``, see :mod:`superex_deploy.geometry`) of rays at ``robot_angles``
    (counter-clockwise from the heading) from a robot with map-frame heading ``yaw``: negated after adding."""
    return -(yaw + np.asarray(robot_angles, np.float64))


def _finite(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _float32(name: str, value) -> float:
    """``value`` rounded to float32, as a Python float (finite)."""
    value = _finite(name, value)
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
    value = _finite(name, value)
    if not 0.0 <= value <= MAX_STAMP_S:
        raise ValueError(f"{name} must lie in [0, {MAX_STAMP_S:.0f}] seconds (a ROS time: int32 seconds since "
                         f"the epoch), got {value}")
    return value


def _heading(name: str, value) -> float:
    """A yaw (radians) normalised to ``(-pi, pi]``; one there already is returned unchanged."""
    value = _finite(name, value)
    if -math.pi < value <= math.pi:
        return value
    if abs(value) > MAX_ABS_YAW:
        raise ValueError(f"{name} must satisfy |yaw| <= {MAX_ABS_YAW:g} rad (beyond, a float64 angle has no "
                         f"usable direction), got {value}")
    value = math.remainder(value, math.tau)  # exact; in [-pi, pi]
    return math.pi if value <= -math.pi else value


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
        resolution = _finite("resolution_m", self.resolution_m)
        if resolution <= 0.0:
            raise ValueError(f"resolution_m must be positive, got {resolution}")
        try:
            origin = tuple(_finite("origin_xy", v) for v in self.origin_xy)
        except TypeError:
            raise ValueError(f"origin_xy must be an (x, y) pair, got {self.origin_xy!r}") from None
        if len(origin) != 2:
            raise ValueError(f"origin_xy must be an (x, y) pair, got {self.origin_xy!r}")
        check_map_size(shape, resolution, "the map frame")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "resolution_m", resolution)
        object.__setattr__(self, "origin_xy", origin)

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
            object.__setattr__(self, name, _finite(f"pose.{name}", getattr(self, name)))
        object.__setattr__(self, "yaw", _heading("pose.yaw", self.yaw))


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One line-of-sight scan (``sensor_msgs/LaserScan``), in the robot's frame.

    Ray ``i`` points at ``angle_min + i * angle_increment`` (radians, counter-clockwise from the robot's heading).
    Ranges follow REP 117:

    * in ``[range_min, range_max]``: a return, the sensor saw a surface at that distance;
    * ``+inf`` or above ``range_max``: no return, the ray saw nothing up to ``range_max`` (free up to there);
    * NaN (no measurement), ``-inf`` or below ``range_min`` (too close): an invalid reading, the ray says nothing
      and is skipped.

    Ranges are stored as float32: a float64 range beyond float32's span becomes ``+inf`` (no return) or ``-inf``
    (invalid), as the rules above read it.

    Attributes:
        angle_min: angle of the first ray (radians).
        angle_increment: angle between rays (radians, > 0: angles increase).
        range_min, range_max: valid range limits (metres, ``0 <= range_min < range_max``).
        ranges: float32 ``[n_rays]`` metres.
        angle_max: angle of the last ray; None: derived from the others. When given (as ROS messages carry it), the
            number of ranges must match ``(angle_max - angle_min) / angle_increment + 1``.
    """

    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    angle_max: Optional[float] = None

    def __post_init__(self) -> None:
        for name in ("angle_min", "angle_increment", "range_min", "range_max"):
            object.__setattr__(self, name, _float32(f"scan.{name}", getattr(self, name)))
        if not self.angle_increment > 0.0:
            raise ValueError(f"scan angles must increase: angle_increment must be > 0, got {self.angle_increment}")
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(f"scan range limits must satisfy 0 <= range_min < range_max, got range_min="
                             f"{self.range_min}, range_max={self.range_max}")
        ranges = np.asarray(self.ranges)
        if ranges.ndim != 1 or ranges.size < 1 or not np.issubdtype(ranges.dtype, np.floating):
            raise ValueError(f"scan.ranges must be a non-empty 1-D float array, got {ranges.dtype} {ranges.shape}")
        if self.angle_increment * (ranges.size - 1) >= 2.0 * math.pi + 1e-6:
            raise ValueError(f"{ranges.size} rays at an increment of {self.angle_increment} rad cover more than a "
                             f"full turn")
        derived = float(np.float32(self.angle_min + (ranges.size - 1) * self.angle_increment))
        if self.angle_max is not None:
            angle_max = _float32("scan.angle_max", self.angle_max)
            expected = int(round((angle_max - self.angle_min) / self.angle_increment)) + 1
            if expected != ranges.size:
                raise ValueError(f"scan has {ranges.size} ranges, but its angles from {self.angle_min} to {angle_max} "
                                 f"rad at {self.angle_increment} rad need {expected}")
        object.__setattr__(self, "angle_max", derived)
        with np.errstate(over="ignore"):  # beyond float32: +-inf, read as above (no return / invalid)
            ranges = ranges.astype(np.float32)
        ranges.flags.writeable = False
        object.__setattr__(self, "ranges", ranges)

    @property
    def n_rays(self) -> int:
        return int(self.ranges.shape[0])

    def angles(self) -> np.ndarray:
        """float64 ``[n_rays]`` ray angles in the robot's frame (radians)."""
        return self.angle_min + np.arange(self.n_rays, dtype=np.float64) * self.angle_increment


@dataclass(frozen=True, eq=False)
class SpadFrame:
    """One SPAD LiDAR frame: a time-of-flight histogram per ray, stored by its non-zero bins.

    A documented message (no ROS equivalent exists; see :mod:`superex_deploy.recording` for its schema). Bin ``b``
    of a ray counts photons whose round-trip path lies in ``[b, b + 1) * bin_width_s * c``.

    Attributes:
        angles: float64 ``[n_rays]`` ray angles in the robot's frame (radians, counter-clockwise from its heading).
        bin_width_s: bin width (seconds, > 0).
        n_bins: bins per ray (>= 1).
        row_start: int64 ``[n_rays + 1]``; ray ``i``'s entries are ``row_start[i]:row_start[i + 1]``.
        bins: int32 ``[nnz]`` bin indices, strictly increasing within a ray, in ``[0, n_bins)``.
        counts: float32 ``[nnz]`` photon counts (finite, >= 0).
    """

    angles: np.ndarray
    bin_width_s: float
    n_bins: int
    row_start: np.ndarray
    bins: np.ndarray
    counts: np.ndarray

    def __post_init__(self) -> None:
        angles = np.asarray(self.angles)
        if angles.ndim != 1 or angles.size < 1 or not np.issubdtype(angles.dtype, np.floating) \
                or not np.all(np.isfinite(angles)):
            raise ValueError(f"spad.angles must be a non-empty 1-D array of finite floats, got {angles.dtype} "
                             f"{angles.shape}")
        bin_width = _finite("spad.bin_width_s", self.bin_width_s)
        if bin_width <= 0.0:
            raise ValueError(f"spad.bin_width_s must be positive, got {bin_width}")
        if not isinstance(self.n_bins, (int, np.integer)) or isinstance(self.n_bins, bool) or self.n_bins < 1:
            raise ValueError(f"spad.n_bins must be a positive integer, got {self.n_bins!r}")
        n_bins = int(self.n_bins)
        row_start, bins, counts = (np.asarray(a) for a in (self.row_start, self.bins, self.counts))
        if row_start.shape != (angles.size + 1,) or not np.issubdtype(row_start.dtype, np.integer):
            raise ValueError(f"spad.row_start must be an integer array of n_rays + 1 = {angles.size + 1} entries, "
                             f"got {row_start.dtype} {row_start.shape}")
        if row_start[0] != 0 or np.any(np.diff(row_start) < 0) or row_start[-1] != bins.size:
            raise ValueError("spad.row_start must start at 0, never decrease and end at the number of entries")
        if bins.ndim != 1 or counts.shape != bins.shape or not np.issubdtype(bins.dtype, np.integer) \
                or not np.issubdtype(counts.dtype, np.floating):
            raise ValueError(f"spad.bins (integer) and spad.counts (float) must be 1-D arrays of one length, got "
                             f"{bins.dtype} {bins.shape} and {counts.dtype} {counts.shape}")
        if bins.size and (bins.min() < 0 or bins.max() >= n_bins):
            raise ValueError(f"spad.bins must lie in [0, n_bins = {n_bins})")
        if bins.size and not (np.all(np.isfinite(counts)) and counts.min() >= 0.0):
            raise ValueError("spad.counts must be finite and non-negative")
        same_ray = np.repeat(np.arange(angles.size), np.diff(row_start))
        if bins.size > 1 and np.any((np.diff(bins) <= 0) & (same_ray[1:] == same_ray[:-1])):
            raise ValueError("spad.bins must increase strictly within each ray")
        for name, array, dtype in (("angles", angles, np.float64), ("row_start", row_start, np.int64),
                                   ("bins", bins, np.int32), ("counts", counts, np.float32)):
            array = np.ascontiguousarray(array, dtype)
            array.flags.writeable = False
            object.__setattr__(self, name, array)
        object.__setattr__(self, "bin_width_s", bin_width)
        object.__setattr__(self, "n_bins", n_bins)

    @property
    def n_rays(self) -> int:
        return int(self.angles.shape[0])

    @classmethod
    def from_dense(cls, angles, bin_width_s: float, histograms: np.ndarray) -> "SpadFrame":
        """A frame from dense float32 ``[n_rays, n_bins]`` histograms (zero bins are dropped)."""
        histograms = np.asarray(histograms)
        if histograms.ndim != 2 or not np.issubdtype(histograms.dtype, np.floating):
            raise ValueError(f"histograms must be a float [n_rays, n_bins] array, got {histograms.dtype} "
                             f"{histograms.shape}")
        if not (np.all(np.isfinite(histograms)) and histograms.min(initial=0.0) >= 0.0):
            raise ValueError("histograms must be finite and non-negative")
        rows, bins = np.nonzero(histograms > 0)
        row_start = np.zeros(histograms.shape[0] + 1, np.int64)
        np.cumsum(np.bincount(rows, minlength=histograms.shape[0]), out=row_start[1:])
        return cls(angles=angles, bin_width_s=bin_width_s, n_bins=histograms.shape[1], row_start=row_start,
                   bins=bins.astype(np.int32), counts=histograms[rows, bins].astype(np.float32))

    def to_dense(self) -> np.ndarray:
        """float32 ``[n_rays, n_bins]`` histograms."""
        out = np.zeros((self.n_rays, self.n_bins), np.float32)
        rows = np.repeat(np.arange(self.n_rays), np.diff(self.row_start))
        out[rows, self.bins] = self.counts
        return out


@dataclass(frozen=True, eq=False)
class Observation:
    """What the robot measures at one step: everything :meth:`superex_deploy.onboard.Explorer.step` receives.

    Attributes:
        stamp_s: time stamp (seconds; see :func:`check_stamp`: finite, in ``[0, MAX_STAMP_S]``).
        pose: the robot's pose in the map frame (where both scans were taken).
        scan: the line-of-sight scan.
        spad: the SPAD frame, or None (no NLOS sensing this step).
    """

    stamp_s: float
    pose: Pose2D
    scan: LaserScan
    spad: Optional[SpadFrame] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stamp_s", check_stamp("stamp_s", self.stamp_s))
        if not isinstance(self.pose, Pose2D):
            raise ValueError(f"pose must be a Pose2D, got {type(self.pose).__name__}")
        if not isinstance(self.scan, LaserScan):
            raise ValueError(f"scan must be a LaserScan, got {type(self.scan).__name__}")
        if self.spad is not None and not isinstance(self.spad, SpadFrame):
            raise ValueError(f"spad must be a SpadFrame or None, got {type(self.spad).__name__}")


@dataclass(frozen=True, eq=False)
class Command:
    """What the explorer answers to one observation.

    Attributes:
        stamp_s: the observation's time stamp (seconds).
        goal_xy: map-frame goal (metres), or None (no goal: see ``finished``).
        goal_rc: the goal cell ``(row, col)``, or None.
        path_xy: float64 ``[N, 2]`` map-frame waypoints (metres) from the robot's cell to the goal (cell centres;
            empty without a goal).
        path_rc: int64 ``[N, 2]`` the same waypoints as cells.
        finished: True when the explorer's map holds known cells and no reachable frontier is left: the
            exploration is over. False while a goal is set, and also without a goal while the map is still empty
            (no observation so far had a valid reading): the next observation may see something.
        new_goal: True when the goal was chosen at this step.
        prediction: the newest predicted map (see :class:`superex_deploy.onboard.types.Prediction`), or None when
            the planner has not needed one yet.
        prediction_step: the step the prediction was made at (its age is ``step - prediction_step``), or -1.
        step: the explorer's step counter (0 for the first observation).
        timings_s: seconds spent per stage of this step (see :data:`superex_deploy.onboard.explorer.STAGES`).
    """

    stamp_s: float
    goal_xy: Optional[tuple[float, float]]
    goal_rc: Optional[tuple[int, int]]
    path_xy: np.ndarray
    path_rc: np.ndarray
    finished: bool
    new_goal: bool
    prediction: Optional[object] = None
    prediction_step: int = -1
    step: int = 0
    timings_s: dict = field(default_factory=dict)

