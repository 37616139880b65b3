"""Rigid 3-D transforms in numpy: :class:`Transform` (a translation and a unit quaternion in ROS order, composed,
inverted, interpolated as tf2 interpolates) and :func:`planar`, the projection of a 2-D LiDAR's 3-D pose onto the
map plane.

A :class:`~superex_deploy.ros.tf.TfBuffer` stores and returns these transforms; the exploration node and the bag
reader project its lookups with :func:`planar`. Nothing of ROS is imported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Transform", "planar"]


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product ``a b`` of quaternions in ROS order ``(x, y, z, w)``."""
    ax, ay, az, aw = a.tolist()
    bx, by, bz, bw = b.tolist()
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` [3] rotated by the unit quaternion ``q``: ``v + 2 w (u x v) + 2 u x (u x v)``, ``u`` its vector part."""
    x, y, z, w = q.tolist()
    vx, vy, vz = v.tolist()
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    return np.array([vx + 2.0 * (w * cx + y * cz - z * cy), vy + 2.0 * (w * cy + z * cx - x * cz),
                     vz + 2.0 * (w * cz + x * cy - y * cx)])


def _sinc(x: float) -> float:
    """``sin(x) / x``, 1 at 0."""
    return math.sin(x) / x if abs(x) > 1e-8 else 1.0 - x * x / 6.0


@dataclass(frozen=True, eq=False)
class Transform:
    """A rigid transform: the pose of a child frame in its parent, mapping the child's points into the parent.

    Attributes:
        translation: float64 [3], the child's origin in the parent (metres).
        rotation: float64 [4], a unit quaternion in ROS order ``(x, y, z, w)``, normalised on construction.

    Raises:
        ValueError: a translation or rotation of another size, not finite, or a rotation of zero norm.
    """

    translation: np.ndarray = (0.0, 0.0, 0.0)
    rotation: np.ndarray = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        try:
            translation = np.array(self.translation, np.float64).reshape(3)
            rotation = np.array(self.rotation, np.float64).reshape(4)
        except (TypeError, ValueError):
            raise ValueError(f"a transform needs 3 translation and 4 rotation numbers, got {self.translation!r} "
                             f"and {self.rotation!r}") from None
        norm = float(np.sqrt(rotation @ rotation)) if np.all(np.isfinite(rotation)) else math.nan
        if not (np.all(np.isfinite(translation)) and math.isfinite(norm) and norm > 1e-12):
            raise ValueError(f"a transform needs a finite translation and a finite non-zero quaternion, got "
                             f"translation {translation.tolist()} rotation {rotation.tolist()}")
        rotation /= norm
        translation.flags.writeable = rotation.flags.writeable = False
        object.__setattr__(self, "translation", translation)
        object.__setattr__(self, "rotation", rotation)

    @classmethod
    def _of(cls, translation: np.ndarray, rotation: np.ndarray) -> "Transform":
        """A transform of values known to be finite (products of valid ones): normalised, not checked."""
        transform = object.__new__(cls)
        rotation = rotation / np.sqrt(rotation @ rotation)
        translation = np.asarray(translation, np.float64)
        translation.flags.writeable = rotation.flags.writeable = False
        object.__setattr__(transform, "translation", translation)
        object.__setattr__(transform, "rotation", rotation)
        return transform

    @classmethod
    def from_planar(cls, x: float, y: float, yaw: float) -> "Transform":
        """The transform of a planar pose: ``(x, y, 0)`` metres, turned by ``yaw`` radians about ``z``."""
        return cls((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)))

    def compose(self, other: "Transform") -> "Transform":
        """``self * other``: with ``self`` frame B in frame A and ``other`` frame C in frame B, frame C in frame A
        (maps points of ``other``'s child frame into ``self``'s parent frame)."""
        return Transform._of(self.translation + _rotate(self.rotation, other.translation),
                             _multiply(self.rotation, other.rotation))

    def inverse(self) -> "Transform":
        """The parent's pose in the child frame."""
        conjugate = self.rotation * np.array([-1.0, -1.0, -1.0, 1.0])
        return Transform._of(-_rotate(conjugate, self.translation), conjugate)

    def apply(self, points) -> np.ndarray:
        """Points of the child frame (float [N, 3] or [3], metres) in the parent frame (float64, same shape)."""
        points = np.asarray(points, np.float64)
        if points.shape[-1:] != (3,) or points.ndim > 2:
            raise ValueError(f"points must be [N, 3] or [3], got shape {points.shape}")
        return points @ self.matrix()[:3, :3].T + self.translation

    def interpolate(self, other: "Transform", ratio: float) -> "Transform":
        """The transform ``ratio`` of the way from ``self`` (0) to ``other`` (1), as tf2 interpolates between two
        samples: the translation linearly, the rotation by slerp along the shorter arc (a yaw from 170 to -170
        degrees passes through 180). A ratio outside [0, 1] extrapolates along the same lines."""
        q1, q2 = self.rotation, other.rotation
        if q1 @ q2 < 0.0:
            q2 = -q2
        theta = 2.0 * math.atan2(math.dist(q2, q1), math.dist(q2, -q1))  # their angle, accurate near 0 and pi/2
        w1, w2 = (1.0 - ratio) * _sinc((1.0 - ratio) * theta), ratio * _sinc(ratio * theta)  # sin(r theta) / ...
        scale = _sinc(theta)  # ... sin(theta), robust at theta -> 0
        w1, w2 = w1 / scale, w2 / scale
        return Transform._of(self.translation + ratio * (other.translation - self.translation), w1 * q1 + w2 * q2)

    def matrix(self) -> np.ndarray:
        """The homogeneous 4 x 4 matrix (float64): rotation block and translation column."""
        x, y, z, w = self.rotation
        out = np.eye(4)
        out[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                       [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                       [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
        out[:3, 3] = self.translation
        return out

    def planar(self, frame: str = "the sensor", tilt_tolerance_rad: float = 0.05) -> tuple[float, float, float, bool]:
        """This pose of a 2-D LiDAR projected onto the map plane: :func:`planar`."""
        return planar(self, frame, tilt_tolerance_rad)


def planar(transform: Transform, frame: str, tilt_tolerance_rad: float = 0.05) -> tuple[float, float, float, bool]:
    """Project a 2-D LiDAR's 3-D pose (its frame in the map frame) onto the map plane.

    Args:
        transform: the sensor frame's pose in the map frame (``lookup(map, sensor, t)``).
        frame: the sensor frame's name, for the error message.
        tilt_tolerance_rad: the largest angle between the sensor's ``z`` axis and the map's vertical (up or down).

    Returns:
        ``(x, y, yaw, mirrored)``: the sensor's position in metres (its height dropped), the heading of its ``x``
        axis in radians (-pi, pi], and whether its ``z`` axis points down (a laser mounted upside down, roll = pi,
        whose counter-clockwise scan angles turn clockwise in the map, as ``laser_geometry`` projects it). A return
        at scan angle ``theta`` and range ``r`` lands at ``(x + r cos(yaw + theta), y + r sin(yaw + theta))``, or at
        ``(x + r cos(yaw - theta), y + r sin(yaw - theta))`` when mirrored.

    Raises:
        ValueError: a sensor tilted more than ``tilt_tolerance_rad`` (a non-planar mount scans a cone, not the
            map's plane).
    """
    rotation = transform.matrix()[:3, :3]
    tilt = math.atan2(math.hypot(rotation[0, 2], rotation[1, 2]), abs(rotation[2, 2]))
    if not tilt <= tilt_tolerance_rad:
        raise ValueError(f"the frame {frame!r} is tilted {math.degrees(tilt):.2f} deg from the vertical (at most "
                         f"{math.degrees(tilt_tolerance_rad):.2f} deg): a non-planar mount cannot be used by a 2-D "
                         f"explorer")
    yaw = math.atan2(rotation[1, 0], rotation[0, 0])
    return (float(transform.translation[0]), float(transform.translation[1]), math.pi if yaw == -math.pi else yaw,
            bool(rotation[2, 2] < 0.0))
