"""Record an exploration episode to an MCAP file and read it back: every observation, every command, the map.

The file uses the ``ros2`` MCAP profile (CDR messages with ``ros2msg`` schemas), so Foxglove, the ``mcap`` CLI and
ROS 2 tools read it. Topics (one message of each per step unless noted; ``sequence`` = the explorer's step):

============  ==================================  =====================================================================
topic         type                                content
============  ==================================  =====================================================================
``/pose``     ``geometry_msgs/msg/PoseStamped``   the robot's pose (frame ``map``; yaw as a quaternion about ``z``)
``/scan``     ``sensor_msgs/msg/LaserScan``       the line-of-sight scan (frame ``base_scan``, aligned with the robot)
``/spad``     ``superex_msgs/msg/SpadFrame``      the SPAD frame, when the step has one (schema :data:`SPAD_FRAME_MSG`)
``/command``  ``superex_msgs/msg/ExplorerCommand``  the explorer's answer: goal cell and position, flags (schema below)
``/plan``     ``nav_msgs/msg/Path``               the commanded path (frame ``map``)
``/map``      ``nav_msgs/msg/OccupancyGrid``      the explorer's map (-1 unknown, 0 free, 100 occupied) every
                                                  ``map_every`` steps and at the last one
============  ==================================  =====================================================================

A robot's observation may carry two more inputs, recorded (and replayed) only when present: ``/slam_map``
(``nav_msgs/msg/OccupancyGrid``, the SLAM map the explorer read; ``/scan`` is absent on a step without a scan) and
``/pose_covariance`` (``geometry_msgs/msg/PoseWithCovarianceStamped``: x, y, yaw entries of the 6 x 6, the rest 0).

A metadata record ``superex.episode`` holds what a replay needs to rebuild the explorer (map frame, planner and its
options, predictor, seed, sensor model, NLOS and explorer configuration), each value a JSON string whose type is
fixed (:data:`METADATA_TYPES`; checked when writing and when reading). The SPAD
frame's arrays are little-endian byte blobs (``uint8[]``): the CDR encoders write numeric arrays element by element,
and a frame holds ~160,000 non-zero bins.

The file is written to ``PATH.part`` and renamed to ``PATH`` when the episode ends; an episode that fails leaves no
file behind. An episode stopped by a signal (SIGINT or SIGTERM raising ``KeyboardInterrupt``, as ``superex`` and
:func:`superex_deploy.parallel.stop_signals` make them) is closed as a valid file of every whole step recorded
before it: a step is written inside :func:`superex_deploy.parallel.signals_deferred`, so a signal never cuts one in
half. A process killed outright (SIGKILL, or SIGTERM with no handler) leaves ``PATH.part``, cut anywhere.
:func:`read_recording` reads the messages in order and stops at the first broken one (a truncated file), saying
which, and keeps every complete step before it.

Time stamps are those of :class:`~superex_deploy.messages.Observation` (finite, in ``[0, 2**31 - 1]`` s), so every
one fits the ``int32`` seconds of a ROS 2 time; yaws are already normalised to ``(-pi, pi]`` there.
"""

from __future__ import annotations

import io
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

from superex_deploy.messages import (Command, LaserScan, MapFrame, Observation, OccupancyGridMessage, Pose2D,
                                     PoseCovariance, SpadFrame, check_stamp)
from superex_deploy.parallel import signals_deferred

__all__ = ["FORMAT_VERSION", "SPAD_FRAME_MSG", "EXPLORER_COMMAND_MSG", "METADATA_TYPES", "EpisodeRecorder",
           "RecordedStep", "Recording", "read_recording", "check_metadata"]

FORMAT_VERSION = "1"
METADATA_NAME = "superex.episode"
METADATA_TYPES: dict = {"format_version": (str,), "frame": (dict,), "map": (str,), "planner": (str,),
                        "planner_options": (dict, type(None)), "predictor": (str,), "seed": (int,), "spad": (bool,),
                        "models": (str, type(None)), "sensor": (dict, type(None)), "nlos": (dict, type(None)),
                        "explorer": (dict,), "profile": (str, type(None)), "profile_settings": (dict,)}
"""The JSON type of each known ``superex.episode`` value (JSON objects are dicts; other keys are free)."""


