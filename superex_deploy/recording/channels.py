"""The one table of topics an episode is published on: :data:`CHANNELS`, read by the MCAP writer
(:class:`~superex_deploy.recording.writer.EpisodeRecorder`, the ``recorded`` ones) and by the live view
(:class:`~superex_deploy.recording.live.LiveServer`, all of them), so that a file and a live client see the same
topics, types, schemas and messages.

Every topic is a ROS 2 message type: its schema is ``ros2msg`` text (:mod:`~superex_deploy.recording.schemas`), its
messages are CDR-encoded (:data:`SCHEMA_ENCODING`, :data:`MESSAGE_ENCODING`). A channel's ``build`` turns one step
(:class:`StepData`) into the message as a dict of the schema's fields, or None when the step has nothing for it (no
scan, no goal, no map this step). Large arrays are numpy arrays there (a grid's ``data``, a scan's ``ranges``);
:func:`plain_values` makes them the lists the ``mcap_ros2`` encoder takes.

Besides the recorded topics (the table in :mod:`superex_deploy.recording`), the live view publishes:

===============  ==================================  ==============================================================
topic            type                                content
===============  ==================================  ==============================================================
``/tf``          ``tf2_msgs/msg/TFMessage``          ``map`` -> ``base_scan``: the robot's pose, so that a 3D panel
                                                     places the scan
``/goal``        ``geometry_msgs/msg/PoseStamped``   the goal (frame ``map``, yaw 0), on steps with one
``/prediction``  ``nav_msgs/msg/OccupancyGrid``      the newest predicted map: the wall probability in percent
``/evidence``    ``nav_msgs/msg/OccupancyGrid``      the SPAD NLOS evidence the predictor reads, in percent of its
                                                     [0, 1] range
===============  ==================================  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from superex_deploy.messages import Command, MapFrame, Observation
from superex_deploy.messages.ros_fields import spad_fields
from superex_deploy.recording.schemas import (COVARIANCE_INDEX, OCCUPANCY_GRID_MSG, POSE_STAMPED_MSG, SCHEMAS,
                                             TF_MESSAGE_MSG, header_message, pose_message, stamp_message)

__all__ = ["SCHEMA_ENCODING", "MESSAGE_ENCODING", "SCAN_FRAME", "StepData", "ChannelSpec", "CHANNELS",
           "RECORDED_CHANNELS", "channel", "grid_message", "map_message", "percent_grid", "plain_values"]

SCHEMA_ENCODING = "ros2msg"
"""How every channel's schema is written (ROS 2 ``.msg`` text, dependencies after ``===`` separators)."""
MESSAGE_ENCODING = "cdr"
"""How every channel's messages are encoded (ROS 2's CDR, little-endian)."""
SCAN_FRAME = "base_scan"
"""The frame of the scan and the SPAD frame: the robot's, aligned with its heading."""


@dataclass(frozen=True)
class StepData:
    """What one step publishes, read by the channels' ``build`` functions.

    Attributes:
        observation: what the explorer received.
        command: what it answered.
        frame: the explorer's map frame of the step (a map that grows changes it).
        observed: int8 ``[H, W]`` the explorer's map (UNKNOWN -1, FREE 0, OCCUPIED 1) on ``frame``, or None: no map
            this step (maps are large; they are written every few steps).
        prediction: float32 ``[H, W]`` the newest prediction's wall probability in [0, 1], or None.
        evidence: float32 ``[H, W]`` the NLOS evidence in [0, 1], or None.
    """

    observation: Observation
    command: Command
    frame: MapFrame
    observed: Optional[np.ndarray] = None
    prediction: Optional[np.ndarray] = None
    evidence: Optional[np.ndarray] = None


@dataclass(frozen=True)
class ChannelSpec:
    """One topic.

    Attributes:
        topic: the topic name.
        type_name: the ROS 2 message type (``nav_msgs/msg/OccupancyGrid``), the schema's name.
        schema: its ``ros2msg`` text.
        build: ``StepData -> dict | None``: the message of a step, or None (nothing this step).
        recorded: whether the MCAP recording holds it (otherwise the live view alone publishes it).
        grid: whether its messages are large (a map, a SPAD frame): the live view publishes them at a limited rate.
    """

    topic: str
    type_name: str
    schema: str
    build: Callable[[StepData], Optional[dict]]
    recorded: bool = True
    grid: bool = False


