"""A transform buffer with the semantics of ROS 2's tf2 (``tf2::BufferCore``), over the rigid 3-D transforms in numpy
of :mod:`superex_deploy.ros.rigid` (:class:`~superex_deploy.ros.rigid.Transform`).

A live ROS 2 node feeds :class:`TfBuffer` the ``tf2_msgs/TFMessage`` of ``/tf`` and ``/tf_static``
(:meth:`TfBuffer.add_message`; cyclonedds messages and ``rosbags``' deserialised ones share the field names), a bag
reader does the same from the bag, and both ask :meth:`TfBuffer.lookup` for the pose of a scan's frame in the map
at the scan's stamp. Nothing of ROS is imported.

What tf2 does, and this does too:

* frame ids lose a leading ``/``; a transform whose parent is its child, an empty frame id, a non-finite value or
  (in messages) a quaternion whose squared norm is 0.01 or more away from 1 is refused;
* dynamic transforms are kept per child frame in stamp order (out-of-order arrivals are sorted in); those older than
  ``cache_s`` behind the child's newest are dropped, and one arriving older than that is ignored (``TF_OLD_DATA``);
  a second transform at a stamp already held is ignored (``TF_REPEATED_DATA``, as Humble does); static transforms
  hold at every stamp, a new one replacing the old; a child that switches between static and dynamic loses its
  history (the newest kind wins);
* every sample keeps its own parent: a child given a new parent has the new one from that sample's stamp on (a
  lookup at the latest time, or after the change, walks the new tree; a lookup at an earlier stamp still walks the
  old one), and between two samples of different parents the older is used without interpolation;
* a lookup walks both frames up to their nearest common ancestor (links above it are never read), interpolating
  each dynamic link between the samples bracketing the stamp (translation lerp, rotation slerp along the shorter
  arc); a stamp of exactly 0 means the latest time at which every link of that path has data; ``lookup(a, a, t)``
  is the identity, even for a frame never seen;
* errors are tf2's, as :class:`TransformError` (a ``LookupError``) subclasses with tf2's wording.

What differs: stamps are float seconds (``sec + 1e-9 nanosec``, as :func:`stamp_seconds` gives them and the bag
reader computes them: equal header stamps give equal floats); ``max_extrapolation_s`` lets a lookup just outside
a link's data **hold** its nearest sample (default 0: tf2 exactly, which never extrapolates; a scan stamped 20 ms
after the newest /tf can take it instead of failing). Holding, not linear extrapolation: holding never invents
motion, and its error is bounded by how far the frame moves within the window (1 cm at 1 m/s over 10 ms).
Linear extrapolation wins only while the motion is smooth, and turns every step of a transform into a velocity
(measured in ``tests/test_ros_tf.py``, 50 ms past the newest sample: at a constant 1 m/s and 1 rad/s from 20 Hz
samples, held 5 cm off, extrapolated 2.5 mm; after a 5 cm localisation correction of ``map -> odom`` between 10 Hz
samples, held exact, extrapolated 2.5 cm off; a robot that stopped at its newest sample, extrapolated 5 cm off).
A window is meant to be short: a lookup that must be exact waits for /tf instead.
Two frames in unconnected trees raise :class:`ConnectivityError` even when a link on the way also lacks data (tf2
then reports the extrapolation). :meth:`TfBuffer.add` takes a :class:`Transform`, normalised whatever its norm
(only :meth:`TfBuffer.add_message` applies tf2's quaternion check). :meth:`TfBuffer.newest_stamp` gives ``inf`` for
a static link (tf2 gives 0). The buffer takes one lock per call and may be shared between a subscription thread and
a timer's.
"""

from __future__ import annotations

import math
import threading
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from typing import Optional, Union

from superex_deploy.messages.ros_fields import stamp_message, stamp_seconds
from superex_deploy.ros.rigid import Transform

__all__ = ["TfBuffer", "stamp_seconds", "stamp_of", "TransformError", "UnknownFrameError", "ConnectivityError",
           "ExtrapolationError", "LoopError", "QUATERNION_TOLERANCE"]

