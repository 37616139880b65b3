"""What the exploration node publishes, as ROS 2 messages (:mod:`superex_deploy.ros.idl`), from the explorer's
command and state: the goal (``geometry_msgs/PoseStamped``, what Nav2's navigator takes on ``/goal_pose``), the path
(``nav_msgs/Path``), the prediction (``nav_msgs/OccupancyGrid``, the wall probability in percent), the frontiers
(``visualization_msgs/MarkerArray``) and the status (``superex_msgs/ExplorerStatus``); and, for the simulated robot,
the inputs a robot publishes (scans, SPAD frames, transforms, maps, the clock).

Poses follow REP 103 and 105: metres and radians in the fixed ``global_frame`` (x east, y north, yaw
counter-clockwise); a goal's orientation is the heading from the robot to it (Nav2 then arrives facing onward).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from superex_deploy.messages import LaserScan, MapFrame, OccupancyGridMessage, SpadFrame
from superex_deploy.messages.ros_fields import spad_fields
from superex_deploy.ros import idl

__all__ = ["header", "pose_message", "goal_message", "path_message", "prediction_message", "frontier_markers",
           "status_message", "scan_message", "spad_message", "tf_message", "grid_message", "clock_message"]


def header(stamp_s: float, frame_id: str) -> idl.Header:
    """A ``std_msgs/Header`` of ``stamp_s`` seconds and ``frame_id``."""
    return idl.Header(stamp=idl.time_from_seconds(stamp_s), frame_id=frame_id)


def pose_message(x: float, y: float, yaw: float) -> idl.Pose:
    """A planar ``geometry_msgs/Pose``: ``(x, y, 0)`` and the rotation by ``yaw`` about ``z``."""
    return idl.Pose(position=idl.Point(x=float(x), y=float(y), z=0.0),
                    orientation=idl.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0)))


def goal_message(goal_xy, robot_xy, stamp_s: float, frame_id: str) -> idl.PoseStamped:
    """The goal as Nav2 takes it: ``goal_xy`` (metres), facing away from ``robot_xy``."""
    yaw = math.atan2(goal_xy[1] - robot_xy[1], goal_xy[0] - robot_xy[0])
    return idl.PoseStamped(header=header(stamp_s, frame_id), pose=pose_message(goal_xy[0], goal_xy[1], yaw))


def path_message(path_xy, stamp_s: float, frame_id: str) -> idl.Path:
    """``nav_msgs/Path`` of float ``[N, 2]`` waypoints (metres), each facing the next."""
    path_xy = np.asarray(path_xy, np.float64).reshape(-1, 2)
    poses = []
    for i, (x, y) in enumerate(path_xy):
        nx, ny = path_xy[min(i + 1, len(path_xy) - 1)]
        yaw = math.atan2(ny - y, nx - x) if i + 1 < len(path_xy) else (poses[-1][2] if poses else 0.0)
        poses.append((x, y, yaw))
    return idl.Path(header=header(stamp_s, frame_id),
                    poses=[idl.PoseStamped(header=header(stamp_s, frame_id), pose=pose_message(x, y, yaw))
                           for x, y, yaw in poses])


def grid_message(grid: OccupancyGridMessage, frame_id: str) -> idl.OccupancyGrid:
    """``nav_msgs/OccupancyGrid`` of an :class:`~superex_deploy.messages.OccupancyGridMessage` (stamped with its
    ``stamp_s``, 0 without one)."""
    stamp = grid.stamp_s or 0.0
    info = idl.MapMetaData(map_load_time=idl.time_from_seconds(stamp), resolution=float(grid.resolution_m),
                           width=grid.width, height=grid.height,
                           origin=pose_message(grid.origin_xy[0], grid.origin_xy[1], 0.0))
    return idl.OccupancyGrid(header=header(stamp, frame_id), info=info, data=grid.data)


def prediction_message(mean: np.ndarray, observed: np.ndarray, frame: MapFrame, stamp_s: float,
                       frame_id: str) -> idl.OccupancyGrid:
    """The prediction as a map: each cell's wall probability in percent (0-100) where the explorer's map is unknown,
    its known value (0 free, 100 wall) elsewhere, on ``frame`` (float ``[H, W]`` ``mean``, int8 ``observed``)."""
    percent = np.rint(np.clip(mean, 0.0, 1.0) * 100.0).astype(np.int8)
    percent = np.where(observed == 0, 0, np.where(observed == 1, 100, percent)).astype(np.int8)
    message = OccupancyGridMessage.from_frame_grid(frame, percent)
    return grid_message(OccupancyGridMessage(message.resolution_m, message.width, message.height, message.origin_xy,
                                             message.data, stamp_s=stamp_s), frame_id)


def frontier_markers(regions_xy: list, goal_xy, stamp_s: float, frame_id: str, cell_m: float) -> idl.MarkerArray:
    """``visualization_msgs/MarkerArray``: one ``POINTS`` marker per frontier region (float ``[n, 2]`` cell centres,
    metres) and a sphere at the goal; a ``DELETEALL`` first clears the previous step's (explore_lite's display)."""
    markers = [idl.Marker(header=header(stamp_s, frame_id), ns="frontiers", id=0, action=3)]  # DELETEALL
    for k, cells in enumerate(regions_xy):
        marker = idl.Marker(header=header(stamp_s, frame_id), ns="frontiers", id=k + 1, type=8, action=0,  # POINTS
                            pose=pose_message(0.0, 0.0, 0.0),
                            scale=idl.Vector3(x=cell_m, y=cell_m, z=cell_m),
                            color=idl.ColorRGBA(r=0.0, g=0.4, b=1.0, a=1.0),
                            points=[idl.Point(x=float(x), y=float(y), z=0.0) for x, y in np.asarray(cells)])
        markers.append(marker)
    if goal_xy is not None:
        markers.append(idl.Marker(header=header(stamp_s, frame_id), ns="goal", id=0, type=2, action=0,  # SPHERE
                                  pose=pose_message(goal_xy[0], goal_xy[1], 0.0),
                                  scale=idl.Vector3(x=0.4, y=0.4, z=0.4),
                                  color=idl.ColorRGBA(r=1.0, g=0.3, b=0.0, a=1.0)))
    return idl.MarkerArray(markers=markers)


def status_message(status, frame_id: str) -> idl.ExplorerStatus:
    """``superex_msgs/ExplorerStatus`` of a :class:`~superex_deploy.ros.node_status.NodeStatus`."""
    goal = status.goal_xy
    names = list(status.stage_s)
    return idl.ExplorerStatus(
        header=header(status.stamp_s, frame_id), state=status.state, reason=status.reason,
        finished=bool(status.finished), has_goal=goal is not None,
        goal_x=math.nan if goal is None else float(goal[0]), goal_y=math.nan if goal is None else float(goal[1]),
        step=int(status.step), known_area_m2=float(status.known_area_m2), free_area_m2=float(status.free_area_m2),
        frontiers=int(status.frontiers), latency_s=float(status.latency_s), scan_age_s=float(status.scan_age_s),
        map_age_s=float(status.map_age_s), tf_age_s=float(status.tf_age_s),
        prediction_age_s=float(status.prediction_age_s), stage_names=names,
        stage_s=np.asarray([status.stage_s[n] for n in names], np.float64),
        scans_received=int(status.scans_received), scans_dropped=int(status.scans_dropped),
        steps_skipped=int(status.steps_skipped))


def scan_message(scan: LaserScan, stamp_s: float, frame_id: str, scan_time_s: float = 0.0) -> idl.LaserScan:
    """``sensor_msgs/LaserScan`` of a :class:`~superex_deploy.messages.LaserScan`."""
    return idl.LaserScan(header=header(stamp_s, frame_id), angle_min=scan.angle_min, angle_max=scan.angle_max,
                         angle_increment=scan.angle_increment, time_increment=0.0, scan_time=float(scan_time_s),
                         range_min=scan.range_min, range_max=scan.range_max, ranges=scan.ranges,
                         intensities=np.zeros(0, np.float32))


def spad_message(spad: SpadFrame, stamp_s: float, frame_id: str) -> idl.SpadFrame:
    """``superex_msgs/SpadFrame`` of a :class:`~superex_deploy.messages.SpadFrame`."""
    fields = spad_fields(spad)
    for name in ("angles_f64le", "row_start_i64le", "bins_i32le", "counts_f32le"):
        fields[name] = np.frombuffer(fields[name], np.uint8)
    return idl.SpadFrame(header=header(stamp_s, frame_id), **fields)


def tf_message(samples) -> idl.TFMessage:
    """``tf2_msgs/TFMessage`` of planar samples (``stamp_s``, ``parent``, ``child``, ``x``, ``y``, ``yaw``)."""
    transforms = []
    for s in samples:
        pose = pose_message(s.x, s.y, s.yaw)
        transforms.append(idl.TransformStamped(
            header=header(s.stamp_s, s.parent), child_frame_id=s.child,
            transform=idl.Transform(translation=idl.Vector3(x=pose.position.x, y=pose.position.y, z=0.0),
                                    rotation=pose.orientation)))
    return idl.TFMessage(transforms=transforms)


def clock_message(stamp_s: float) -> idl.Clock:
    """``rosgraph_msgs/Clock`` of ``stamp_s``."""
    return idl.Clock(clock=idl.time_from_seconds(stamp_s))


def robot_xy(command, fallback: Optional[tuple] = None):
    """The robot's position of a command (its path's first waypoint), or ``fallback``."""
    path = np.asarray(command.path_xy).reshape(-1, 2)
    return tuple(path[0]) if len(path) else fallback
