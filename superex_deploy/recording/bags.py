"""A robot's recording as observations: ROS 1 bags, ROS 2 bags (SQLite or MCAP storage) and MCAP files, read with
the ``rosbags`` library (the ``bag`` extra), turned into the :class:`~superex_deploy.messages.Observation` stream
the explorer takes on a robot.

What is read (each ROS message converted by :mod:`superex_deploy.messages.ros_fields`):

* **scans**: ``sensor_msgs/LaserScan`` on ``scan_topic`` (default: the bag's only LaserScan topic);
* **the pose** of each scan's sensor at its stamp (:mod:`superex_deploy.recording.bag_poses`), from one source
  (``pose_source``):

  - ``tf``: the ``tf2_msgs/TFMessage`` tree of ``/tf`` and ``/tf_static`` in a
    :class:`~superex_deploy.ros.tf.TfBuffer`, from ``map_frame`` to the scan's ``header.frame_id``, interpolated
    between the transforms bracketing the stamp and held at most ``max_extrapolation_s`` beyond them;
  - a ``geometry_msgs/PoseWithCovarianceStamped`` or ``nav_msgs/Odometry`` topic: the robot base's pose and its
    covariance, interpolated between the two pose messages bracketing the stamp within ``max_pose_age_s``, then
    the ``base_frame`` -> scan-frame transform of ``/tf_static`` (or ``/tf``): a scan in another frame than
    ``base_frame`` (or an empty one) without that transform has no pose;
  - ``auto`` (default): a PoseWithCovarianceStamped topic if the bag has one, else ``tf`` if the tree holds
    ``map_frame`` (or the bag has no Odometry topic), else an Odometry topic;

  a laser mounted upside down (roll pi) is mirrored; any other non-planar mount refuses the bag, naming its frame;
  with ``deskew`` each ray takes its own pose (``stamp + i * time_increment``), see
  :func:`~superex_deploy.recording.bag_poses.deskew`;
* optionally **a SLAM map**: ``nav_msgs/OccupancyGrid`` on ``map_topic`` (default: the bag's only OccupancyGrid
  topic; ``""``: none), given to the explorer with the first scan after it (that step takes its map from it), or,
  after the bag's last scan, in one more step at the last scan's pose.

Stamps (``stamps``): ``"header"`` (default), the messages' header stamps; ``"arrival"``, the bag's receive times
(log times) of every message, for a driver without a clock. Observations count seconds since the first scan's.
Scans whose header stamps do not advance (all 0, or all equal) refuse the bag with ``"header"``.

A scan is skipped and counted by reason (:attr:`BagReading.skipped`) when it has no pose within the limits, is
stamped before the scan before it or stamped 0 among stamped ones, or is malformed
(:class:`~superex_deploy.messages.LaserScan`'s checks; a driver's glitch). A bad message is skipped, counted by
topic (:attr:`BagReading.messages_skipped`) and listed with its stamp and why (:attr:`BagReading.bad_messages`):
one that cannot be deserialised, a malformed scan or one stamped 0, a pose with a non-finite value, a quaternion
far from unit norm or a covariance that is none (a negative variance), a transform tf2 refuses, a SLAM map with
values outside -1..100 or a data length that is not ``width * height``. Refused before any scan is run, with one
``ValueError``: a SLAM map with a rotated origin, a tilted scan frame, scan stamps that do not advance, no scan
with a pose. A bag whose storage breaks (a corrupt chunk: rosbags raises its own errors mid-way) raises one
``ValueError`` naming the bag and how far it was read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from superex_deploy.messages import Observation, Pose2D
from superex_deploy.messages.ros_fields import laser_scan, occupancy_grid, stamp_seconds, yaw_of
from superex_deploy.recording.bag_poses import MountError, ScanPoses, deskew

__all__ = ["BagTopics", "BagReading", "read_bag", "LASER_SCAN", "POSE_WITH_COVARIANCE", "ODOMETRY", "OCCUPANCY_GRID",
           "TF", "STAMPS", "MAX_LISTED"]

LASER_SCAN = "sensor_msgs/msg/LaserScan"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
TF = "tf2_msgs/msg/TFMessage"
STAMPS = ("header", "arrival")
MAX_LISTED = 100
"""The most bad messages :attr:`BagReading.bad_messages` lists (all are counted)."""


@dataclass(frozen=True)
class BagTopics:
    """Which topics and frames a bag is read with, and how (the ``superex offline`` options).

    Attributes:
        scan_topic: the LaserScan topic, or None: the bag's only one.
        pose_source: ``"auto"``, ``"tf"``, or a PoseWithCovarianceStamped / Odometry topic.
        map_topic: the OccupancyGrid topic, None: the bag's only one (if any), ``""``: no SLAM map.
        map_frame: the fixed frame poses are expressed in (``tf``).
        base_frame: the robot's frame, which a pose topic's pose is of.
        max_pose_age_s: a pose topic's messages are used at most this far from a scan (seconds).
        max_extrapolation_s: a transform (or pose message) is held at most this far beyond its data (seconds; 0:
            tf2's rule, never).
        stamps: ``"header"`` or ``"arrival"`` (the bag's receive times; see the module docstring).
        deskew: give each ray its own pose (``time_increment``).
        usable_range_m: returns beyond this range count in the extent only up to it (the explorer's usable range:
            they clear free space up to it, no farther).
    """

    scan_topic: Optional[str] = None
    pose_source: str = "auto"
    map_topic: Optional[str] = None
    map_frame: str = "map"
    base_frame: str = "base_link"
    max_pose_age_s: float = 0.5
    max_extrapolation_s: float = 0.1
    stamps: str = "header"
    deskew: bool = False
    usable_range_m: float = math.inf

    def __post_init__(self) -> None:
        for name, low_open in (("max_pose_age_s", True), ("max_extrapolation_s", False)):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)
                                               and (value > 0 if low_open else value >= 0)):
                raise ValueError(f"{name} must be a {'positive' if low_open else 'non-negative'} number of seconds, "
                                 f"got {value!r}")
        if self.stamps not in STAMPS:
            raise ValueError(f"stamps must be one of {', '.join(STAMPS)}, got {self.stamps!r}")
        if not (isinstance(self.usable_range_m, (int, float)) and self.usable_range_m > 0):
            raise ValueError(f"usable_range_m must be a positive number of metres, got {self.usable_range_m!r}")


@dataclass
class BagReading:
    """What :func:`read_bag` found: the topics it used, what it skipped and why (filled while iterating).

    Attributes:
        scan_topic, pose_source, map_topic: what was used (``map_topic`` None: no SLAM map).
        scans: scans turned into observations.
        skipped: scans left out, by reason (``no_pose``: no pose within the limits; ``backwards``: stamped before
            the scan before it; ``invalid``: a malformed LaserScan, or one that cannot be deserialised;
            ``no_stamp``: stamped 0 among stamped scans).
        messages_skipped: bad messages of every topic (scans included), by topic.
        bad_messages: the first :data:`MAX_LISTED` of them: ``{"topic", "stamp_s", "reason"}`` (``stamp_s``: the
            header stamp, or the receive time of a message that cannot be read).
        expected_scans: the scans the first reading found usable: what the run will step on (a progress total).
        first_stamp_s: the first scan's stamp (seconds since the epoch the bag uses).
        first_xy: the first usable scan's sensor position (map frame, metres).
        extent_xy: ``(x_min, y_min, x_max, y_max)`` (metres, map frame) of every sensor position and return (and
            SLAM map) of the bag: the area an explorer's frame must hold.
        map_resolution_m, map_origin_xy: the first SLAM map's resolution (metres per cell) and origin (metres),
            or None: an explorer's frame on that lattice takes the maps without resampling.
        mirrored: scans turned into observations from an upside-down scanner (mirrored).
        deskewed: scans de-skewed (``deskew`` and a non-zero ``time_increment``).
        late_maps: SLAM maps applied after the last scan (0 or 1); ``late_maps_expected``: what the first reading
            expects (the run's last step then takes the map, so it has ``expected_scans + late_maps_expected``).
    """

    scan_topic: str
    pose_source: str
    map_topic: Optional[str]
    scans: int = 0
    skipped: dict = field(default_factory=lambda: {"no_pose": 0, "backwards": 0, "invalid": 0, "no_stamp": 0})
    messages_skipped: dict = field(default_factory=dict)
    bad_messages: list = field(default_factory=list)
    expected_scans: int = 0
    first_stamp_s: Optional[float] = None
    first_xy: Optional[tuple[float, float]] = None
    extent_xy: Optional[tuple[float, float, float, float]] = None
    map_resolution_m: Optional[float] = None
    map_origin_xy: Optional[tuple[float, float]] = None
    mirrored: int = 0
    deskewed: int = 0
    late_maps: int = 0
    late_maps_expected: int = 0

    def note(self, topic: str, stamp_s: float, reason: str) -> None:
        """Count a bad message of ``topic`` and list it (the first :data:`MAX_LISTED`)."""
        self.messages_skipped[topic] = self.messages_skipped.get(topic, 0) + 1
        if len(self.bad_messages) < MAX_LISTED:
            self.bad_messages.append({"topic": topic, "stamp_s": round(float(stamp_s), 9), "reason": reason})


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


def _seconds_of_ns(nanoseconds: int) -> float:
    """Seconds of a receive time, as a header stamp of the same time gives them (equal times, equal floats)."""
    sec, nanosec = divmod(int(nanoseconds), 10**9)
    return float(sec) + 1e-9 * float(nanosec)


def _messages(reader, path: Path, connections, what: str):
    """``(connection, receive time ns, message or None, why not)`` of ``connections`` in receive-time order: a
    message that cannot be deserialised comes as None with the reason; storage that breaks mid-way (a corrupt chunk:
    rosbags raises its own errors) raises one ValueError naming the bag and how far it was read."""
    count, last = 0, None
    iterator = iter(reader.messages(connections=connections))
    while True:
        try:
            connection, log_ns, raw = next(iterator)
        except StopIteration:
            return
        except Exception as error:
            start, duration = reader.start_time, reader.duration
            into = 0.0 if last is None else (last - start) * 1e-9
            raise ValueError(f"{path} is corrupt: reading {what} stopped after {count} messages, {into:.3f} s into "
                             f"the bag's {duration * 1e-9:.3f} s ({type(error).__name__}: {error})") from None
        count, last = count + 1, log_ns
        try:
            message = reader.deserialize(raw, connection.msgtype)
        except Exception as error:
            yield connection, log_ns, None, f"cannot be deserialised ({error})"
            continue
        yield connection, log_ns, message, None


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


def read_bag(path, topics: BagTopics = BagTopics()) -> tuple[BagReading, Iterator[Observation]]:
    """Open a bag and return what it will be read with and the observations, one per usable scan, in receive order.

    The bag is read three times: the poses and transforms, then the scans and maps for the checks and the extent
    (``reading.extent_xy``, ``reading.expected_scans``: known when this returns), then scan by scan as the iterator
    is consumed.

    Raises:
        ValueError: a file that is not a bag, a bag without scans or without a pose source, a topic that is not in
            the bag or not of the needed type, several candidate topics and none chosen, no scan with a pose, scan
            stamps that do not advance, a tilted scan frame, a SLAM map with a rotated origin, corrupt storage.
        ModuleNotFoundError: the ``rosbags`` library is not installed (the ``bag`` extra).
    """
    path = Path(path)
    reader = _open(path)
    try:
        reading = _choose(reader, topics)
        poses = _read_poses(reader, path, reading, topics)
        odometry = _topics_of(reader, ODOMETRY)
        if topics.pose_source == "auto" and reading.pose_source == "tf" and odometry and not poses.holds(
                topics.map_frame):
            # A robot without localisation still has /tf (odom -> base_link, the mounts): it does not reach the
            # map frame, and the odometry topic is the pose.
            reading = BagReading(scan_topic=reading.scan_topic, pose_source=odometry[0], map_topic=reading.map_topic)
            poses = _read_poses(reader, path, reading, topics)
        _measure(reader, path, reading, topics, poses)
    except BaseException:
        reader.close()
        raise
    return reading, _observations(reader, path, reading, topics, poses)


def _read_poses(reader, path: Path, reading: BagReading, topics: BagTopics) -> ScanPoses:
    poses = ScanPoses(reading.pose_source, topics.map_frame, topics.base_frame, topics.max_pose_age_s,
                      topics.max_extrapolation_s)
    arrival = topics.stamps == "arrival"
    wanted = [c for c in reader.connections if c.msgtype == TF or c.topic == reading.pose_source]
    for connection, log_ns, message, error in _messages(reader, path, wanted, "the poses"):
        topic = connection.topic
        if message is None:
            reading.note(topic, _seconds_of_ns(log_ns), error)
        elif connection.msgtype == TF:
            why = poses.add_tf(message, topic.rstrip("/").endswith("tf_static"), log_ns if arrival else None)
            if why is not None:
                first = message.transforms[0].header.stamp if message.transforms else None
                reading.note(topic, _seconds_of_ns(log_ns) if first is None else stamp_seconds(first), why)
        else:
            stamp = _seconds_of_ns(log_ns) if arrival else stamp_seconds(message.header.stamp)
            why = poses.add_pose(message, stamp)
            if why is not None:
                reading.note(topic, stamp, why)
    poses.poses.finish()
    return poses


def _judge(reading: BagReading, topics: BagTopics, poses: ScanPoses, message, stamp: float, last):
    """``(reason, detail, scan, pose)`` of one scan message: a reason of :attr:`BagReading.skipped` (and why) for
    a scan left out, else None and its scan and sensor pose.

    Raises:
        ValueError: a tilted scan frame.
    """
    if topics.stamps == "header" and stamp == 0.0:
        return "no_stamp", "stamped 0", None, None
    if last is not None and stamp < last:
        return "backwards", None, None, None
    try:
        pose = poses.at(message.header.frame_id, stamp)
    except MountError as error:
        raise ValueError(f"the scans on {reading.scan_topic}: {error}") from None
    if pose is None:
        return "no_pose", None, None, None
    try:
        scan = laser_scan(message)
    except ValueError as error:
        return "invalid", str(error), None, None
    return None, None, scan, pose


def _rotated(message) -> bool:
    try:
        return abs(yaw_of(message.info.origin.orientation)) > 1e-6
    except (AttributeError, TypeError, ValueError):
        return False


def _measure(reader, path: Path, reading: BagReading, topics: BagTopics, poses: ScanPoses) -> None:
    """The first reading of the scans and maps: the refusals, the extent, the usable scans."""
    low, high = np.full(2, np.inf), np.full(2, -np.inf)
    scan_stamps, count, last = set(), 0, None
    arrival = topics.stamps == "arrival"
    wanted = [c for c in reader.connections if c.topic in (reading.scan_topic, reading.map_topic)]
    for connection, log_ns, message, _ in _messages(reader, path, wanted, "the scans"):
        if message is None:
            continue  # counted when the run reaches it
        stamp = _seconds_of_ns(log_ns) if arrival else stamp_seconds(message.header.stamp)
        if connection.msgtype == OCCUPANCY_GRID:
            try:
                grid = occupancy_grid(message)
            except ValueError as error:
                if _rotated(message):  # refused now, not when the run reaches it
                    raise ValueError(f"the SLAM map on {reading.map_topic} stamped {stamp:.9f} s: {error}") from None
                continue  # a garbled map: skipped and listed by the run
            x0, y0 = grid.origin_xy
            if reading.map_resolution_m is None:
                reading.map_resolution_m, reading.map_origin_xy = grid.resolution_m, (x0, y0)
            low = np.minimum(low, (x0, y0))
            high = np.maximum(high, (x0 + grid.width * grid.resolution_m, y0 + grid.height * grid.resolution_m))
            reading.late_maps_expected = int(reading.first_xy is not None)  # until a usable scan follows it
            continue
        count += 1
        if len(scan_stamps) < 2:
            scan_stamps.add(stamp)
        reason, _, scan, pose = _judge(reading, topics, poses, message, stamp, last)
        if reason is not None:
            continue
        last = stamp
        reading.expected_scans += 1
        reading.late_maps_expected = 0
        if reading.first_xy is None:
            reading.first_xy = (pose.x, pose.y)
        scan = scan.mirrored() if pose.mirrored else scan
        ranges = scan.ranges.astype(np.float64)
        hit = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges < scan.range_max)
        reach = np.minimum(ranges[hit], topics.usable_range_m)
        angles = pose.yaw + scan.angles()[hit]
        xs, ys = np.append(pose.x + reach * np.cos(angles), pose.x), np.append(pose.y + reach * np.sin(angles), pose.y)
        low, high = np.minimum(low, (xs.min(), ys.min())), np.maximum(high, (xs.max(), ys.max()))
    if not arrival and len(scan_stamps) == 1 and (count > 1 or 0.0 in scan_stamps):
        raise ValueError(f"the header stamps of the {count} scans on {reading.scan_topic} do not advance (all "
                         f"{next(iter(scan_stamps)):.9f} s: a driver without a clock); --stamps arrival uses the "
                         f"bag's receive times instead")
    if reading.first_xy is None:
        if reading.pose_source == "tf":
            hint = (f"(map frame {topics.map_frame!r}; a transform is held at most {topics.max_extrapolation_s:g} s "
                    f"beyond its data: --max-extrapolation)")
        else:
            hint = (f"within {topics.max_pose_age_s:g} s (the pose is the robot's, --base-frame "
                    f"{topics.base_frame!r}, and a scan in another frame needs the transform from it in /tf_static or "
                    f"/tf; --base-frame <the scans' frame> if the pose is the scanner's)")
        raise ValueError(f"no scan on {reading.scan_topic} has a pose from {reading.pose_source} {hint}")
    reading.extent_xy = (float(low[0]), float(low[1]), float(high[0]), float(high[1]))


def _deskewed(message, scan, pose, stamp: float, poses: ScanPoses):
    """The scan with each ray at its own pose, or None where the message gives no usable ``time_increment``."""
    step = float(message.time_increment)
    n = scan.n_rays
    if not (math.isfinite(step) and step != 0.0 and abs(step) * n < 1.0) or n < 2:
        return None
    times = stamp + np.arange(n) * step
    angles = float(message.angle_min) + np.arange(n) * float(message.angle_increment)
    return deskew(scan, angles, np.asarray(message.ranges, np.float64),
                  poses.along(message.header.frame_id, times, pose), pose)


def _observations(reader, path: Path, reading: BagReading, topics: BagTopics, poses: ScanPoses
                  ) -> Iterator[Observation]:
    wanted = [c for c in reader.connections if c.topic in (reading.scan_topic, reading.map_topic)]
    arrival = topics.stamps == "arrival"
    pending_map, pending_stamp, last, previous = None, None, None, None
    try:
        for connection, log_ns, message, error in _messages(reader, path, wanted, "the scans"):
            topic = connection.topic
            if message is None:
                reading.note(topic, _seconds_of_ns(log_ns), error)
                if topic == reading.scan_topic:
                    reading.skipped["invalid"] += 1
                continue
            stamp = _seconds_of_ns(log_ns) if arrival else stamp_seconds(message.header.stamp)
            if connection.msgtype == OCCUPANCY_GRID:
                try:
                    pending_map, pending_stamp = occupancy_grid(message), stamp
                except ValueError as why:
                    reading.note(topic, stamp, f"the map is refused: {why}")
                continue
            reason, detail, scan, pose = _judge(reading, topics, poses, message, stamp, last)
            if reason is not None:
                reading.skipped[reason] += 1
                if detail is not None:
                    reading.note(topic, stamp, f"the scan is refused: {detail}")
                continue
            if reading.first_stamp_s is None:
                reading.first_stamp_s = stamp
            last = stamp
            if pose.mirrored:
                scan = scan.mirrored()
                reading.mirrored += 1
            if topics.deskew:
                deskewed = _deskewed(message, scan, pose, stamp, poses)
                if deskewed is not None:
                    scan = deskewed
                    reading.deskewed += 1
            reading.scans += 1
            previous = Observation(stamp_s=stamp - reading.first_stamp_s, pose=Pose2D(pose.x, pose.y, pose.yaw),
                                   scan=None if pending_map is not None else scan, pose_covariance=pose.covariance,
                                   occupancy_grid=pending_map)
            pending_map = None
            yield previous
        if pending_map is not None and previous is not None:
            # A SLAM map published after the last scan: one more step at the last pose takes it.
            reading.late_maps += 1
            yield Observation(stamp_s=max(previous.stamp_s, pending_stamp - reading.first_stamp_s),
                              pose=previous.pose, scan=None, pose_covariance=previous.pose_covariance,
                              occupancy_grid=pending_map)
    finally:
        reader.close()
