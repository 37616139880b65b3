"""The ROS 2 messages SuperEx reads and writes, as Cyclone DDS ``IdlStruct`` classes that serialise byte for byte as
ROS 2 does.

A ROS 2 message on the wire (``rmw_cyclonedds_cpp``, also Fast DDS) is the XCDR1 ("plain CDR") encoding of its
IDL struct ``pkg::msg::dds_::Type_``: every class here is ``@annotate.final`` (no DHEADERs, no member ids) with the
fields, order and types of the ROS definition (constants are class attributes, not fields), so that
``msg.serialize()`` equals ``rosbags``' ``Typestore.serialize_cdr`` of the same message and a ROS node reads it
(``tests/test_ros_wire.py`` checks every class against rosbags' ``Stores.ROS2_JAZZY``, with random values).

``visualization_msgs/Marker`` follows **Jazzy**, with ``texture_resource``, ``texture``, ``uv_coordinates`` and
``mesh_file``. These fields are older than they look: ros2/common_interfaces added them in August 2021 ("Marker
Textures"), so the humble, iron and jazzy branches of ``Marker.msg`` have the same fields (Jazzy only adds the
constant ``ARROW_STRIP``; constants are not on the wire), as rosbags' ``ROS2_HUMBLE`` and ``ROS2_JAZZY`` stores do:
this class is Humble's Marker too. Galactic's lacks the four fields and does not interoperate.

**Big arrays.** After building each class's machines this module swaps every machine of a sequence or array of
numbers (not ``bool``) for a numpy one (:mod:`superex_deploy.ros.cdr_arrays`, which says why and how much faster):
**numeric sequences and arrays deserialise as writable numpy arrays** of their ROS dtype (``ranges``: float32,
``data``: int8, ``covariance``: float64 [36]) and serialise from a numpy array, a list or (1-byte types) ``bytes``; a
value of another dtype is converted when no value changes (an int64 array of -1..100 into int8) and refused with a
``ValueError`` otherwise (a float into an integer field, 200 into int8, a 2-D array). :data:`FAST_FIELDS` counts the
swapped machines (``tests/test_ros_wire.py`` checks the swap is in place).

Messages compare equal (``==``) field by field, numpy arrays by value (NaN is not equal to NaN, as for floats).
:func:`to_cdr` / :func:`from_cdr` serialise with one ``ValueError`` for bad input; the helpers at the end convert
to and from numpy and seconds.
"""

import math
import re
from dataclasses import dataclass, field, fields

import numpy as np
from cyclonedds.idl import IdlStruct, annotations as annotate, types

from superex_deploy.recording.schemas import SPAD_FRAME_MSG
from superex_deploy.ros.cdr_arrays import install_fast_machines

__all__ = ["MESSAGE_TYPES", "EXPLORER_STATUS_MSG", "SPAD_FRAME_MSG", "RosMessage", "ros_message", "field_error",
           "ros_name", "dds_type_name", "to_cdr",
           "from_cdr", "ranges_array", "grid_array", "grid_data", "covariance_matrix", "time_from_seconds", "seconds",
           "Time", "Duration", "Header", "ColorRGBA", "Empty", "String", "Point", "Point32", "Quaternion", "Pose",
           "PoseStamped", "PoseWithCovariance", "PoseWithCovarianceStamped", "Vector3", "Transform",
           "TransformStamped", "Twist", "TwistWithCovariance", "Polygon", "PolygonStamped", "CompressedImage",
           "LaserScan", "MapMetaData", "OccupancyGrid", "Path", "Odometry", "TFMessage", "Clock", "UVCoordinate",
           "MeshFile", "Marker", "MarkerArray", "SpadFrame", "ExplorerStatus"]

