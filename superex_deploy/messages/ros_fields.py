"""ROS messages into SuperEx's messages, read by their field names: one conversion for every place a ROS message
comes from (a bag read with ``rosbags``, a recording decoded by ``mcap_ros2``, a live topic deserialised by Cyclone
DDS), since all three give objects with the ROS fields.

* :func:`stamp_seconds` of a ``builtin_interfaces/Time`` (and :func:`stamp_message` back); :func:`yaw_of` of a ``geometry_msgs/Quaternion`` (the
  rotation about ``z`` of its planar part);
* :func:`laser_scan`: ``sensor_msgs/LaserScan`` -> :class:`~superex_deploy.messages.LaserScan` (float32 ranges,
  ``angle_max`` checked against the ranges' count);
* :func:`occupancy_grid`: ``nav_msgs/OccupancyGrid`` -> :class:`~superex_deploy.messages.OccupancyGridMessage` with
  its header stamp and origin yaw (a rotated origin is refused there, with one error);
* :func:`pose_covariance`: the ``x, y, yaw`` block of a ``geometry_msgs/PoseWithCovariance`` (None when all zero:
  a source that fills no covariance);
* :func:`spad_frame` / :func:`spad_fields`: ``superex_msgs/SpadFrame`` (its arrays are little-endian byte blobs,
  :data:`~superex_deploy.recording.schemas.SPAD_FRAME_MSG`) <-> :class:`~superex_deploy.messages.SpadFrame`.

Each raises ``ValueError`` for a message the SuperEx type refuses (its checks name what is wrong).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from superex_deploy.messages.frame import Pose2D
from superex_deploy.messages.occupancy import OccupancyGridMessage, PoseCovariance
from superex_deploy.messages.sensors import LaserScan, SpadFrame

__all__ = ["stamp_seconds", "stamp_message", "yaw_of", "planar_pose", "laser_scan", "occupancy_grid", "pose_covariance",
           "spad_frame", "spad_fields"]


def stamp_seconds(stamp) -> float:
    """Seconds (float) of a ROS time (an object with ``sec`` and ``nanosec``)."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def stamp_message(seconds: float) -> dict:
    """A ROS 2 time ``{"sec", "nanosec"}`` (ints) of ``seconds`` (float, rounded to the nanosecond)."""
    nanoseconds = int(round(seconds * 1e9))
    return {"sec": nanoseconds // 1_000_000_000, "nanosec": nanoseconds % 1_000_000_000}


def yaw_of(q) -> float:
    """The yaw (radians) of a quaternion with fields ``x, y, z, w``: the heading of its rotated ``x`` axis in the
    plane."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def planar_pose(pose) -> Pose2D:
    """The planar :class:`~superex_deploy.messages.Pose2D` of a ``geometry_msgs/Pose`` (x, y and yaw)."""
    return Pose2D(float(pose.position.x), float(pose.position.y), yaw_of(pose.orientation))


def laser_scan(message) -> LaserScan:
    """The :class:`~superex_deploy.messages.LaserScan` of a ``sensor_msgs/LaserScan``.

    Raises:
        ValueError: what :class:`~superex_deploy.messages.LaserScan` refuses (no ranges, ``range_min >=
            range_max``, angles that do not match the ranges).
    """
    return LaserScan(angle_min=float(message.angle_min), angle_increment=float(message.angle_increment),
                     range_min=float(message.range_min), range_max=float(message.range_max),
                     ranges=np.asarray(message.ranges, np.float32), angle_max=float(message.angle_max))


def occupancy_grid(message, resolution_as: Optional[float] = None) -> OccupancyGridMessage:
    """The :class:`~superex_deploy.messages.OccupancyGridMessage` of a ``nav_msgs/OccupancyGrid`` (its header
    stamp as ``stamp_s``); ``resolution_as``: a resolution (metres) to take instead of the message's float32 one
    when both agree at float32 (a recording's frame).

    Raises:
        ValueError: a rotated origin, values outside -1..100, a data length that is not ``width * height``.
    """
    from superex_deploy.messages.occupancy import same_resolution

    info = message.info
    resolution = float(info.resolution)
    if resolution_as is not None and same_resolution(resolution, resolution_as):
        resolution = float(resolution_as)
    return OccupancyGridMessage(resolution_m=resolution, width=int(info.width), height=int(info.height),
                                origin_xy=(float(info.origin.position.x), float(info.origin.position.y)),
                                data=np.asarray(message.data, np.int8), stamp_s=stamp_seconds(message.header.stamp),
                                origin_yaw=yaw_of(info.origin.orientation))


def pose_covariance(covariance36) -> Optional[PoseCovariance]:
    """The :class:`~superex_deploy.messages.PoseCovariance` of a ``geometry_msgs/PoseWithCovariance.covariance``
    (36 values), or None when all of them are 0 (a source that fills none: the pose is then taken as exact).

    Raises:
        ValueError: not 36 values, a non-finite, asymmetric or not positive semi-definite ``x, y, yaw`` block.
    """
    values = np.asarray(covariance36, np.float64)
    if values.size and not np.any(values):
        return None
    return PoseCovariance.from_ros(values)


def spad_frame(message) -> SpadFrame:
    """The :class:`~superex_deploy.messages.SpadFrame` of a ``superex_msgs/SpadFrame`` (byte blobs decoded).

    Raises:
        ValueError: blobs of the wrong length for their counts, or what :class:`SpadFrame` refuses.
    """
    def blob(name: str, dtype: str, count: int) -> np.ndarray:
        data = bytes(getattr(message, name))
        size = np.dtype(dtype).itemsize
        if len(data) != count * size:
            raise ValueError(f"SpadFrame.{name} holds {len(data)} bytes, {count} values of {size} bytes expected")
        return np.frombuffer(data, dtype)

    n_rays, nnz = int(message.n_rays), int(message.nnz)
    return SpadFrame(angles=blob("angles_f64le", "<f8", n_rays), bin_width_s=float(message.bin_width_s),
                     n_bins=int(message.n_bins), row_start=blob("row_start_i64le", "<i8", n_rays + 1),
                     bins=blob("bins_i32le", "<i4", nnz), counts=blob("counts_f32le", "<f4", nnz))


def spad_fields(spad: SpadFrame) -> dict:
    """The fields of a ``superex_msgs/SpadFrame`` (but its header) for ``spad``: counts and little-endian blobs."""
    return {"bin_width_s": float(spad.bin_width_s), "n_rays": spad.n_rays, "n_bins": int(spad.n_bins),
            "nnz": int(spad.bins.size), "angles_f64le": spad.angles.astype("<f8").tobytes(),
            "row_start_i64le": spad.row_start.astype("<i8").tobytes(),
            "bins_i32le": spad.bins.astype("<i4").tobytes(), "counts_f32le": spad.counts.astype("<f4").tobytes()}