def grid_message(values: np.ndarray, frame: MapFrame, stamp_s: float) -> dict:
    """A ``nav_msgs/OccupancyGrid`` of int8 ``[H, W]`` ``values`` (row 0 at the top of the map image) on ``frame``:
    rows flipped (ROS grids start at the bottom row), ``data`` an int8 ``[H * W]`` array, frame ``map``."""
    height, width = frame.shape
    return {"header": header_message(stamp_s, "map"),
            "info": {"map_load_time": stamp_message(0.0), "resolution": frame.resolution_m,
                     "width": width, "height": height,
                     "origin": pose_message(frame.origin_xy[0], frame.origin_xy[1], 0.0)},
            "data": np.ascontiguousarray(np.asarray(values, np.int8)[::-1]).ravel()}


def percent_grid(values: np.ndarray) -> np.ndarray:
    """int8 ``[H, W]`` percent (0..100) of float ``[H, W]`` values in [0, 1] (clipped; NaN counts as 0)."""
    return np.rint(np.clip(np.nan_to_num(np.asarray(values, np.float32)), 0.0, 1.0) * 100.0).astype(np.int8)


def plain_values(message: dict) -> dict:
    """``message`` with its top-level numpy arrays as lists (the values the ``mcap_ros2`` encoder takes)."""
    return {key: value.tolist() if isinstance(value, np.ndarray) else value for key, value in message.items()}


def _pose(step: StepData) -> dict:
    pose = step.observation.pose
    return {"header": header_message(step.observation.stamp_s, "map"), "pose": pose_message(pose.x, pose.y, pose.yaw)}


def _tf(step: StepData) -> dict:
    pose, stamp = step.observation.pose, step.observation.stamp_s
    rotation = pose_message(pose.x, pose.y, pose.yaw)["orientation"]
    return {"transforms": [{"header": header_message(stamp, "map"), "child_frame_id": SCAN_FRAME,
                            "transform": {"translation": {"x": pose.x, "y": pose.y, "z": 0.0},
                                          "rotation": rotation}}]}


def _scan(step: StepData) -> Optional[dict]:
    scan = step.observation.scan
    if scan is None:
        return None
    return {"header": header_message(step.observation.stamp_s, SCAN_FRAME), "angle_min": scan.angle_min,
            "angle_max": scan.angle_max, "angle_increment": scan.angle_increment, "time_increment": 0.0,
            "scan_time": 0.0, "range_min": scan.range_min, "range_max": scan.range_max, "ranges": scan.ranges,
            "intensities": []}


def _slam_map(step: StepData) -> Optional[dict]:
    grid, stamp = step.observation.occupancy_grid, step.observation.stamp_s
    if grid is None:
        return None
    # The map's own stamp, where it has one: a map handed to several steps is one map again in a replay.
    return {"header": header_message(stamp if grid.stamp_s is None else grid.stamp_s, "map"),
            "info": {"map_load_time": stamp_message(0.0), "resolution": grid.resolution_m, "width": grid.width,
                     "height": grid.height, "origin": pose_message(grid.origin_xy[0], grid.origin_xy[1], 0.0)},
            "data": grid.data}


def _pose_covariance(step: StepData) -> Optional[dict]:
    covariance = step.observation.pose_covariance
    if covariance is None:
        return None
    full = np.zeros((6, 6))
    full[np.ix_(COVARIANCE_INDEX, COVARIANCE_INDEX)] = covariance.matrix
    pose = step.observation.pose
    return {"header": header_message(step.observation.stamp_s, "map"),
            "pose": {"pose": pose_message(pose.x, pose.y, pose.yaw), "covariance": full.ravel().tolist()}}


def _spad(step: StepData) -> Optional[dict]:
    spad = step.observation.spad
    if spad is None:
        return None
    return {"header": header_message(step.observation.stamp_s, SCAN_FRAME), **spad_fields(spad)}


