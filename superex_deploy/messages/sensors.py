"""The robot's sensor messages: the line-of-sight :class:`LaserScan` and the :class:`SpadFrame` of histograms."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.messages.limits import check_finite, check_float32

__all__ = ["LaserScan", "SpadFrame"]


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One line-of-sight scan (``sensor_msgs/LaserScan``), in the robot's frame.

    Ray ``i`` points at ``angle_min + i * angle_increment`` (radians, counter-clockwise from the robot's heading).
    Ranges follow REP 117:

    * in ``[range_min, range_max)``: a return, the sensor saw a surface at that distance;
    * ``+inf``, or ``range_max`` and above: no return, the ray saw nothing up to ``range_max`` (free up to there).
      Gazebo and several drivers report "no return" as exactly ``range_max``, and costmap_2d's ``laser_geometry``
      keeps only ``range < range_max`` as a return: a reading at ``range_max`` is never a wall;
    * NaN (no measurement), ``-inf`` or below ``range_min`` (too close): an invalid reading, the ray says nothing
      and is skipped.

    Ranges are stored as float32: a float64 range beyond float32's span becomes ``+inf`` (no return) or ``-inf``
    (invalid), as the rules above read it.

    Attributes:
        angle_min: angle of the first ray (radians).
        angle_increment: angle between rays (radians, non-zero). A clockwise scanner's negative increment is
            accepted and the scan stored counter-clockwise: ``angle_min`` becomes its last ray's angle, the
            increment positive, the ranges reversed (the same rays; what :meth:`angles` gives matches ``ranges``).
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
            object.__setattr__(self, name, check_float32(f"scan.{name}", getattr(self, name)))
        if self.angle_increment == 0.0:
            raise ValueError("scan.angle_increment must not be 0")
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(f"scan range limits must satisfy 0 <= range_min < range_max, got range_min="
                             f"{self.range_min}, range_max={self.range_max}")
        ranges = np.asarray(self.ranges)
        if ranges.ndim != 1 or ranges.size < 1 or not np.issubdtype(ranges.dtype, np.floating):
            raise ValueError(f"scan.ranges must be a non-empty 1-D float array, got {ranges.dtype} {ranges.shape}")
        if abs(self.angle_increment) * (ranges.size - 1) >= 2.0 * math.pi + 1e-6:
            raise ValueError(f"{ranges.size} rays at an increment of {self.angle_increment} rad cover more than a "
                             f"full turn")
        derived = float(np.float32(self.angle_min + (ranges.size - 1) * self.angle_increment))
        if self.angle_max is not None:
            angle_max = check_float32("scan.angle_max", self.angle_max)
            expected = int(round((angle_max - self.angle_min) / self.angle_increment)) + 1
            if expected != ranges.size:
                raise ValueError(f"scan has {ranges.size} ranges, but its angles from {self.angle_min} to {angle_max} "
                                 f"rad at {self.angle_increment} rad need {expected}")
        with np.errstate(over="ignore"):  # beyond float32: +-inf, read as above (no return / invalid)
            ranges = ranges.astype(np.float32)
        if self.angle_increment < 0.0:  # a clockwise scanner: the same rays, stored counter-clockwise
            object.__setattr__(self, "angle_min", derived)
            object.__setattr__(self, "angle_increment", -self.angle_increment)
            derived = float(np.float32(self.angle_min + (ranges.size - 1) * self.angle_increment))
            ranges = ranges[::-1].copy()
        object.__setattr__(self, "angle_max", derived)
        ranges.flags.writeable = False
        object.__setattr__(self, "ranges", ranges)

    @property
    def n_rays(self) -> int:
        return int(self.ranges.shape[0])

    def angles(self) -> np.ndarray:
        """float64 ``[n_rays]`` ray angles in the robot's frame (radians)."""
        return self.angle_min + np.arange(self.n_rays, dtype=np.float64) * self.angle_increment

    def mirrored(self) -> "LaserScan":
        """The scan as an upright sensor would report the same rays when this one is mounted upside down (rolled by
        pi, its z axis pointing down): a ray at angle ``theta`` of the rolled sensor points along ``-theta`` of the
        upright one, so the angles are negated (and, stored counter-clockwise, the ranges reversed), as
        ``laser_geometry`` projects a rolled scanner. Twice mirrored is the scan itself."""
        return LaserScan(angle_min=-self.angle_min, angle_increment=-self.angle_increment, range_min=self.range_min,
                         range_max=self.range_max, ranges=self.ranges)


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
        bin_width = check_finite("spad.bin_width_s", self.bin_width_s)
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
