"""A robot's recording as observations: ROS 1 bags, ROS 2 bags (SQLite or MCAP storage) and MCAP files, read with
the ``rosbags`` library (the ``bag`` extra), turned into the :class:`~superex_deploy.messages.Observation` stream
the explorer takes on a robot.

What is read:

* **scans**: ``sensor_msgs/LaserScan`` on ``scan_topic`` (default: the bag's only LaserScan topic);
* **the pose** of each scan's sensor, from one source (``pose_source``):

  - ``tf``: the ``tf2_msgs/TFMessage`` tree of ``/tf`` and ``/tf_static``, from ``map_frame`` to the scan's
    ``header.frame_id`` (each transform the newest at or before the scan's stamp, planar: x, y and yaw);
  - a ``geometry_msgs/PoseWithCovarianceStamped`` or ``nav_msgs/Odometry`` topic: the robot base's pose and its
    covariance, then the ``base_frame`` -> scan-frame transform of ``/tf_static`` (or ``/tf``): a scan in another
    frame than ``base_frame`` (or an empty one) without that transform has no pose;
  - ``auto`` (default): a PoseWithCovarianceStamped topic if the bag has one, else ``tf`` if the tree holds
    ``map_frame`` (or the bag has no Odometry topic), else an Odometry topic;

* optionally **a SLAM map**: ``nav_msgs/OccupancyGrid`` on ``map_topic`` (default: the bag's only OccupancyGrid
  topic; ``""``: none), given to the explorer with the first scan after it.

Stamps are the messages' header stamps, as seconds since the first scan's (the explorer's clock starts at 0). A scan
without a pose within ``max_pose_age_s`` before it, stamped before the scan it follows, or malformed (no ranges,
``range_min >= range_max``, angles that do not match its ranges: :class:`~superex_deploy.messages.LaserScan`'s
checks; a driver's glitch) is skipped and counted. A SLAM map the explorer cannot take (a rotated origin, values
outside -1..100) is refused when the bag is opened, before any scan is read.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from superex_deploy.messages import LaserScan, Observation, OccupancyGridMessage, Pose2D, PoseCovariance

__all__ = ["BagTopics", "BagReading", "read_bag", "LASER_SCAN", "POSE_WITH_COVARIANCE", "ODOMETRY", "OCCUPANCY_GRID",
           "TF"]

LASER_SCAN = "sensor_msgs/msg/LaserScan"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
TF = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class BagTopics:
    """Which topics and frames a bag is read with (the ``superex offline`` options).

    Attributes:
        scan_topic: the LaserScan topic, or None: the bag's only one.
        pose_source: ``"auto"``, ``"tf"``, or a PoseWithCovarianceStamped / Odometry topic.
        map_topic: the OccupancyGrid topic, None: the bag's only one (if any), ``""``: no SLAM map.
        map_frame: the fixed frame poses are expressed in (``tf``).
        base_frame: the robot's frame, which a pose topic's pose is of.
        max_pose_age_s: a scan takes the newest pose at most this old (seconds).
    """

    scan_topic: Optional[str] = None
    pose_source: str = "auto"
    map_topic: Optional[str] = None
    map_frame: str = "map"
    base_frame: str = "base_link"
    max_pose_age_s: float = 0.5

    def __post_init__(self) -> None:
        if not (isinstance(self.max_pose_age_s, (int, float)) and math.isfinite(self.max_pose_age_s)
                and self.max_pose_age_s > 0):
            raise ValueError(f"max_pose_age_s must be a positive number of seconds, got {self.max_pose_age_s!r}")


@dataclass
class BagReading:
    """What :func:`read_bag` found: the topics it used and why it skipped scans (filled while iterating).

    Attributes:
        scan_topic, pose_source, map_topic: what was used (``map_topic`` None: no SLAM map).
        scans: scans turned into observations.
        skipped: scans left out, by reason (``no_pose``: no pose within ``max_pose_age_s``; ``backwards``:
            stamped before the scan before it; ``invalid``: a malformed LaserScan).
        first_stamp_s: the first scan's header stamp (seconds since the epoch the bag uses).
        extent_xy: ``(x_min, y_min, x_max, y_max)`` (metres, map frame) of every sensor position and return (and
            SLAM map) of the bag: the area an explorer's frame must hold.
        map_resolution_m, map_origin_xy: the first SLAM map's resolution (metres per cell) and origin (metres),
            or None: an explorer's frame on that lattice takes the maps without resampling.
    """

    scan_topic: str
    pose_source: str
    map_topic: Optional[str]
    scans: int = 0
    skipped: dict = field(default_factory=lambda: {"no_pose": 0, "backwards": 0, "invalid": 0})
    first_stamp_s: Optional[float] = None
    extent_xy: Optional[tuple[float, float, float, float]] = None
    map_resolution_m: Optional[float] = None
    map_origin_xy: Optional[tuple[float, float]] = None


def _stamp(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """The planar pose ``b`` (in ``a``'s frame) in the frame ``a`` is expressed in."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


class _Series:
    """Planar poses (and covariances) in stamp order; :meth:`at` gives the newest at or before a stamp."""

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.values: list = []

    def add(self, stamp: float, value) -> None:
        if self.stamps and stamp < self.stamps[-1]:  # out of order in the bag: keep them sorted
            index = bisect_right(self.stamps, stamp)
            self.stamps.insert(index, stamp)
            self.values.insert(index, value)
        else:
            self.stamps.append(stamp)
            self.values.append(value)

    def at(self, stamp: float, max_age_s: Optional[float]):
        index = bisect_right(self.stamps, stamp) - 1
        if index < 0 or (max_age_s is not None and stamp - self.stamps[index] > max_age_s):
            return None
        return self.values[index]


class _TfTree:
    """The planar transforms of ``/tf`` (time series) and ``/tf_static``, by child frame."""

    def __init__(self) -> None:
        self.parent: dict[str, str] = {}
        self.dynamic: dict[str, _Series] = {}
        self.static: dict[str, tuple[float, float, float]] = {}

    def add(self, message, static: bool) -> None:
        for transform in message.transforms:
            child, parent = transform.child_frame_id.lstrip("/"), transform.header.frame_id.lstrip("/")
            t = transform.transform
            value = (float(t.translation.x), float(t.translation.y), _yaw(t.rotation))
            self.parent[child] = parent
            if static:
                self.static[child] = value
            else:
                self.dynamic.setdefault(child, _Series()).add(_stamp(transform.header), value)

    def holds(self, frame: str) -> bool:
        """Whether ``frame`` is in the tree (the parent or the child of a transform)."""
        return frame in self.parent or frame in self.parent.values()

    def reaches(self, frame: str, root: str) -> bool:
        seen = set()
        while frame != root:
            if frame in seen or frame not in self.parent:
                return False
            seen.add(frame)
            frame = self.parent[frame]
        return True

    def lookup(self, root: str, frame: str, stamp: float, max_age_s: float):
        """``frame``'s planar pose in ``root`` at ``stamp``, or None (a missing link, a transform too old, or a
        loop: a tree whose frames are each other's parents, as two publishers of one link inverted make it)."""
        pose = (0.0, 0.0, 0.0)
        seen = set()
        while frame != root:
            if frame in seen:
                return None
            seen.add(frame)
            if frame in self.static:
                link = self.static[frame]
            elif frame in self.dynamic:
                link = self.dynamic[frame].at(stamp, max_age_s)
                if link is None:
                    return None
            else:
                return None
            pose = _compose(link, pose)
            frame = self.parent[frame]
        return pose


def _open(path: Path):
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ModuleNotFoundError as error:
        raise ModuleNotFoundError("reading bags needs the rosbags library: pip install 'superex[bag]'",
                                  name="rosbags") from error
    if not path.exists():
        raise ValueError(f"no such bag: {path}")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as error:  # rosbags raises its own errors for unreadable or unknown formats
        raise ValueError(f"cannot read {path} as a ROS 1 bag, a ROS 2 bag or an MCAP file: {error}") from None
    return reader


def _topics_of(reader, msgtype: str) -> list[str]:
    """The topics of ``msgtype`` that hold messages (a topic declared but never written is left out)."""
    return sorted({c.topic for c in reader.connections if c.msgtype == msgtype and c.msgcount})


def _choose(reader, topics: BagTopics) -> BagReading:
    found = {c.topic: c.msgtype for c in reader.connections if c.msgcount}
    listing = ", ".join(f"{topic} ({kind})" for topic, kind in sorted(found.items())) or "no topics"
    scans = _topics_of(reader, LASER_SCAN)
    if topics.scan_topic is not None:
        if found.get(topics.scan_topic) != LASER_SCAN:
            raise ValueError(f"the bag has no {LASER_SCAN} topic {topics.scan_topic!r}; it has {listing}")
        scan_topic = topics.scan_topic
    elif len(scans) == 1:
        scan_topic = scans[0]
    elif not scans:
        raise ValueError(f"the bag has no {LASER_SCAN} topic (the scans are needed); it has {listing}")
    else:
        raise ValueError(f"the bag has several {LASER_SCAN} topics ({', '.join(scans)}): choose one with --scan-topic")
    source = topics.pose_source
    if source not in ("auto", "tf"):
        if found.get(source) not in (POSE_WITH_COVARIANCE, ODOMETRY):
            raise ValueError(f"the pose source {source!r} is not a {POSE_WITH_COVARIANCE} or {ODOMETRY} topic of the "
                             f"bag; it has {listing}")
    elif source == "auto":
        with_covariance, odometry = _topics_of(reader, POSE_WITH_COVARIANCE), _topics_of(reader, ODOMETRY)
        if with_covariance:
            source = with_covariance[0]
        elif _topics_of(reader, TF):
            source = "tf"
        elif odometry:
            source = odometry[0]
        else:
            raise ValueError(f"the bag has no pose: no {POSE_WITH_COVARIANCE} or {ODOMETRY} topic and no /tf; it has "
                             f"{listing}")
    elif not _topics_of(reader, TF):
        raise ValueError(f"--pose-source tf: the bag has no {TF} topic; it has {listing}")
    maps = _topics_of(reader, OCCUPANCY_GRID)
    if topics.map_topic == "":
        map_topic = None
    elif topics.map_topic is not None:
        if found.get(topics.map_topic) != OCCUPANCY_GRID:
            raise ValueError(f"the bag has no {OCCUPANCY_GRID} topic {topics.map_topic!r}; it has {listing}")
        map_topic = topics.map_topic
    elif len(maps) > 1:
        raise ValueError(f"the bag has several {OCCUPANCY_GRID} topics ({', '.join(maps)}): choose one with "
                         f"--map-topic, or none with --map-topic ''")
    else:
        map_topic = maps[0] if maps else None
    return BagReading(scan_topic=scan_topic, pose_source=source, map_topic=map_topic)


def _grid_message(message) -> OccupancyGridMessage:
    info = message.info
    if abs(_yaw(info.origin.orientation)) > 1e-6:
        raise ValueError("a SLAM map with a rotated origin is not supported (nav_msgs/OccupancyGrid info.origin has "
                         f"a yaw of {_yaw(info.origin.orientation):.3g} rad)")
    return OccupancyGridMessage(resolution_m=float(info.resolution), width=int(info.width), height=int(info.height),
                                origin_xy=(float(info.origin.position.x), float(info.origin.position.y)),
                                data=np.asarray(message.data, np.int8))


def _scan_message(message) -> Optional[LaserScan]:
    """The scan, or None when :class:`LaserScan` refuses it (malformed)."""
    try:
        return _laser_scan(message)
    except ValueError:
        return None


def _laser_scan(message) -> LaserScan:
    return LaserScan(angle_min=float(message.angle_min), angle_increment=float(message.angle_increment),
                     range_min=float(message.range_min), range_max=float(message.range_max),
                     ranges=np.asarray(message.ranges, np.float32))


def read_bag(path, topics: BagTopics = BagTopics()) -> tuple[BagReading, Iterator[Observation]]:
    """Open a bag and return what it will be read with and the observations, one per usable scan, in stamp order.

    The bag is read twice: once for the poses, the transforms and the extent (``reading.extent_xy``, known when
    this returns), then scan by scan as the iterator is consumed.

    Raises:
        ValueError: a file that is not a bag, a bag without scans or without a pose source, a topic that is not in
            the bag or not of the needed type, several candidate topics and none chosen, no scan with a pose.
        ModuleNotFoundError: the ``rosbags`` library is not installed (the ``bag`` extra).
    """
    path = Path(path)
    reader = _open(path)
    try:
        reading = _choose(reader, topics)
        poses, tree = _read_poses(reader, reading, topics)
        odometry = _topics_of(reader, ODOMETRY)
        if topics.pose_source == "auto" and reading.pose_source == "tf" and odometry and not tree.holds(
                topics.map_frame):
            # A robot without localisation still has /tf (odom -> base_link, the mounts): it does not reach the
            # map frame, and the odometry topic is the pose.
            reading.pose_source = odometry[0]
            poses, tree = _read_poses(reader, reading, topics)
        _measure_extent(reader, reading, topics, poses, tree)
    except BaseException:
        reader.close()
        raise
    return reading, _observations(reader, reading, topics, poses, tree)


def _read_poses(reader, reading: BagReading, topics: BagTopics):
    tree = _TfTree()
    poses = _Series()
    wanted = [c for c in reader.connections if c.msgtype == TF or c.topic == reading.pose_source]
    for connection, _, raw in reader.messages(connections=wanted):
        message = reader.deserialize(raw, connection.msgtype)
        if connection.msgtype == TF:
            tree.add(message, static=connection.topic.rstrip("/").endswith("tf_static"))
        else:
            pose = message.pose  # PoseWithCovariance in both message types
            covariance = np.asarray(pose.covariance, np.float64)
            value = ((float(pose.pose.position.x), float(pose.pose.position.y), _yaw(pose.pose.orientation)),
                     covariance if np.any(covariance) else None)
            poses.add(_stamp(message.header), value)
    return poses, tree


def _sensor_pose(reading, topics, poses, tree, frame_id: str, stamp: float):
    """The scan sensor's planar pose in the map frame and its covariance (or None) at ``stamp``, or None."""
    frame_id = frame_id.lstrip("/")
    if reading.pose_source == "tf":
        pose = tree.lookup(topics.map_frame, frame_id, stamp, topics.max_pose_age_s)
        return None if pose is None else (pose, None)
    found = poses.at(stamp, topics.max_pose_age_s)
    if found is None:
        return None
    base, covariance = found
    if not frame_id or frame_id == topics.base_frame:  # the scan is the base's (an empty frame_id: taken as such)
        return base, covariance
    # A scanner elsewhere on the robot: without the mount its scans would be drawn from the wrong place, off by the
    # mount's offset and turned by its yaw, so a scan without it has no pose.
    mount = tree.lookup(topics.base_frame, frame_id, stamp, None)
    return None if mount is None else (_compose(base, mount), covariance)


def _measure_extent(reader, reading, topics, poses, tree) -> None:
    xs, ys = [], []
    wanted = [c for c in reader.connections if c.topic in (reading.scan_topic, reading.map_topic)]
    for connection, _, raw in reader.messages(connections=wanted):
        message = reader.deserialize(raw, connection.msgtype)
        if connection.msgtype == OCCUPANCY_GRID:
            try:  # refused now, not when the run reaches it
                grid = _grid_message(message)
            except ValueError as error:
                raise ValueError(f"the SLAM map on {reading.map_topic} stamped {_stamp(message.header):.9f} s: "
                                 f"{error}") from None
            x0, y0 = grid.origin_xy
            if reading.map_resolution_m is None:
                reading.map_resolution_m, reading.map_origin_xy = grid.resolution_m, (x0, y0)
            xs += [x0, x0 + grid.width * grid.resolution_m]
            ys += [y0, y0 + grid.height * grid.resolution_m]
            continue
        found = _sensor_pose(reading, topics, poses, tree, message.header.frame_id, _stamp(message.header))
        scan = None if found is None else _scan_message(message)
        if scan is None:
            continue
        (x, y, yaw), _ = found
        ranges = scan.ranges.astype(np.float64)
        hit = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges < scan.range_max)
        angles = yaw + scan.angles()[hit]
        xs += [x, *(x + ranges[hit] * np.cos(angles)).tolist()]
        ys += [y, *(y + ranges[hit] * np.sin(angles)).tolist()]
    if not xs:
        hint = (f"map frame {topics.map_frame!r}" if reading.pose_source == "tf" else
                f"the pose is the robot's, --base-frame {topics.base_frame!r}, and a scan in another frame needs the "
                f"transform from it in /tf_static or /tf; --base-frame <the scans' frame> if the pose is the scanner's")
        raise ValueError(f"no scan on {reading.scan_topic} has a pose from {reading.pose_source} within "
                         f"{topics.max_pose_age_s} s ({hint})")
    reading.extent_xy = (min(xs), min(ys), max(xs), max(ys))


