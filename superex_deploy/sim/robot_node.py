"""``superex robot-sim``: the simulated robot of :mod:`superex_deploy.sim.robot` on DDS, as a ROS 2 robot publishes
itself, so that ``superex node`` (or any ROS 2 exploration node) runs a closed loop on one machine.

Published (every topic a ROS 2 robot with a 2-D LiDAR, slam_toolbox and Nav2 has; QoS as those publishers'):
``/clock`` (every tick, ``rosgraph_msgs/Clock``), ``/tf`` (``map -> odom``, ``odom -> base_link`` every tick:
``tf_hz``), ``/tf_static`` (``base_link -> laser``), ``/scan`` (``sensor_msgs/LaserScan`` in ``laser``, sensor-data
QoS), ``/spad`` (``superex_msgs/SpadFrame`` with the same stamp, with a SPAD), ``/map`` (``nav_msgs/OccupancyGrid``,
reliable and transient local, every ``map_period_s``). Subscribed: ``/goal_pose`` (``geometry_msgs/PoseStamped``,
what Nav2's navigator takes; the follower drives there) and ``/superex/status`` (``superex_msgs/ExplorerStatus``:
when the node said ``finished``, for the run's log).

Time is simulated and paced at ``rate`` times the wall clock (1: real time). The stamps (and ``/clock``) count from
``epoch_s``, by default the wall clock's time at the start: at rate 1 they stay on the system clock, so a node
without ``use_sim_time`` runs on it as on a real robot; at another rate give the node ``use_sim_time``. With ``--out`` the run's log (coverage per scan of the truth, goals,
goals in walls, the node's status changes, when ``finished`` came against when the last reachable frontier went)
is written as JSON (:class:`~superex_deploy.sim.robot.RobotRun`).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Optional

from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages.ros_fields import stamp_seconds
from superex_deploy.ros import idl, outputs, qos
from superex_deploy.ros.dds import RosParticipant
from superex_deploy.sim.robot import LASER_FRAME, RobotRun, RobotSimConfig, RunLog, SimulatedRobot

__all__ = ["SimulatedRobotNode"]


class SimulatedRobotNode:
    """The simulated robot on DDS (see the module docstring); a context manager that closes its participant.

    Args:
        grid: the ground truth.
        start_rc: the start cell.
        cfg: the robot's sensors, SLAM stand-in and follower.
        finish_frontier_m: the frontier size the node's ``finished`` is judged against (its ``min_frontier_size``).
        namespace, domain_id, config: as :class:`~superex_deploy.ros.dds.RosParticipant` takes them.
        goal_topic, status_topic: where the goals come from and the node's status.
        epoch_s: the stamp of simulated time 0 (seconds; None: the wall clock's now, whole seconds).
        judge_every_s: how often (simulated seconds) the log checks whether a reachable frontier is left
            (:class:`~superex_deploy.sim.robot.RunLog`; 0: never).
    """

    def __init__(self, grid: OccupancyGrid, start_rc, cfg: RobotSimConfig = RobotSimConfig(),
                 finish_frontier_m: float = 0.5, namespace: str = "", domain_id: Optional[int] = None,
                 config: Optional[str] = None, goal_topic: str = "/goal_pose",
                 status_topic: str = "/superex/status", epoch_s: Optional[float] = None, judge_every_s: float = 0.5):
        self.epoch_s = float(math.floor(time.time()) if epoch_s is None else epoch_s)
        self.robot = SimulatedRobot(grid, start_rc, cfg)
        self.log = RunLog(self.robot, finish_frontier_m, judge_every_s)
        self.participant = part = RosParticipant("robot_sim", namespace, domain_id, config=config)
        self._clock = part.publisher("/clock", idl.Clock, qos.CLOCK)
        self._tf = part.publisher("/tf", idl.TFMessage, qos.TF)
        self._tf_static = part.publisher("/tf_static", idl.TFMessage, qos.TF_STATIC)
        self._scan = part.publisher("/scan", idl.LaserScan, qos.SENSOR_DATA)
        self._spad = part.publisher("/spad", idl.SpadFrame, qos.SENSOR_DATA) if cfg.spad is not None else None
        self._map = part.publisher("/map", idl.OccupancyGrid, qos.MAP)
        self._goals = part.subscription(goal_topic, idl.PoseStamped, qos.DEFAULT)
        self._status = part.subscription(status_topic, idl.ExplorerStatus, qos.DEFAULT)
        self._tf_static.publish(outputs.tf_message(self._stamped(self.robot.static_transforms())))

    def __enter__(self) -> "SimulatedRobotNode":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the participant (the topics go)."""
        self.participant.close()

    def wait_for_node(self, timeout_s: float = 30.0) -> bool:
        """Wait (wall time) until a reader of ``/scan`` and a writer of the goals have matched and the node has said
        its status once: it is up, its models loaded (as a robot's launch waits for its nodes to be ready)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self._scan.matched_subscriptions() and self._goals.matched_publishers() and self._status.take():
                return True
            time.sleep(0.05)
        return False

    def run(self, duration_s: float, rate: float = 1.0, stop_when_finished: bool = True,
            hold_s: float = 1.0, progress=None) -> RobotRun:
        """Run ``duration_s`` seconds of simulated time paced at ``rate`` times real time (until the node says
        ``finished``, then ``hold_s`` more, with ``stop_when_finished``); ``progress(stamp_s)`` after each scan.

        Raises:
            ValueError: a non-positive rate or duration.
        """
        if not (rate > 0 and math.isfinite(rate)) or not (duration_s > 0 and math.isfinite(duration_s)):
            raise ValueError(f"rate and duration must be positive, got {rate} and {duration_s}")
        robot, cfg = self.robot, self.robot.cfg
        start = time.monotonic()
        finished_wall = None
        while robot.stamp_s + 1.0 / cfg.tf_hz <= duration_s + 1e-9:
            tick = robot.tick()
            stamp, wire = tick.stamp_s, tick.stamp_s + self.epoch_s
            self._clock.publish(outputs.clock_message(wire))
            self._tf.publish(outputs.tf_message(self._stamped(tick.transforms)))
            if tick.slam_map is not None:
                self._map.publish(outputs.grid_message(replace(tick.slam_map, stamp_s=wire), "map"))
            if tick.scan is not None:
                self.log.scanned(stamp)
                self._scan.publish(outputs.scan_message(tick.scan, wire, LASER_FRAME, 1.0 / cfg.scan_hz))
                if self._spad is not None and tick.spad is not None:
                    self._spad.publish(outputs.spad_message(tick.spad, wire, LASER_FRAME))
                if progress is not None:
                    progress(stamp)
            self._listen(stamp)
            if stop_when_finished and self.log.finished_s is not None:
                finished_wall = finished_wall or time.monotonic()
                if time.monotonic() - finished_wall >= hold_s:
                    break
            delay = start + (stamp + 1.0 / cfg.tf_hz) / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        self._listen(robot.stamp_s)
        return self.log.result()

    def _stamped(self, samples) -> list:
        """The transforms with their stamps on the wire's clock (``epoch_s`` added)."""
        return [replace(sample, stamp_s=sample.stamp_s + self.epoch_s) for sample in samples]

    def _listen(self, stamp_s: float) -> None:
        for message, _ in self._goals.take():
            self.log.goal(stamp_s, float(message.pose.position.x), float(message.pose.position.y))
        for message, _ in self._status.take():
            self.log.status(stamp_seconds(message.header.stamp) - self.epoch_s, message.state, message.reason,
                            message.finished)