_SEPARATOR = "=" * 80 + "\n"
EXPLORER_STATUS_MSG = """# The SuperEx explorer node's state, published after every step and whenever the state changes.
std_msgs/Header header     # stamp: when the status was made (the node's clock); frame_id: the map frame
string state               # waiting_for_scan | exploring | no_reachable_frontier | returning | done | paused | waiting_for_input
string reason              # why there is no goal, in words; empty with a goal
bool finished              # exploration is over: no reachable frontier is left (state done)
bool has_goal              # the explorer holds a goal
float64 goal_x             # goal in the map frame (m); NaN without a goal
float64 goal_y             # (m); NaN without a goal
uint32 step                # the explorer's step counter
float64 known_area_m2      # area of the explorer's map that is known, free or occupied (m^2)
float64 free_area_m2       # area of the explorer's map that is known free (m^2)
uint32 frontiers           # frontier regions the planner was offered at the last step
float64 latency_s          # from the last stepped scan's arrival to its goal's publication (s); NaN before any
float64 scan_age_s         # now minus the newest scan's stamp (s); NaN before any scan
float64 map_age_s          # now minus the newest SLAM map's stamp (s); NaN without a map topic or before any map
float64 tf_age_s           # now minus the newest map-to-robot transform's stamp (s); NaN when poses come without tf
float64 prediction_age_s   # the prediction's age at the last step, between stamps (s); NaN without a prediction
string[] stage_names       # the last step's stages, in order; same length as stage_s
float64[] stage_s          # time the last step spent in each stage (s)
uint32 scans_received      # scans received since the node started
uint32 scans_dropped       # scans replaced by a newer one before a step used them
uint32 steps_skipped       # loop iterations that had no usable input (no scan, no pose or a stale map)
""" + _SEPARATOR + """MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
""" + _SEPARATOR + """MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
"""``superex_msgs/msg/ExplorerStatus``, with its dependencies (the MCAP ``ros2msg`` schema form)."""


def _eq(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and bool(np.array_equal(a, b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_eq(x, y) for x, y in zip(a, b))
    return bool(a == b)


class RosMessage(IdlStruct):
    """Base of the messages: equality field by field, numpy arrays by value."""

    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        return all(_eq(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))


def _arr(dtype, n: int = 0):
    return field(default_factory=lambda: np.zeros(n, dtype))


def _msg(cls):
    return field(default_factory=cls)


def ros_message(cls):
    """``@dataclass`` (equality from :class:`RosMessage`) ``@annotate.final``: plain CDR, as ROS 2 encodes."""
    return dataclass(eq=False)(annotate.final(cls))


_F64, _F32 = types.float64, types.float32

@ros_message
class Time(RosMessage, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: types.int32 = 0
    nanosec: types.uint32 = 0

@ros_message
class Duration(RosMessage, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: types.int32 = 0
    nanosec: types.uint32 = 0

@ros_message
class Header(RosMessage, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = _msg(Time)
    frame_id: str = ""

@ros_message
class ColorRGBA(RosMessage, typename="std_msgs::msg::dds_::ColorRGBA_"):
    r: _F32 = 0.0
    g: _F32 = 0.0
    b: _F32 = 0.0
    a: _F32 = 0.0

@ros_message
class Empty(RosMessage, typename="std_msgs::msg::dds_::Empty_"):
    structure_needs_at_least_one_member: types.uint8 = 0

@ros_message
class String(RosMessage, typename="std_msgs::msg::dds_::String_"):
    data: str = ""

@ros_message
class Point(RosMessage, typename="geometry_msgs::msg::dds_::Point_"):
    x: _F64 = 0.0
    y: _F64 = 0.0
    z: _F64 = 0.0

@ros_message
class Point32(RosMessage, typename="geometry_msgs::msg::dds_::Point32_"):
    x: _F32 = 0.0
    y: _F32 = 0.0
    z: _F32 = 0.0

@ros_message
class Quaternion(RosMessage, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: _F64 = 0.0
    y: _F64 = 0.0
    z: _F64 = 0.0
    w: _F64 = 1.0

@ros_message
class Vector3(RosMessage, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: _F64 = 0.0
    y: _F64 = 0.0
    z: _F64 = 0.0

@ros_message
class Pose(RosMessage, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = _msg(Point)
    orientation: Quaternion = _msg(Quaternion)

@ros_message
class PoseStamped(RosMessage, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = _msg(Header)
    pose: Pose = _msg(Pose)

@ros_message
class PoseWithCovariance(RosMessage, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = _msg(Pose)
    covariance: types.array[_F64, 36] = _arr(np.float64, 36)  # row-major 6 x 6 over (x, y, z, rot x, rot y, rot z)

@ros_message
class PoseWithCovarianceStamped(RosMessage, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header = _msg(Header)
    pose: PoseWithCovariance = _msg(PoseWithCovariance)

@ros_message
class Transform(RosMessage, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = _msg(Vector3)
    rotation: Quaternion = _msg(Quaternion)

@ros_message
class TransformStamped(RosMessage, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = _msg(Header)
    child_frame_id: str = ""
    transform: Transform = _msg(Transform)

@ros_message
class Twist(RosMessage, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = _msg(Vector3)
    angular: Vector3 = _msg(Vector3)

@ros_message
class TwistWithCovariance(RosMessage, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = _msg(Twist)
    covariance: types.array[_F64, 36] = _arr(np.float64, 36)

@ros_message
class Polygon(RosMessage, typename="geometry_msgs::msg::dds_::Polygon_"):
    points: types.sequence[Point32] = field(default_factory=list)

@ros_message
class PolygonStamped(RosMessage, typename="geometry_msgs::msg::dds_::PolygonStamped_"):
    header: Header = _msg(Header)
    polygon: Polygon = _msg(Polygon)

@ros_message
class CompressedImage(RosMessage, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Header = _msg(Header)
    format: str = ""
    data: types.sequence[types.uint8] = _arr(np.uint8)

@ros_message
class LaserScan(RosMessage, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header = _msg(Header)
    angle_min: _F32 = 0.0        # rad
    angle_max: _F32 = 0.0        # rad
    angle_increment: _F32 = 0.0  # rad
    time_increment: _F32 = 0.0   # s
    scan_time: _F32 = 0.0        # s
    range_min: _F32 = 0.0        # m
    range_max: _F32 = 0.0        # m
    ranges: types.sequence[_F32] = _arr(np.float32)       # m
    intensities: types.sequence[_F32] = _arr(np.float32)

@ros_message
class MapMetaData(RosMessage, typename="nav_msgs::msg::dds_::MapMetaData_"):
    map_load_time: Time = _msg(Time)
    resolution: _F32 = 0.0  # m / cell
    width: types.uint32 = 0
    height: types.uint32 = 0
    origin: Pose = _msg(Pose)  # cell (0, 0)'s corner in the map frame

@ros_message
class OccupancyGrid(RosMessage, typename="nav_msgs::msg::dds_::OccupancyGrid_"):
    header: Header = _msg(Header)
    info: MapMetaData = _msg(MapMetaData)
    data: types.sequence[types.int8] = _arr(np.int8)  # row-major from the origin, -1 unknown, 0..100 occupied %

@ros_message
class Path(RosMessage, typename="nav_msgs::msg::dds_::Path_"):
    header: Header = _msg(Header)
    poses: types.sequence[PoseStamped] = field(default_factory=list)

@ros_message
class Odometry(RosMessage, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = _msg(Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = _msg(PoseWithCovariance)
    twist: TwistWithCovariance = _msg(TwistWithCovariance)

@ros_message
class TFMessage(RosMessage, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: types.sequence[TransformStamped] = field(default_factory=list)

@ros_message
class Clock(RosMessage, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time = _msg(Time)

@ros_message
class UVCoordinate(RosMessage, typename="visualization_msgs::msg::dds_::UVCoordinate_"):
    u: _F32 = 0.0
    v: _F32 = 0.0

@ros_message
class MeshFile(RosMessage, typename="visualization_msgs::msg::dds_::MeshFile_"):
    filename: str = ""
    data: types.sequence[types.uint8] = _arr(np.uint8)

@ros_message
class Marker(RosMessage, typename="visualization_msgs::msg::dds_::Marker_"):
    header: Header = _msg(Header)
    ns: str = ""
    id: types.int32 = 0
    type: types.int32 = 0
    action: types.int32 = 0
    pose: Pose = _msg(Pose)
    scale: Vector3 = _msg(Vector3)
    color: ColorRGBA = _msg(ColorRGBA)
    lifetime: Duration = _msg(Duration)
    frame_locked: bool = False
    points: types.sequence[Point] = field(default_factory=list)
    colors: types.sequence[ColorRGBA] = field(default_factory=list)
    texture_resource: str = ""
    texture: CompressedImage = _msg(CompressedImage)
    uv_coordinates: types.sequence[UVCoordinate] = field(default_factory=list)
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile = _msg(MeshFile)
    mesh_use_embedded_materials: bool = False
    # Constants (not fields): the Jazzy definition's.
    ARROW, CUBE, SPHERE, CYLINDER, LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, POINTS = range(9)
    TEXT_VIEW_FACING, MESH_RESOURCE, TRIANGLE_LIST, ARROW_STRIP = 9, 10, 11, 12
    ADD, MODIFY, DELETE, DELETEALL = 0, 0, 2, 3

@ros_message
class MarkerArray(RosMessage, typename="visualization_msgs::msg::dds_::MarkerArray_"):
    markers: types.sequence[Marker] = field(default_factory=list)

@ros_message
class SpadFrame(RosMessage, typename="superex_msgs::msg::dds_::SpadFrame_"):
    """``superex_msgs/msg/SpadFrame`` (definition: :data:`SPAD_FRAME_MSG`, with units)."""

    header: Header = _msg(Header)
    bin_width_s: _F64 = 0.0
    n_rays: types.uint32 = 0
    n_bins: types.uint32 = 0
    nnz: types.uint32 = 0
    angles_f64le: types.sequence[types.uint8] = _arr(np.uint8)
    row_start_i64le: types.sequence[types.uint8] = _arr(np.uint8)
    bins_i32le: types.sequence[types.uint8] = _arr(np.uint8)
    counts_f32le: types.sequence[types.uint8] = _arr(np.uint8)

@ros_message
class ExplorerStatus(RosMessage, typename="superex_msgs::msg::dds_::ExplorerStatus_"):
    """``superex_msgs/msg/ExplorerStatus`` (definition: :data:`EXPLORER_STATUS_MSG`, with units)."""

    header: Header = _msg(Header)
    state: str = ""
    reason: str = ""
    finished: bool = False
    has_goal: bool = False
    goal_x: _F64 = math.nan
    goal_y: _F64 = math.nan
    step: types.uint32 = 0
    known_area_m2: _F64 = 0.0
    free_area_m2: _F64 = 0.0
    frontiers: types.uint32 = 0
    latency_s: _F64 = math.nan
    scan_age_s: _F64 = math.nan
    map_age_s: _F64 = math.nan
    tf_age_s: _F64 = math.nan
    prediction_age_s: _F64 = math.nan
    stage_names: types.sequence[str] = field(default_factory=list)
    stage_s: types.sequence[_F64] = _arr(np.float64)
    scans_received: types.uint32 = 0
    scans_dropped: types.uint32 = 0
    steps_skipped: types.uint32 = 0


def dds_type_name(name: str) -> str:
    """``"sensor_msgs/msg/LaserScan"`` -> ``"sensor_msgs::msg::dds_::LaserScan_"`` (the DDS type ROS 2 uses)."""
    package, kind, base = name.split("/")
    return f"{package}::{kind}::dds_::{base}_"


def ros_name(cls) -> str:
    """The ROS 2 name of a message class (``"sensor_msgs/msg/LaserScan"``), from its DDS type name."""
    typename = getattr(cls, "__idl_typename__", "")
    parts = typename.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise ValueError(f"{cls!r} is not a ROS 2 message class (DDS type name {typename!r})")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


MESSAGE_TYPES: dict[str, type] = {ros_name(c): c for c in (
    Time, Duration, Header, ColorRGBA, Empty, String, Point, Point32, Quaternion, Vector3, Pose, PoseStamped,
    PoseWithCovariance, PoseWithCovarianceStamped, Transform, TransformStamped, Twist, TwistWithCovariance, Polygon,
    PolygonStamped, CompressedImage, LaserScan, MapMetaData, OccupancyGrid, Path, Odometry, TFMessage, Clock,
    UVCoordinate, MeshFile, Marker, MarkerArray, SpadFrame, ExplorerStatus)}
"""ROS 2 name (``"sensor_msgs/msg/LaserScan"``) -> message class, for every message this package puts on the wire."""


FAST_FIELDS = {name: install_fast_machines(cls) for name, cls in MESSAGE_TYPES.items()}
"""ROS name -> number of machines swapped for numpy ones (two per numeric array field: XCDR1 and XCDR2)."""


# --- Serialisation and numpy helpers ----------------------------------------------------------------------------

def field_error(error: BaseException) -> str:
    """``"info.width: <cause>"`` from cyclonedds' chain of "Failed to encode member X" exceptions."""
    path = []
    while error.__cause__ is not None:
        match = re.match(r"Failed to encode member (\w+)", str(error))
        if match:
            path.append(match.group(1))
        error = error.__cause__
    return f"field {'.'.join(path) or '?'}: {error}"


