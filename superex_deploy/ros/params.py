"""The exploration node's parameters (:class:`NodeParams`): names and units as a ROS 2 params file holds them, with
explore_lite's (m-explore-ros2) names where the meaning is the same (``robot_base_frame``, ``costmap_topic``,
``progress_timeout``, ``transform_tolerance``, ``min_frontier_size``, ``return_to_init``, ``visualize``), every
length in metres and every time in seconds.

A params file is the ROS 2 format::

    superex_node:            # the node's name, or /** for every node
      ros__parameters:
        costmap_topic: /map
        planner: superex
        progress_timeout: 30.0

:func:`load_params` reads it (``--params-file``), :meth:`NodeParams.to_yaml` writes one with every parameter (``superex
node --print-params``). An unknown name, a value of the wrong type or out of range is refused with one
``ValueError`` naming it; nothing is guessed.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from pathlib import Path

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_int, check_real
from superex_deploy.onboard.planning.planners import PLANNERS

__all__ = ["NodeParams", "load_params", "PARAM_DOCS"]

PARAM_DOCS = {
    "costmap_topic": "nav_msgs/OccupancyGrid of SLAM (reliable, transient local); '' for none: the node integrates "
                     "the scans itself (explore_lite's name)",
    "map_durability": "durability of the map subscription: transient_local (slam_toolbox, Cartographer, map_server) "
                      "or volatile (a SLAM that publishes the map volatile)",
    "scan_topic": "sensor_msgs/LaserScan (sensor-data QoS: best effort, keep last 5)",
    "spad_topic": "superex_msgs/SpadFrame of the SPAD LiDAR; '' for none",
    "pose_topic": "geometry_msgs/PoseWithCovarianceStamped whose covariance the explorer reads (AMCL's amcl_pose, "
                  "slam_toolbox's pose); '' for none: the pose is exact. The pose itself always comes from tf",
    "goal_topic": "geometry_msgs/PoseStamped the goals are published on (Nav2's bt_navigator takes /goal_pose)",
    "global_frame": "the fixed frame of the map and the goals",
    "robot_base_frame": "the robot's frame: the goals' orientation is the base's heading toward them (explore_lite's "
                        "name)",
    "planner": f"the planner ({', '.join(PLANNERS)})",
    "predictor": "the map predictor (lama_bp needs spad_topic; auto: lama_bp with a SPAD topic, else lama_los)",
    "profile": "the real-time profile (realtime, full)",
    "resolution": "the explorer's cell size in metres; 0: the SLAM map's where the models serve it, else the nearest "
                  "they do (0.05 for a 0.0504 m map, resampled onto the explorer's cells; 0.1 without a map)",
    "initial_size": "the side in metres of the explorer's first grid around the robot; the grid grows as it needs",
    "usable_range": "metres: returns beyond it and no-return readings (inf, range_max and above) clear free space only "
                    "up to it and never lower a wall (GMapping's maxUrange, slam_toolbox's max_laser_range)",
    "range_sigma": "metres: the LiDAR's range noise (its calibration; 0: exact), which places each return's wall",
    "integrate_scans": "between two SLAM maps the explorer also integrates the scans itself (a fresher map), else it "
                       "reads the SLAM map alone",
    "progress_timeout": "seconds without progress toward a goal before it is blacklisted (explore_lite's name); "
                        "0: never",
    "min_frontier_size": "metres: frontier regions smaller than this never keep the exploration alive "
                         "(explore_lite's name: there, they are never goals)",
    "finish_after": "seconds without a reachable frontier of min_frontier_size before the exploration is finished",
    "return_to_init": "once finished, drive back to the start before saying done (explore_lite's name)",
    "bounds": "the exploration polygon [x1, y1, x2, y2, ...] in metres of global_frame; [] for none",
    "transform_tolerance": "seconds a scan waits for the transform at its stamp before it is dropped "
                           "(explore_lite's name)",
    "scan_timeout": "seconds without a scan after which the status says so",
    "map_timeout": "seconds without a new SLAM map after which the status says so",
    "spad_sync": "seconds between a scan's and a SPAD frame's stamps for them to form one step",
    "visualize": "publish the frontiers (visualization_msgs/MarkerArray) and the prediction (explore_lite's name)",
    "prediction_period": "seconds between two publications of the prediction (nav_msgs/OccupancyGrid, 0-100)",
    "status_period": "seconds between two status messages when no step publishes one",
    "record": "an MCAP file to record every step to ('' for none): superex replay reruns it",
    "cores": "the cores the explorer may use; 0: the process's CPU affinity",
    "use_sim_time": "take the time from /clock (a simulation), else the system clock",
    "seed": "seed of the planner's random generator",
}
"""What each parameter means (also the ``--print-params`` comments)."""


@dataclass(frozen=True)
class NodeParams(JsonConfig):
    """The node's parameters (see :data:`PARAM_DOCS` for each; metres and seconds).

    Raises:
        ValueError: a value of the wrong type or out of range, an odd-length or bad ``bounds``, an unknown QoS name.
    """

    costmap_topic: str = "/map"
    map_durability: str = "transient_local"
    scan_topic: str = "/scan"
    spad_topic: str = ""
    pose_topic: str = ""
    goal_topic: str = "/goal_pose"
    global_frame: str = "map"
    robot_base_frame: str = "base_link"
    planner: str = "superex"
    predictor: str = "auto"
    profile: str = "realtime"
    resolution: float = 0.0
    initial_size: float = 20.0
    usable_range: float = 20.0
    range_sigma: float = 0.0
    integrate_scans: bool = True
    progress_timeout: float = 30.0
    min_frontier_size: float = 0.5
    finish_after: float = 5.0
    return_to_init: bool = False
    bounds: tuple = ()
    transform_tolerance: float = 0.3
    scan_timeout: float = 1.0
    map_timeout: float = 30.0
    spad_sync: float = 0.05
    visualize: bool = True
    prediction_period: float = 1.0
    status_period: float = 1.0
    record: str = ""
    cores: int = 0
    use_sim_time: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "str" and not isinstance(value, str):
                raise ValueError(f"parameter {f.name} must be a string, got {value!r}")
            if f.type == "bool" and not isinstance(value, bool):
                raise ValueError(f"parameter {f.name} must be true or false, got {value!r}")
        for name in ("resolution", "progress_timeout", "min_frontier_size", "finish_after", "transform_tolerance",
                     "prediction_period", "spad_sync", "range_sigma"):
            object.__setattr__(self, name, check_real(f"parameter {name}", getattr(self, name), 0.0))
        for name in ("initial_size", "scan_timeout", "map_timeout", "status_period", "usable_range"):
            object.__setattr__(self, name, check_real(f"parameter {name}", getattr(self, name), 0.0, low_open=True))
        object.__setattr__(self, "cores", check_int("parameter cores", self.cores, 0))
        object.__setattr__(self, "seed", check_int("parameter seed", self.seed, 0))
        if self.map_durability not in ("transient_local", "volatile"):
            raise ValueError(f"parameter map_durability must be transient_local or volatile, got "
                             f"{self.map_durability!r}")
        object.__setattr__(self, "bounds", _bounds(self.bounds))
        if not self.scan_topic:
            raise ValueError("parameter scan_topic must name the LaserScan topic: the explorer steps on every scan")
        self.exploration_config()  # every setting the explorer refuses is refused now

    @property
    def predictor_name(self) -> str:
        """The predictor the node runs (``auto`` resolved: lama_bp with a SPAD topic, else lama_los)."""
        if self.predictor == "auto":
            return "lama_bp" if self.spad_topic else "lama_los"
        return self.predictor

    def motion(self):
        """The explorer's :class:`~superex_deploy.onboard.planning.motion.MotionConfig`: the defaults, but goals and
        paths only on space the line-of-sight map holds free (``drive_carved`` False): the robot's navigator plans
        on SLAM's map and its own costmap, where space free only by SPAD carving is unknown."""
        from superex_deploy.onboard.planning.motion import MotionConfig

        return MotionConfig(drive_carved=False)

    def exploration_config(self, base=None):
        """The explorer's :class:`~superex_deploy.onboard.config.ExplorerConfig`: ``base`` (the profile's; default
        the explorer's defaults) with the node's motion (:meth:`motion`), the LiDAR's usable range and range
        sigma, the grid growing, the finish rule, the progress timeout, the return and the bounds of these
        parameters."""
        from superex_deploy.onboard.config import ExplorerConfig
        from superex_deploy.onboard.mapping.growth import MapGrowth

        base = base or ExplorerConfig()
        policy = dataclasses.replace(base.goal_policy, no_progress_s=self.progress_timeout or None)
        motion = dataclasses.replace(base.motion, drive_carved=False)
        occupancy = dataclasses.replace(base.occupancy, usable_range_m=self.usable_range, range_sigma_m=self.range_sigma)
        return dataclasses.replace(base, motion=motion, occupancy=occupancy, growth=MapGrowth(),
                                   finish_after_s=self.finish_after,
                                   finish_frontier_m=self.min_frontier_size, return_to_start=self.return_to_init,
                                   bounds=self.bounds or None, goal_policy=policy)

    @property
    def explorer(self):
        """:meth:`exploration_config` with the explorer's defaults."""
        return self.exploration_config()

    def to_yaml(self, node_name: str = "superex_node") -> str:
        """A ROS 2 params file with every parameter at its value, each with its meaning as a comment."""
        lines = [f"{node_name}:", "  ros__parameters:"]
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool):
                text = "true" if value else "false"
            elif isinstance(value, str):
                text = f'"{value}"'
            elif isinstance(value, tuple):
                text = "[" + ", ".join(f"{v:g}" for point in value for v in point) + "]"
            else:
                text = f"{value!r}"
            lines.append(f"    # {PARAM_DOCS[f.name]}")
            lines.append(f"    {f.name}: {text}")
        return "\n".join(lines) + "\n"