def _command(step: StepData) -> dict:
    command, stamp = step.command, step.observation.stamp_s
    goal = command.goal_rc
    return {"header": header_message(stamp, "map"), "step": command.step, "has_goal": goal is not None,
            "goal_row": -1 if goal is None else goal[0], "goal_col": -1 if goal is None else goal[1],
            "goal_x": math.nan if goal is None else command.goal_xy[0],
            "goal_y": math.nan if goal is None else command.goal_xy[1],
            "new_goal": bool(command.new_goal), "finished": bool(command.finished),
            "prediction_step": int(command.prediction_step), "robot_yaw": step.observation.pose.yaw,
            "prediction_age_s": math.nan if command.prediction_age_s is None else float(command.prediction_age_s),
            "status": str(command.status), "reason": str(command.reason)}


def _goal(step: StepData) -> Optional[dict]:
    goal = step.command.goal_xy
    if goal is None:
        return None
    return {"header": header_message(step.observation.stamp_s, "map"),
            "pose": pose_message(float(goal[0]), float(goal[1]), 0.0)}


def _plan(step: StepData) -> dict:
    header = header_message(step.observation.stamp_s, "map")
    orientation = pose_message(0.0, 0.0, 0.0)["orientation"]  # one dict for every pose: read, never changed
    return {"header": header,
            "poses": [{"header": header, "pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": orientation}}
                      for x, y in np.asarray(step.command.path_xy, np.float64).reshape(-1, 2).tolist()]}


def map_message(observed: np.ndarray, frame: MapFrame, stamp_s: float) -> dict:
    """The ``/map`` message of the explorer's int8 ``[H, W]`` map on ``frame``: -1 unknown, 0 free, 100 occupied."""
    observed = np.asarray(observed)
    return grid_message(np.where(observed > 0, 100, observed), frame, stamp_s)


def _map(step: StepData) -> Optional[dict]:
    return None if step.observed is None else map_message(step.observed, step.frame, step.observation.stamp_s)


def _on_frame(values: Optional[np.ndarray], step: StepData) -> Optional[dict]:
    """A percent grid of ``values`` when they lie on the step's frame (None otherwise: a map that grew since)."""
    if values is None or np.shape(values) != tuple(step.frame.shape):
        return None
    return grid_message(percent_grid(values), step.frame, step.observation.stamp_s)


def _spec(topic: str, build: Callable, recorded: bool = True, grid: bool = False, type_name: str = "",
          schema: str = "") -> ChannelSpec:
    name, text = SCHEMAS[topic] if recorded else (type_name, schema)
    return ChannelSpec(topic, name, text, build, recorded=recorded, grid=grid)


CHANNELS: tuple = (
    _spec("/pose", _pose),
    _spec("/tf", _tf, recorded=False, type_name="tf2_msgs/msg/TFMessage", schema=TF_MESSAGE_MSG),
    _spec("/scan", _scan),
    _spec("/slam_map", _slam_map, grid=True),
    _spec("/pose_covariance", _pose_covariance),
    _spec("/spad", _spad, grid=True),
    _spec("/command", _command),
    _spec("/goal", _goal, recorded=False, type_name="geometry_msgs/msg/PoseStamped", schema=POSE_STAMPED_MSG),
    _spec("/plan", _plan),
    _spec("/map", _map, grid=True),
    _spec("/prediction", lambda step: _on_frame(step.prediction, step), recorded=False, grid=True,
          type_name="nav_msgs/msg/OccupancyGrid", schema=OCCUPANCY_GRID_MSG),
    _spec("/evidence", lambda step: _on_frame(step.evidence, step), recorded=False, grid=True,
          type_name="nav_msgs/msg/OccupancyGrid", schema=OCCUPANCY_GRID_MSG),
)
"""Every topic, in the order a step publishes them (the order a recording's messages of a step are written)."""
RECORDED_CHANNELS: tuple = tuple(spec for spec in CHANNELS if spec.recorded)
"""The topics an MCAP recording holds (:data:`superex_deploy.recording.schemas.SCHEMAS` names their schemas)."""


def channel(topic: str) -> ChannelSpec:
    """The channel of ``topic``.

    Raises:
        KeyError: naming a topic no channel publishes.
    """
    for spec in CHANNELS:
        if spec.topic == topic:
            return spec
    raise KeyError(f"no channel publishes {topic!r} ({', '.join(spec.topic for spec in CHANNELS)})")