def check_metadata(metadata: dict, where: str) -> dict:
    """Refuse metadata whose known values (:data:`METADATA_TYPES`) have another type.

    Args:
        metadata: the decoded values.
        where: what the message names (the recording's path).

    Returns:
        ``metadata``.

    Raises:
        ValueError: naming the first value of the wrong type.
    """
    for key, types in METADATA_TYPES.items():
        if key not in metadata:
            continue
        value = metadata[key]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            names = " or ".join("null" if t is type(None) else {dict: "object", str: "string", int: "integer",
                                                                  bool: "true/false"}[t] for t in types)
            raise ValueError(f"{where}: the {METADATA_NAME!r} metadata value {key!r} must be {names}, got "
                             f"{type(value).__name__} {value!r:.80}")
    return metadata

_SEPARATOR = "=" * 80 + "\n"
_HEADER = """MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
""" + _SEPARATOR + """MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_POSE = """MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
""" + _SEPARATOR + """MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
""" + _SEPARATOR + """MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
POSE_STAMPED_MSG = "std_msgs/Header header\ngeometry_msgs/Pose pose\n" + _SEPARATOR + _HEADER + _SEPARATOR + _POSE
LASER_SCAN_MSG = """std_msgs/Header header
float32 angle_min
float32 angle_max
float32 angle_increment
float32 time_increment
float32 scan_time
float32 range_min
float32 range_max
float32[] ranges
float32[] intensities
""" + _SEPARATOR + _HEADER
PATH_MSG = ("std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n" + _SEPARATOR + _HEADER + _SEPARATOR
            + "MSG: geometry_msgs/PoseStamped\nstd_msgs/Header header\ngeometry_msgs/Pose pose\n" + _SEPARATOR + _POSE)
OCCUPANCY_GRID_MSG = """std_msgs/Header header
nav_msgs/MapMetaData info
int8[] data
""" + _SEPARATOR + _HEADER + _SEPARATOR + """MSG: nav_msgs/MapMetaData
builtin_interfaces/Time map_load_time
float32 resolution
uint32 width
uint32 height
geometry_msgs/Pose origin
""" + _SEPARATOR + _POSE
POSE_WITH_COVARIANCE_STAMPED_MSG = ("std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n" + _SEPARATOR
                                    + _HEADER + _SEPARATOR + "MSG: geometry_msgs/PoseWithCovariance\n"
                                    "geometry_msgs/Pose pose\nfloat64[36] covariance\n" + _SEPARATOR + _POSE)
SPAD_FRAME_MSG = """# One SPAD LiDAR frame: a time-of-flight histogram per ray, stored by its non-zero bins (compressed sparse rows).
# Bin b of a ray counts photons whose round-trip path lies in [b, b + 1) * bin_width_s * c.
std_msgs/Header header
float64 bin_width_s      # seconds per bin
uint32 n_rays
uint32 n_bins
uint32 nnz               # non-zero bins over all rays
uint8[] angles_f64le     # n_rays float64, little-endian: ray angles (rad, counter-clockwise from the robot's heading)
uint8[] row_start_i64le  # n_rays + 1 int64, little-endian: ray i's entries are row_start[i]:row_start[i + 1]
uint8[] bins_i32le       # nnz int32, little-endian: bin indices, increasing within a ray
uint8[] counts_f32le     # nnz float32, little-endian: photon counts
""" + _SEPARATOR + _HEADER
EXPLORER_COMMAND_MSG = """# The SuperEx explorer's answer to one observation.
std_msgs/Header header
uint32 step              # the explorer's step counter
bool has_goal
int32 goal_row           # goal cell (row 0 at the top of the map image); -1 without a goal
int32 goal_col
float64 goal_x           # goal in the map frame (metres); NaN without a goal
float64 goal_y
bool new_goal            # the goal was chosen at this step
bool finished            # no reachable frontier is left
int32 prediction_step    # step of the newest prediction, -1 for none
float64 robot_yaw        # the observation's yaw (rad), exactly: the /pose quaternion rounds it
""" + _SEPARATOR + _HEADER