QUATERNION_TOLERANCE = 0.01
"""A message's quaternion is refused when its squared norm is this far from 1 or more (tf2's
``QUATERNION_NORMALIZATION_TOLERANCE``); one within is normalised."""


def stamp_of(seconds: float) -> tuple[int, int]:
    """The ROS 2 time ``(sec, nanosec)`` (ints) of ``seconds``, rounded to the nanosecond."""
    stamp = stamp_message(seconds)
    return stamp["sec"], stamp["nanosec"]


class TransformError(LookupError):
    """A transform the buffer cannot give (tf2's ``TransformException``)."""


class UnknownFrameError(TransformError):
    """A frame no transform has named (tf2's ``LookupException``)."""


class ConnectivityError(TransformError):
    """Two frames in unconnected trees (tf2's ``ConnectivityException``)."""


class ExtrapolationError(TransformError):
    """A link of the path holds no data at the stamp (tf2's ``ExtrapolationException``)."""


class LoopError(TransformError):
    """The tree holds a loop on the path (tf2 raises a ``LookupException``)."""


_IDENTITY = Transform()


@dataclass
class _Cache:
    """One child frame's transforms: static (one sample) or dynamic (samples in stamp order)."""

    static: bool
    stamps: list = field(default_factory=list)
    parents: list = field(default_factory=list)
    transforms: list = field(default_factory=list)


_LISTED = 40  # frames an error message lists


def _seconds(stamp_s, what: str) -> float:
    try:
        seconds = float(stamp_s)
    except (TypeError, ValueError):
        seconds = math.nan
    if not math.isfinite(seconds):
        raise ValueError(f"{what} needs a finite stamp in seconds, got {stamp_s!r}")
    return seconds


def _name(frame) -> str:
    return frame[1:] if isinstance(frame, str) and frame.startswith("/") else frame