def to_cdr(message) -> bytes:
    """The ROS 2 wire bytes of ``message`` (4-byte CDR_LE header, then XCDR1), as ``rmw_cyclonedds`` sends them.

    Raises:
        ValueError: ``message`` is not one of :data:`MESSAGE_TYPES`, or a field does not fit its type (naming it).
    """
    if type(message) not in MESSAGE_TYPES.values():
        raise ValueError(f"not a ROS message of this package: {type(message).__name__}")
    try:
        return message.serialize()
    except Exception as error:  # cyclonedds wraps every member's error in a bare Exception
        raise ValueError(f"cannot serialise this {ros_name(type(message))}: {field_error(error)}") from error


def from_cdr(cls, data: bytes):
    """The ``cls`` message in the ROS 2 wire bytes ``data`` (from :func:`to_cdr`, a ROS node or a bag).

    Raises:
        ValueError: ``cls`` is not one of :data:`MESSAGE_TYPES`, or ``data`` is too short or malformed.
    """
    if cls not in MESSAGE_TYPES.values():
        raise ValueError(f"not a ROS message class of this package: {cls!r}")
    data = bytes(data)
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError(f"not XCDR1 ROS 2 data for {ros_name(cls)} (header {data[:4]!r})")
    try:
        return cls.deserialize(data)
    except Exception as error:
        raise ValueError(f"malformed {ros_name(cls)} data ({len(data)} bytes): {error!r}") from error