_SCHEMAS = {"/pose": ("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSG),
            "/scan": ("sensor_msgs/msg/LaserScan", LASER_SCAN_MSG),
            "/spad": ("superex_msgs/msg/SpadFrame", SPAD_FRAME_MSG),
            "/command": ("superex_msgs/msg/ExplorerCommand", EXPLORER_COMMAND_MSG),
            "/plan": ("nav_msgs/msg/Path", PATH_MSG),
            "/map": ("nav_msgs/msg/OccupancyGrid", OCCUPANCY_GRID_MSG),
            "/slam_map": ("nav_msgs/msg/OccupancyGrid", OCCUPANCY_GRID_MSG),
            "/pose_covariance": ("geometry_msgs/msg/PoseWithCovarianceStamped", POSE_WITH_COVARIANCE_STAMPED_MSG)}
_REPLAYED_TOPICS = ("/pose", "/scan", "/spad", "/slam_map", "/pose_covariance", "/command")
_COVARIANCE_INDEX = (0, 1, 5)  # x, y and yaw among the 6 x 6 covariance's x, y, z, roll, pitch, yaw


def _stamp(seconds: float) -> dict:
    nanoseconds = int(round(seconds * 1e9))
    return {"sec": nanoseconds // 1_000_000_000, "nanosec": nanoseconds % 1_000_000_000}


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _header(seconds: float, frame_id: str) -> dict:
    return {"stamp": _stamp(seconds), "frame_id": frame_id}


def _pose(x: float, y: float, yaw: float) -> dict:
    return {"position": {"x": x, "y": y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}}


@dataclass
class RecordedStep:
    """One step of a recording.

    Attributes:
        step: the explorer's step counter.
        observation: what the explorer received.
        goal_rc: the recorded command's goal cell, or None.
        new_goal, finished: the recorded command's flags.
    """

    step: int
    observation: Observation
    goal_rc: Optional[tuple[int, int]]
    new_goal: bool
    finished: bool


@dataclass
class Recording:
    """What :func:`read_recording` read.

    Attributes:
        metadata: the ``superex.episode`` record, JSON values decoded.
        frame: the explorer's map frame.
        steps: the complete steps, in order.
        error: None, or what stopped the reading (the broken message and why).
    """

    metadata: dict
    frame: MapFrame
    steps: list = field(default_factory=list)
    error: Optional[str] = None


class EpisodeRecorder:
    """Writes an episode to ``path`` (see the module docstring); use as a context manager.

    Args:
        path: the ``.mcap`` file to write (its folder must exist; an existing file is replaced at the end).
        frame: the explorer's map frame.
        metadata: what a replay needs (JSON-serialisable values; see :func:`superex_deploy.commands.replay`).
        map_every: write the explorer's map every this many steps (and at the last step).
        chunk_bytes: messages are compressed in chunks of about this size; a file cut short (a crash, a full
            disk) loses at most its last chunk.

    Leaving the ``with`` block normally, or by ``KeyboardInterrupt`` (a signal), closes the file (:meth:`close`);
    by any other exception drops it (:meth:`abort`).

    Attributes:
        steps_written: the steps recorded so far (whole: a signal never cuts a step in half).

    Raises:
        ValueError: a path whose folder does not exist or that names a folder, a bad ``map_every``.
    """

    def __init__(self, path: Union[str, Path], frame: MapFrame, metadata: dict, map_every: int = 25,
                 chunk_bytes: int = 256 * 1024):
        from mcap_ros2.writer import Writer

        self.path = Path(path)
        if self.path.is_dir():
            raise ValueError(f"--record {self.path} is a folder, not a file")
        if not self.path.parent.is_dir():
            raise ValueError(f"--record {self.path}: the folder {self.path.parent} does not exist")
        if int(map_every) < 1:
            raise ValueError(f"map_every must be >= 1, got {map_every}")
        self.frame, self.map_every = frame, int(map_every)
        values = check_metadata({"format_version": FORMAT_VERSION,
                                 "frame": {"shape": list(frame.shape), "resolution_m": frame.resolution_m,
                                           "origin_xy": list(frame.origin_xy)}, **metadata}, f"--record {path}")
        try:
            encoded = {key: json.dumps(value) for key, value in values.items()}
        except TypeError as error:
            raise ValueError(f"recording metadata must be JSON-serialisable: {error}") from None
        self._part = self.path.with_name(self.path.name + ".part")
        self._file = None
        self._closed = False
        self.steps_written = 0
        self._last_map_step = -1
        self._last = (0.0, 0)
        try:  # a signal may arrive anywhere in here: nothing is left behind then
            self._file = open(self._part, "wb")
            self._writer = Writer(self._file, chunk_size=int(chunk_bytes))
            self._schemas = {topic: self._writer.register_msgdef(name, text)
                             for topic, (name, text) in _SCHEMAS.items()}
            self._writer.add_metadata(METADATA_NAME, encoded)
        except BaseException:
            self.abort()
            raise

    def _write(self, topic: str, message: dict, stamp_s: float, step: int) -> None:
        nanoseconds = int(round(stamp_s * 1e9))
        self._writer.write_message(topic, self._schemas[topic], message, log_time=nanoseconds,
                                   publish_time=nanoseconds, sequence=step)

    def write(self, observation: Observation, command: Command, observed: Optional[np.ndarray] = None) -> None:
        """Record one step: the observation, the command and, every ``map_every`` steps, ``observed`` (int8
        ``[H, W]``, the explorer's map after the step). A signal arriving meanwhile is handled after the step is
        whole."""
        with signals_deferred():
            self._write_step(observation, command, observed)
            self.steps_written += 1

    def _write_step(self, observation: Observation, command: Command, observed: Optional[np.ndarray]) -> None:
        stamp, step = observation.stamp_s, command.step
        self._last = (stamp, step)
        pose = observation.pose
        self._write("/pose", {"header": _header(stamp, "map"), "pose": _pose(pose.x, pose.y, pose.yaw)}, stamp, step)
        scan = observation.scan
        if scan is not None:
            self._write("/scan", {"header": _header(stamp, "base_scan"), "angle_min": scan.angle_min,
                                  "angle_max": scan.angle_max, "angle_increment": scan.angle_increment,
                                  "time_increment": 0.0, "scan_time": 0.0, "range_min": scan.range_min,
                                  "range_max": scan.range_max, "ranges": scan.ranges.tolist(), "intensities": []},
                        stamp, step)
        self._write_robot_inputs(observation, stamp, step)
        spad = observation.spad
        if spad is not None:
            self._write("/spad", {"header": _header(stamp, "base_scan"), "bin_width_s": spad.bin_width_s,
                                  "n_rays": spad.n_rays, "n_bins": spad.n_bins, "nnz": int(spad.bins.size),
                                  "angles_f64le": spad.angles.astype("<f8").tobytes(),
                                  "row_start_i64le": spad.row_start.astype("<i8").tobytes(),
                                  "bins_i32le": spad.bins.astype("<i4").tobytes(),
                                  "counts_f32le": spad.counts.astype("<f4").tobytes()}, stamp, step)
        goal = command.goal_rc
        self._write("/command", {"header": _header(stamp, "map"), "step": step, "has_goal": goal is not None,
                                 "goal_row": -1 if goal is None else goal[0],
                                 "goal_col": -1 if goal is None else goal[1],
                                 "goal_x": math.nan if goal is None else command.goal_xy[0],
                                 "goal_y": math.nan if goal is None else command.goal_xy[1],
                                 "new_goal": bool(command.new_goal), "finished": bool(command.finished),
                                 "prediction_step": int(command.prediction_step), "robot_yaw": pose.yaw},
                    stamp, step)
        self._write("/plan", {"header": _header(stamp, "map"),
                              "poses": [{"header": _header(stamp, "map"), "pose": _pose(float(x), float(y), 0.0)}
                                        for x, y in command.path_xy]}, stamp, step)
        if observed is not None and (step % self.map_every == 0 or command.finished):
            self._write_map(observed, stamp, step)

    def _write_robot_inputs(self, observation: Observation, stamp: float, step: int) -> None:
        """The SLAM map and the pose covariance of an observation that carries them."""
        grid = observation.occupancy_grid
        if grid is not None:
            self._write("/slam_map", {"header": _header(stamp, "map"),
                                      "info": {"map_load_time": _stamp(0.0), "resolution": grid.resolution_m,
                                               "width": grid.width, "height": grid.height,
                                               "origin": _pose(grid.origin_xy[0], grid.origin_xy[1], 0.0)},
                                      "data": grid.data.tolist()}, stamp, step)
        covariance = observation.pose_covariance
        if covariance is not None:
            full = np.zeros((6, 6))
            full[np.ix_(_COVARIANCE_INDEX, _COVARIANCE_INDEX)] = covariance.matrix
            pose = observation.pose
            self._write("/pose_covariance", {"header": _header(stamp, "map"),
                                             "pose": {"pose": _pose(pose.x, pose.y, pose.yaw),
                                                      "covariance": full.ravel().tolist()}}, stamp, step)

    def write_map(self, observed: np.ndarray, stamp_s: Optional[float] = None, step: Optional[int] = None) -> None:
        """Record the explorer's int8 ``[H, W]`` map (rows flipped: ROS grids start at the bottom row), stamped
        with the last recorded step unless told otherwise (once per step at most)."""
        with signals_deferred():
            self._write_map(observed, stamp_s, step)

    def _write_map(self, observed: np.ndarray, stamp_s: Optional[float], step: Optional[int]) -> None:
        if stamp_s is None or step is None:
            stamp_s, step = self._last
        stamp_s = check_stamp("stamp_s", stamp_s)
        if step == self._last_map_step:
            return
        observed = np.asarray(observed)
        data = np.where(observed > 0, 100, observed).astype(np.int8)[::-1]
        height, width = self.frame.shape
        self._write("/map", {"header": _header(stamp_s, "map"),
                             "info": {"map_load_time": _stamp(0.0), "resolution": self.frame.resolution_m,
                                      "width": width, "height": height,
                                      "origin": _pose(self.frame.origin_xy[0], self.frame.origin_xy[1], 0.0)},
                             "data": data.ravel().tolist()}, stamp_s, step)
        self._last_map_step = step

    def close(self) -> None:
        """Finish the file with the steps written so far and move it into place (on failure, nothing is left at
        ``path`` or ``path.part``); a signal arriving meanwhile is handled after it."""
        if self._closed:
            return
        with signals_deferred():
            try:
                self._writer.finish()
                self._file.close()
                os.replace(self._part, self.path)
            except BaseException:
                self.abort()
                raise
            self._closed = True

    def abort(self) -> None:
        """Drop the partial file (nothing is left at ``path``)."""
        if self._closed:
            return
        with signals_deferred():
            if self._file is not None:
                self._file.close()
            self._part.unlink(missing_ok=True)
            self._closed = True

    def __enter__(self) -> "EpisodeRecorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            self.abort()


def _spad_frame(message) -> SpadFrame:
    return SpadFrame(angles=np.frombuffer(bytes(message.angles_f64le), "<f8"), bin_width_s=message.bin_width_s,
                     n_bins=int(message.n_bins), row_start=np.frombuffer(bytes(message.row_start_i64le), "<i8"),
                     bins=np.frombuffer(bytes(message.bins_i32le), "<i4"),
                     counts=np.frombuffer(bytes(message.counts_f32le), "<f4"))


def _slam_map(message, frame: MapFrame) -> OccupancyGridMessage:
    """The recorded SLAM map; its float32 resolution is read as the frame's when they agree at float32 (ROS stores
    ``info.resolution`` as float32, the explorer's frame as float64)."""
    info = message.info
    resolution = float(info.resolution)
    if np.float32(resolution) == np.float32(frame.resolution_m):
        resolution = frame.resolution_m
    return OccupancyGridMessage(resolution_m=resolution, width=int(info.width), height=int(info.height),
                                origin_xy=(info.origin.position.x, info.origin.position.y),
                                data=np.asarray(message.data, np.int8))


def _observation(parts: dict, frame: MapFrame) -> Observation:
    pose_message, scan_message = parts["/pose"], parts.get("/scan")
    yaw = float(parts["/command"].robot_yaw)
    pose = Pose2D(pose_message.pose.position.x, pose_message.pose.position.y, yaw)
    scan = None
    if scan_message is not None:
        scan = LaserScan(angle_min=scan_message.angle_min, angle_increment=scan_message.angle_increment,
                         range_min=scan_message.range_min, range_max=scan_message.range_max,
                         ranges=np.asarray(scan_message.ranges, np.float32), angle_max=scan_message.angle_max)
    spad = _spad_frame(parts["/spad"]) if "/spad" in parts else None
    grid = _slam_map(parts["/slam_map"], frame) if "/slam_map" in parts else None
    covariance = None
    if "/pose_covariance" in parts:
        full = np.asarray(parts["/pose_covariance"].pose.covariance, np.float64)
        covariance = PoseCovariance.from_ros(full)
    return Observation(stamp_s=_seconds(pose_message.header.stamp), pose=pose, scan=scan, spad=spad,
                       pose_covariance=covariance, occupancy_grid=grid)


def _metadata(data: bytes, path: Path) -> dict:
    from mcap.reader import NonSeekingReader

    reader = NonSeekingReader(io.BytesIO(data))
    try:
        for record in reader.iter_metadata():
            if record.name == METADATA_NAME:
                try:
                    metadata = {key: json.loads(value) for key, value in record.metadata.items()}
                except json.JSONDecodeError as error:
                    raise ValueError(f"{path}: the {METADATA_NAME!r} metadata is not JSON ({error})") from None
                return check_metadata(metadata, str(path))
    except ValueError:
        raise
    except Exception:  # the metadata comes first: a file broken before it holds nothing usable
        pass
    raise ValueError(f"{path} is not a SuperEx recording: no readable {METADATA_NAME!r} metadata record")


def _message_count(data: bytes) -> Optional[int]:
    """The number of messages the file's summary section states, or None (no summary: a cut file)."""
    from mcap.reader import make_reader

    try:
        summary = make_reader(io.BytesIO(data)).get_summary()
        return None if summary is None or summary.statistics is None else int(summary.statistics.message_count)
    except Exception:  # noqa: BLE001 - a broken summary only costs the progress bar its total
        return None


def read_recording(path: Union[str, Path], progress: bool = False) -> Recording:
    """Read a recording written by :class:`EpisodeRecorder`.

    Reading stops at the first message that cannot be decoded or is inconsistent (a truncated file, a corrupt
    record); :attr:`Recording.error` then names it (a file that ends inside a record is said to be truncated, at
    its size in bytes), and :attr:`Recording.steps` holds every complete step before it.

    Args:
        path: the ``.mcap`` file.
        progress: show a progress bar (tqdm, on stderr) over the messages read, from the first one.

    Raises:
        ValueError: a missing file, a file that is not an MCAP recording with SuperEx metadata, metadata values of
            the wrong type (:data:`METADATA_TYPES`), another format version, a map frame beyond the size limits
            (:func:`superex_deploy.messages.check_map_size`).
    """
    from mcap.exceptions import EndOfFile
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory
    from tqdm import tqdm

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"recording {path} does not exist or is not a file")
    data = path.read_bytes()
    metadata = _metadata(data, path)
    if metadata.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path} has recording format {metadata.get('format_version')!r}, this package reads "
                         f"{FORMAT_VERSION!r}")
    try:
        frame_fields = metadata["frame"]
        frame = MapFrame(tuple(frame_fields["shape"]), frame_fields["resolution_m"], tuple(frame_fields["origin_xy"]))
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: the map frame in the metadata is unusable ({error})") from None
    recording = Recording(metadata=metadata, frame=frame)
    stream = io.BytesIO(data)
    reader = NonSeekingReader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
    parts: dict = {}
    current = -1
    done = 0  # messages fully read
    topic, sequence = "?", -1
    # In file order: sorting by time would read the whole file before yielding, and a cut one not at all.
    with tqdm(reader.iter_decoded_messages(log_time_order=False), desc=f"reading {path.name}", unit="msg",
              total=_message_count(data) if progress else None, disable=not progress) as messages:
        try:
            for _, channel, message, decoded in messages:
                topic, sequence = channel.topic, message.sequence
                if topic in _REPLAYED_TOPICS:
                    if sequence != current:
                        parts, current = {}, sequence
                    parts[topic] = decoded
                    if topic == "/command":
                        if "/pose" not in parts or ("/scan" not in parts and "/slam_map" not in parts):
                            raise ValueError("a command without the pose and scan (or SLAM map) of its step")
                        goal = (int(decoded.goal_row), int(decoded.goal_col)) if decoded.has_goal else None
                        recording.steps.append(RecordedStep(step=int(decoded.step),
                                                            observation=_observation(parts, frame),
                                                            goal_rc=goal, new_goal=bool(decoded.new_goal),
                                                            finished=bool(decoded.finished)))
                done += 1
                topic, sequence = "?", -1
        except Exception as error:  # noqa: BLE001 - any decoding failure ends the readable part
            steps = recording.steps
            if topic != "?":
                where = f"topic {topic}, step {sequence}"
            else:
                where = f"after step {steps[-1].step}" if steps else "before the first step"
            if isinstance(error, EndOfFile) or stream.tell() >= len(data):
                why = f"the file is truncated: it ends at byte {len(data):,}, inside a record"
            else:
                why = f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
            recording.error = f"message {done + 1} ({where}) is broken: {why}; kept the {len(steps)} complete " \
                              f"steps before it"
    return recording