def _observations(reader, reading, topics, poses, tree) -> Iterator[Observation]:
    wanted = [c for c in reader.connections if c.topic in (reading.scan_topic, reading.map_topic)]
    pending_map: Optional[OccupancyGridMessage] = None
    last = None
    try:
        for connection, _, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            if connection.msgtype == OCCUPANCY_GRID:
                pending_map = _grid_message(message)
                continue
            stamp = _stamp(message.header)
            if last is not None and stamp < last:
                reading.skipped["backwards"] += 1
                continue
            found = _sensor_pose(reading, topics, poses, tree, message.header.frame_id, stamp)
            if found is None:
                reading.skipped["no_pose"] += 1
                continue
            scan = _scan_message(message)
            if scan is None:
                reading.skipped["invalid"] += 1
                continue
            if reading.first_stamp_s is None:
                reading.first_stamp_s = stamp
            last = stamp
            (x, y, yaw), covariance = found
            try:
                covariance = None if covariance is None else PoseCovariance.from_ros(covariance)
            except ValueError as error:
                raise ValueError(f"the pose on {reading.pose_source} for the scan stamped {stamp:.9f} s: "
                                 f"{error}") from None
            reading.scans += 1
            yield Observation(stamp_s=stamp - reading.first_stamp_s, pose=Pose2D(x, y, yaw),
                              scan=None if pending_map is not None else scan,
                              pose_covariance=covariance, occupancy_grid=pending_map)
            pending_map = None
    finally:
        reader.close()