def ranges_array(scan: LaserScan) -> np.ndarray:
    """The scan's ranges as float32 ``[n]`` metres (the field itself when it is already that array)."""
    return np.asarray(scan.ranges, np.float32)


def grid_array(grid: OccupancyGrid) -> np.ndarray:
    """The grid's cells as int8 ``[height, width]``, row 0 at ``info.origin`` (ROS order: the bottom row of the
    map image; ``[::-1]`` puts row 0 at the top, as ``superex_deploy`` grids have it). -1 unknown, 0..100 occupied %.

    Raises:
        ValueError: ``data`` does not hold ``width * height`` cells.
    """
    data = np.asarray(grid.data, np.int8)
    height, width = int(grid.info.height), int(grid.info.width)
    if data.ndim != 1 or data.size != height * width:
        raise ValueError(f"an OccupancyGrid of {width} x {height} cells holds {data.size} values")
    return data.reshape(height, width)


def grid_data(values) -> np.ndarray:
    """OccupancyGrid ``data`` (int8 ``[height * width]``) from int ``[height, width]`` values, row 0 at the origin.

    Raises:
        ValueError: ``values`` is not 2-D, not integer, or outside -1..100.
    """
    values = np.asarray(values)
    if values.ndim != 2 or values.dtype.kind not in "iu":
        raise ValueError(f"grid values must be a 2-D integer array, got {values.dtype} {values.shape}")
    if values.size and (values.min() < -1 or values.max() > 100):
        raise ValueError(f"grid values must be -1 (unknown) or 0..100, got {values.min()}..{values.max()}")
    return np.ascontiguousarray(values, np.int8).ravel()


def covariance_matrix(message) -> np.ndarray:
    """float64 ``[6, 6]`` covariance of a ``PoseWithCovariance`` or ``TwistWithCovariance`` (x, y, z, rotations)."""
    return np.asarray(message.covariance, np.float64).reshape(6, 6)


def time_from_seconds(t: float) -> Time:
    """``builtin_interfaces/Time`` of ``t`` seconds, rounded to the nanosecond (as ``recording.schemas`` does).

    Raises:
        ValueError: ``t`` is NaN, negative or past ``2**31 - 1`` s.
    """
    t = float(t)
    nanoseconds = int(round(t * 1e9)) if 0.0 <= t < 2.0 ** 31 else -1
    if not 0 <= nanoseconds < 2 ** 31 * 10 ** 9:
        raise ValueError(f"a ROS time stamp must be in [0, 2**31) s, got {t!r}")
    return Time(sec=nanoseconds // 10 ** 9, nanosec=nanoseconds % 10 ** 9)


def seconds(stamp) -> float:
    """Seconds of a ``Time`` or ``Duration`` (``sec + nanosec * 1e-9``)."""
    return stamp.sec + stamp.nanosec * 1e-9