class TfBuffer:
    """Transforms between frames over time, fed from ``/tf`` and ``/tf_static``, looked up as tf2 does.

    Args:
        cache_s: how long dynamic transforms are kept behind each child's newest (seconds; tf2's cache time).
        max_extrapolation_s: a lookup this far (seconds) past a link's newest sample or before its oldest holds
            that sample; 0 (default): none, tf2's rule.

    Attributes:
        rejected: transforms :meth:`add_message` skipped as invalid (bad frame ids or values).
        last_rejection: why the latest of them was skipped (None before any).
    """

    def __init__(self, cache_s: float = 10.0, max_extrapolation_s: float = 0.0) -> None:
        if not (isinstance(cache_s, (int, float)) and math.isfinite(cache_s) and cache_s > 0):
            raise ValueError(f"cache_s must be a positive number of seconds, got {cache_s!r}")
        if not (isinstance(max_extrapolation_s, (int, float)) and 0 <= max_extrapolation_s < math.inf):
            raise ValueError(f"max_extrapolation_s must be a finite number of seconds >= 0, got "
                             f"{max_extrapolation_s!r}")
        self.cache_s = float(cache_s)
        self.max_extrapolation_s = float(max_extrapolation_s)
        self.rejected = 0
        self.last_rejection: Optional[str] = None
        self._caches: dict[str, _Cache] = {}
        self._frames: set[str] = set()
        self._lock = threading.Lock()

    def add(self, parent: str, child: str, stamp_s: float, transform: Transform, static: bool = False) -> bool:
        """Store ``child``'s pose in ``parent`` at ``stamp_s`` (seconds; ignored for a static transform).

        Returns:
            True when stored; False when ignored as tf2 ignores it: older than ``cache_s`` behind the child's newest,
            or at a stamp the child already holds (the first one kept).

        Raises:
            ValueError: an empty frame id, a parent equal to its child (after stripping a leading ``/``), a stamp
                that is not finite (nothing is stored).
            TypeError: ``transform`` is not a :class:`Transform`.
        """
        parent, child = _name(parent), _name(child)
        if not (isinstance(parent, str) and isinstance(child, str) and parent and child):
            raise ValueError(f"a transform needs non-empty parent and child frame ids, got {parent!r} -> {child!r}")
        if parent == child:
            raise ValueError(f"a transform from frame {parent!r} to itself is refused (tf2's TF_SELF_TRANSFORM)")
        stamp_s = _seconds(stamp_s, f"the transform {parent!r} -> {child!r}")
        if not isinstance(transform, Transform):
            raise TypeError(f"the transform {parent!r} -> {child!r} must be a Transform, got "
                            f"{type(transform).__name__}")
        static = bool(static)
        with self._lock:
            cache = self._caches.get(child)
            if cache is None or cache.static != static:
                cache = self._caches[child] = _Cache(static)
            self._frames.update((parent, child))
            if static:
                cache.stamps[:], cache.parents[:], cache.transforms[:] = [stamp_s], [parent], [transform]
                return True
            stamps = cache.stamps
            if stamps and stamp_s < stamps[-1] - self.cache_s:
                return False
            index = bisect_left(stamps, stamp_s)
            if index < len(stamps) and stamps[index] == stamp_s:
                return False
            stamps.insert(index, stamp_s)
            cache.parents.insert(index, parent)
            cache.transforms.insert(index, transform)
            old = bisect_left(stamps, stamps[-1] - self.cache_s)
            if old:
                del stamps[:old], cache.parents[:old], cache.transforms[:old]
            return True

    def add_message(self, message, static: bool) -> int:
        """Store every transform of a ``tf2_msgs/TFMessage`` (``static``: from ``/tf_static``).

        The message is read by ROS field names (``transforms[i].header.frame_id``, ``.header.stamp.sec`` /
        ``.nanosec``, ``.child_frame_id``, ``.transform.translation.x`` ..., ``.transform.rotation.x`` ...), so
        cyclonedds and ``rosbags`` messages both work. A transform that is invalid (see :meth:`add`, or a quaternion
        whose squared norm is :data:`QUATERNION_TOLERANCE` or more away from 1) is skipped and counted in
        :attr:`rejected`: a bad message from the network never raises here nor reaches the buffer.

        Returns:
            how many transforms were stored.
        """
        stored = 0
        for item in message.transforms:
            try:
                t, q = item.transform.translation, item.transform.rotation
                rotation = [float(q.x), float(q.y), float(q.z), float(q.w)]
                squared = sum(v * v for v in rotation)
                if not abs(squared - 1.0) < QUATERNION_TOLERANCE:
                    raise ValueError(f"the quaternion {rotation} is not normalised (tf2's TF_DENORMALIZED_QUATERNION)")
                transform = Transform((float(t.x), float(t.y), float(t.z)), rotation)
                stamp = stamp_seconds(item.header.stamp)
                stored += self.add(item.header.frame_id, item.child_frame_id, stamp, transform, static)
            except (ValueError, TypeError, AttributeError) as error:
                self.rejected += 1
                parent = getattr(getattr(item, "header", None), "frame_id", "?")
                child = getattr(item, "child_frame_id", "?")
                self.last_rejection = f"transform {parent!r} -> {child!r} skipped: {error}"
        return stored

    def frames(self) -> set[str]:
        """Every frame named by a stored transform, as parent or child (leading ``/`` stripped)."""
        with self._lock:
            return set(self._frames)

    def newest_stamp(self, child: str) -> Optional[float]:
        """The newest stamp (seconds) of ``child``'s transform to its parent: ``inf`` for a static one (it holds at
        every stamp), None when no transform has ``child`` as its child (a root frame, or one never seen)."""
        with self._lock:
            cache = self._caches.get(_name(child))
            return None if cache is None else math.inf if cache.static else cache.stamps[-1]

    def can_transform(self, target: str, source: str, stamp_s: float) -> bool:
        """Whether :meth:`lookup` would give the transform (without raising a :class:`TransformError`)."""
        try:
            self.lookup(target, source, stamp_s)
        except TransformError:
            return False
        return True

    def latest_common_time(self, target: str, source: str) -> float:
        """The newest stamp (seconds) at which every dynamic link between ``target`` and ``source`` has data (each
        link's newest parent followed, as tf2's ``getLatestCommonTime``); 0.0 when the path is all static; for a
        frame with itself, its own newest stamp (0.0 for a root or a static link).

        Raises:
            UnknownFrameError, ConnectivityError, LoopError: as :meth:`lookup`.
        """
        target, source = _name(target), _name(source)
        with self._lock:
            return self._latest_common_time(target, source)

    def lookup(self, target: str, source: str, stamp_s: float) -> Transform:
        """The pose of frame ``source`` in frame ``target`` at ``stamp_s`` (tf2's ``lookupTransform(target, source,
        time)``): it maps points of ``source`` into ``target``.

        Args:
            target, source: frame ids (a leading ``/`` is stripped).
            stamp_s: seconds; exactly 0.0: the latest common time (:meth:`latest_common_time`).

        Raises:
            UnknownFrameError: a frame no transform has named (or an empty one).
            ConnectivityError: the two frames are in unconnected trees.
            ExtrapolationError: a link of the path has no data within ``max_extrapolation_s`` of the stamp (the
                message names the link, the stamp and the link's data range).
            LoopError: a loop on the path.
            ValueError: a stamp that is not finite.
        """
        target, source = _name(target), _name(source)
        stamp_s = _seconds(stamp_s, "the lookup")
        if target == source:
            return _IDENTITY
        with self._lock:
            stamp_s = self._latest_common_time(target, source) if stamp_s == 0.0 else stamp_s
            return self._walk(target, source, stamp_s)

    # -- under the lock ----------------------------------------------------------------------------------------------

    def _check(self, target: str, source: str) -> None:
        for role, frame in (("target", target), ("source", source)):
            if not isinstance(frame, str) or frame not in self._frames:
                what = "an empty frame id" if frame == "" else f'"{frame}"'
                raise UnknownFrameError(f"{what} passed to lookup argument {role} does not exist; the buffer holds "
                                        f"{self._listing()}")

    def _listing(self) -> str:
        if not self._frames:
            return "no frames"
        described = []
        for frame in sorted(self._frames)[:_LISTED]:
            cache = self._caches.get(frame)
            described.append(f"{frame} (root)" if cache is None else f"{frame} (parent {cache.parents[-1]}"
                             f"{', static' if cache.static else ''})")
        more = f" and {len(self._frames) - _LISTED} more" if len(self._frames) > _LISTED else ""
        return "the frames " + ", ".join(described) + more

    def _sample(self, child: str, stamp_s: float, path: str) -> Union[tuple[str, Transform], str]:
        """``child``'s parent and transform at ``stamp_s`` (0.0: its newest), or the tf2 error message."""
        cache = self._caches[child]
        stamps = cache.stamps
        if cache.static or stamp_s == 0.0:
            return cache.parents[-1], cache.transforms[-1]
        index = bisect_right(stamps, stamp_s) - 1  # stamps[index] <= stamp_s
        if index >= 0 and stamps[index] == stamp_s:
            return cache.parents[index], cache.transforms[index]
        link = f"the link {cache.parents[-1]} -> {child} (data from {stamps[0]:.6f} to {stamps[-1]:.6f})"
        if index == len(stamps) - 1 or index < 0:
            nearest = -1 if index >= 0 else 0
            limit = self.max_extrapolation_s and self.max_extrapolation_s + 4.0 * math.ulp(stamp_s)  # float stamps
            if abs(stamp_s - stamps[nearest]) <= limit:
                return cache.parents[nearest], cache.transforms[nearest]
            if len(stamps) == 1:
                reason = f"at time {stamp_s:.6f}, but only time {stamps[0]:.6f} is in the buffer"
            elif index >= 0:
                reason = (f"into the future.  Requested time {stamp_s:.6f} but the latest data is at time "
                          f"{stamps[-1]:.6f}")
            else:
                reason = (f"into the past.  Requested time {stamp_s:.6f} but the earliest data is at time "
                          f"{stamps[0]:.6f}")
            held = f" (held at most {self.max_extrapolation_s:g} s)" if self.max_extrapolation_s else ""
            return f"Lookup would require extrapolation {reason}{held}, on {link}, {path}"
        if cache.parents[index] != cache.parents[index + 1]:
            return cache.parents[index], cache.transforms[index]
        ratio = (stamp_s - stamps[index]) / (stamps[index + 1] - stamps[index])
        return cache.parents[index], cache.transforms[index].interpolate(cache.transforms[index + 1], ratio)

    def _unconnected(self, target: str, source: str) -> ConnectivityError:
        return ConnectivityError(f"Could not find a connection between '{target}' and '{source}' because they are not "
                                 f"part of the same tree. Tf has two or more unconnected trees; the buffer holds "
                                 f"{self._listing()}")

    def _loop(self, chain: list, frame: str) -> LoopError:
        cycle = " -> ".join(chain[chain.index(frame):] + [frame])
        return LoopError(f"The tf tree is invalid because it contains a loop: {cycle} (each frame's parent "
                         f"followed); the buffer holds {self._listing()}")

    def _walk(self, target: str, source: str, stamp_s: float) -> Transform:
        self._check(target, source)
        path = f"when looking up transform from frame [{source}] to frame [{target}]"
        chain, links, failure = [source], [], None  # source's ancestors, the links between, why the walk stopped
        while chain[-1] != target and chain[-1] in self._caches:
            found = self._sample(chain[-1], stamp_s, path)
            if isinstance(found, str):
                failure = found
                break
            parent, transform = found
            if parent in chain:
                raise self._loop(chain, parent)
            chain.append(parent)
            links.append(transform)
        depth = {frame: k for k, frame in enumerate(chain)}
        frame, up, seen = target, _IDENTITY, [target]  # up: target's pose in the frame reached
        while frame not in depth:
            if frame not in self._caches:
                if failure is not None:  # unless the trees are not connected anyway (tf2 says extrapolation)
                    self._latest_common_time(target, source)
                    raise ExtrapolationError(failure)
                raise self._unconnected(target, source)
            found = self._sample(frame, stamp_s, path)
            if isinstance(found, str):
                raise ExtrapolationError(found)
            frame, transform = found
            if frame in seen:
                raise self._loop(seen, frame)
            seen.append(frame)
            up = transform.compose(up)
        down = _IDENTITY  # source's pose in the common ancestor
        for transform in links[:depth[frame]]:
            down = transform.compose(down)
        return up.inverse().compose(down)

    def _latest_common_time(self, target: str, source: str) -> float:
        self._check(target, source)
        if target == source:  # tf2: the frame's own newest stamp
            cache = self._caches.get(target)
            return 0.0 if cache is None or cache.static else cache.stamps[-1]
        chain, stamps = [source], []
        while chain[-1] != target and chain[-1] in self._caches:
            cache = self._caches[chain[-1]]
            if cache.parents[-1] in chain:
                raise self._loop(chain, cache.parents[-1])
            chain.append(cache.parents[-1])
            stamps.append(None if cache.static else cache.stamps[-1])
        depth = {frame: k for k, frame in enumerate(chain)}
        frame, newest, seen = target, [], [target]
        while frame not in depth:
            cache = self._caches.get(frame)
            if cache is None:
                raise self._unconnected(target, source)
            newest.append(None if cache.static else cache.stamps[-1])
            frame = cache.parents[-1]
            if frame in seen:
                raise self._loop(seen, frame)
            seen.append(frame)
        dynamic = [s for s in stamps[:depth[frame]] + newest if s is not None]
        return min(dynamic) if dynamic else 0.0