def _bounds(value) -> tuple:
    """``bounds`` as a tuple of (x, y) pairs: a flat list ``[x1, y1, x2, y2, ...]`` (a ROS 2 double array) or pairs."""
    if value is None or (hasattr(value, "__len__") and len(value) == 0):
        return ()
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise ValueError(f"parameter bounds must be a list [x1, y1, x2, y2, ...] of metres, got {value!r}")
    items = list(value)
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
        if len(items) % 2:
            raise ValueError(f"parameter bounds must hold pairs of numbers [x1, y1, x2, y2, ...], got {len(items)} "
                             f"numbers")
        items = [(items[i], items[i + 1]) for i in range(0, len(items), 2)]
    points = []
    for i, point in enumerate(items):
        try:
            x, y = point
            x, y = float(x), float(y)
        except (TypeError, ValueError):
            raise ValueError(f"parameter bounds point {i} must be two numbers, got {point!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"parameter bounds point {i} must be finite, got {point!r}")
        points.append((x, y))
    return tuple(points)


def load_params(path, node_name: str = "superex_node", **overrides) -> NodeParams:
    """The :class:`NodeParams` of a ROS 2 params file (``node_name:`` or ``/**:``, then ``ros__parameters:``; the
    node's own section wins over ``/**``), then ``overrides`` (command-line values; None: not given).

    Raises:
        ValueError: a file that does not exist or is not such a YAML file, an unknown parameter (named, with the
            known ones), a bad value.
    """
    import yaml

    values: dict = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"no such params file: {path}")
        try:
            document = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as error:
            raise ValueError(f"{path} is not a YAML file: {error}") from None
        if not isinstance(document, dict):
            raise ValueError(f"{path}: a ROS 2 params file maps node names to {{ros__parameters: ...}}")
        found = False
        for key in ("/**", node_name, "/" + node_name.lstrip("/")):
            section = document.get(key)
            if section is None:
                continue
            if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
                raise ValueError(f"{path}: the section {key!r} must hold a ros__parameters mapping")
            values.update(section["ros__parameters"])
            found = True
        if not found:
            raise ValueError(f"{path} has no section for the node {node_name!r} (nor /**); it has "
                             f"{', '.join(map(str, document)) or 'none'}")
    values.update({k: v for k, v in overrides.items() if v is not None})
    known = {f.name for f in fields(NodeParams)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; the node takes "
                         f"{', '.join(sorted(known))}")
    for name in ("resolution", "progress_timeout", "min_frontier_size", "finish_after", "transform_tolerance",
                 "initial_size", "scan_timeout", "map_timeout", "status_period", "prediction_period", "spad_sync",
                 "usable_range", "range_sigma"):
        if isinstance(values.get(name), int) and not isinstance(values.get(name), bool):
            values[name] = float(values[name])  # YAML's 30 for 30.0, as ROS 2 would refuse but users write
    return NodeParams(**values)
