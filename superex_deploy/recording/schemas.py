"""The recording's format: its version, metadata keys and types, the ROS 2 message schemas it writes, and the small
conversions of stamps and poses both the writer and the reader use."""

from __future__ import annotations

import math

from superex_deploy.messages.ros_fields import stamp_message, stamp_seconds

__all__ = ["FORMAT_VERSION", "METADATA_NAME", "METADATA_TYPES", "check_metadata", "SPAD_FRAME_MSG",
           "EXPLORER_COMMAND_MSG", "POSE_STAMPED_MSG", "LASER_SCAN_MSG", "PATH_MSG", "OCCUPANCY_GRID_MSG",
           "POSE_WITH_COVARIANCE_STAMPED_MSG", "TF_MESSAGE_MSG", "SCHEMAS", "REPLAYED_TOPICS", "COVARIANCE_INDEX",
           "stamp_message", "stamp_seconds", "header_message", "pose_message"]

FORMAT_VERSION = "2"
"""The recording format this package writes and reads (:mod:`superex_deploy.recording.metadata`). ``"1"``: the
versions up to 0.2, whose metadata held some configurations in their old form (``superex convert-recording``,
:mod:`superex_deploy.recording.convert`, rewrites it)."""
METADATA_NAME = "superex.episode"
METADATA_TYPES: dict = {"format_version": (str,), "frame": (dict,), "map": (str,), "planner": (str,),
                        "planner_options": (dict, type(None)), "planner_config": (dict,), "predictor": (str,),
                        "seed": (int,), "spad": (bool,), "models": (str, type(None)), "sensor": (dict, type(None)),
                        "nlos": (dict, type(None)), "explorer": (dict,), "profile": (str, type(None)),
                        "profile_settings": (dict,)}
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
int32 prediction_step    # step whose map the newest prediction was made from, -1 for none
float64 robot_yaw        # the observation's yaw (rad), exactly: the /pose quaternion rounds it
float64 prediction_age_s # seconds from that step's stamp to this one's; NaN for none (absent in older files)
string status            # waiting_for_scan, exploring, no_reachable_frontier, returning, done (absent in older files)
string reason            # why no goal was given; empty with a goal (absent in older files)
""" + _SEPARATOR + _HEADER

TF_MESSAGE_MSG = ("geometry_msgs/TransformStamped[] transforms\n" + _SEPARATOR
                  + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
                  "geometry_msgs/Transform transform\n" + _SEPARATOR + _HEADER + _SEPARATOR
                  + "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n"
                  "geometry_msgs/Quaternion rotation\n" + _SEPARATOR
                  + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n" + _SEPARATOR
                  + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n")
"""``tf2_msgs/msg/TFMessage``: the live view's transform from ``map`` to the scan's frame (not recorded)."""

SCHEMAS = {"/pose": ("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSG),
           "/scan": ("sensor_msgs/msg/LaserScan", LASER_SCAN_MSG),
           "/spad": ("superex_msgs/msg/SpadFrame", SPAD_FRAME_MSG),
           "/command": ("superex_msgs/msg/ExplorerCommand", EXPLORER_COMMAND_MSG),
           "/plan": ("nav_msgs/msg/Path", PATH_MSG),
           "/map": ("nav_msgs/msg/OccupancyGrid", OCCUPANCY_GRID_MSG),
           "/slam_map": ("nav_msgs/msg/OccupancyGrid", OCCUPANCY_GRID_MSG),
           "/pose_covariance": ("geometry_msgs/msg/PoseWithCovarianceStamped", POSE_WITH_COVARIANCE_STAMPED_MSG)}
"""Topic -> (ROS 2 message type, its schema text) of every topic a recording holds."""
REPLAYED_TOPICS = ("/pose", "/scan", "/spad", "/slam_map", "/pose_covariance", "/command")
"""The topics the reader gathers into recorded steps (``/plan`` and ``/map`` are written for viewers)."""
COVARIANCE_INDEX = (0, 1, 5)  # x, y and yaw among the 6 x 6 covariance's x, y, z, roll, pitch, yaw
"""Rows and columns of x, y and yaw in a ROS 2 pose's 6 x 6 covariance."""


def header_message(seconds: float, frame_id: str) -> dict:
    """A ``std_msgs/Header`` as a dict: the time of ``seconds`` and ``frame_id``."""
    return {"stamp": stamp_message(seconds), "frame_id": frame_id}


def pose_message(x: float, y: float, yaw: float) -> dict:
    """A planar ``geometry_msgs/Pose`` as a dict: position ``(x, y, 0)`` (metres), orientation the quaternion of a
    rotation by ``yaw`` (radians) about z."""
    return {"position": {"x": x, "y": y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}}
