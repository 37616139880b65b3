"""``superex node``: the exploration node a ROS 2 robot runs, on DDS, without a ROS install.

It subscribes what explore_lite / m-explore-ros2 and Nav2 users have on their robot and publishes the goals Nav2's
navigator takes (topics relative to the node's namespace; QoS from :mod:`superex_deploy.ros.qos`):

========================== ======================================== ===========================================
topic                      type                                     QoS
========================== ======================================== ===========================================
``costmap_topic`` (/map)   ``nav_msgs/OccupancyGrid`` in            reliable, transient local (``map_durability``)
``scan_topic`` (/scan)     ``sensor_msgs/LaserScan`` in             best effort (sensor data), the newest kept
``/tf``, ``/tf_static``    ``tf2_msgs/TFMessage`` in                tf2's listener QoS
``spad_topic``             ``superex_msgs/SpadFrame`` in            best effort
``pose_topic``             ``geometry_msgs/PoseWithCovarianceStamped`` in  best effort (its covariance is read)
``/clock``                 ``rosgraph_msgs/Clock`` in               best effort (``use_sim_time``)
``goal_topic`` (/goal_pose) ``geometry_msgs/PoseStamped`` out        reliable, volatile (when the goal changes)
``superex/path``           ``nav_msgs/Path`` out                    reliable, volatile (every step)
``superex/prediction``     ``nav_msgs/OccupancyGrid`` out (0-100)   reliable, transient local (every
                                                                    ``prediction_period``)
``superex/frontiers``      ``visualization_msgs/MarkerArray`` out   reliable, volatile (``visualize``)
``superex/status``         ``superex_msgs/ExplorerStatus`` out      reliable, volatile (every step and every
                                                                    ``status_period``)
``superex/pause``,         ``std_msgs/Empty`` in                    reliable: operator commands
``superex/resume``,
``superex/return_to_start``
``superex/bounds``         ``geometry_msgs/PolygonStamped`` in      reliable: the exploration polygon (empty:
                                                                    none), as frontier_exploration takes it
========================== ======================================== ===========================================

**The loop** runs on its own thread (:meth:`ExplorationNode.start`) and is the only code that touches the
explorer: it waits on the subscriptions (a DDS wait set: no callback, nothing ever runs in a DDS thread), takes what
arrived (every transform, the newest map, the newest scan: older scans are dropped, never queued), steps the
:class:`~superex_deploy.ros.core.ExplorationCore` and publishes. Its latency, from a scan's arrival to the
publication of its step's goal, is measured every step (``latency_s`` in the status; percentiles in
``DIR/summary.json`` with ``--out``). A missing or stale map, transform or scan is a state with a reason in the
status, never a crash or a silent stop. With ``record`` every step goes to an MCAP file ``superex replay`` reruns.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import asdict
from pathlib import Path
from typing import Optional

import numpy as np

from superex_deploy.messages.ros_fields import occupancy_grid, laser_scan, pose_covariance, spad_frame, stamp_seconds
from superex_deploy.ros import idl, outputs, qos
from superex_deploy.ros.core import ExplorationCore
from superex_deploy.ros.dds import RosParticipant
from superex_deploy.ros.node_status import StepOutputs
from superex_deploy.ros.params import NodeParams

__all__ = ["ExplorationNode"]


class ExplorationNode:
    """The exploration node (see the module docstring); a context manager that stops it.

    Args:
        params: the node's parameters.
        node_name, namespace: the ROS node name and namespace (topics resolve under the namespace).
        domain_id: the DDS domain (None: ``ROS_DOMAIN_ID``, default 0).
        config: a Cyclone DDS XML configuration (:func:`~superex_deploy.ros.dds.loopback_config` on one machine).
        models: folder of exported models (default: the installed ones).

    Attributes:
        core: the :class:`~superex_deploy.ros.core.ExplorationCore`, warmed up (:meth:`~superex_deploy.ros.core.
            ExplorationCore.warm_up`: the models loaded, the kernels compiled) before the node subscribes.
        warm_up_s: the seconds that took.
        latencies_s: every step's latency (scan received -> its outputs published), seconds.
        steps: steps run; ``goals_sent``: goals published.

    Raises:
        ValueError: parameters the core refuses, a bad node name, namespace or domain.
    """

    def __init__(self, params: NodeParams = NodeParams(), node_name: str = "superex", namespace: str = "",
                 domain_id: Optional[int] = None, config: Optional[str] = None, models=None):
        self.params = params
        self.core = ExplorationCore(params, models)
        self.warm_up_s = self.core.warm_up()  # models loaded, kernels compiled: before the robot's first scan
        self.participant = RosParticipant(node_name, namespace, domain_id, config=config)
        part, p = self.participant, params
        self._scan = part.subscription(p.scan_topic, idl.LaserScan, qos.SENSOR_DATA)
        self._tf = part.subscription("/tf", idl.TFMessage, qos.TF)
        self._tf_static = part.subscription("/tf_static", idl.TFMessage, qos.TF_STATIC_LISTENER)
        self._map = part.subscription(p.costmap_topic, idl.OccupancyGrid,
                                      qos.RosQos("reliable", p.map_durability, 1)) if p.costmap_topic else None
        self._spad = part.subscription(p.spad_topic, idl.SpadFrame, qos.SENSOR_DATA) if p.spad_topic else None
        self._pose = part.subscription(p.pose_topic, idl.PoseWithCovarianceStamped,
                                       qos.RosQos("best_effort", "volatile", 5)) if p.pose_topic else None
        self._clock = part.subscription("/clock", idl.Clock, qos.CLOCK) if p.use_sim_time else None
        self._commands = {name: part.subscription(f"superex/{name}", idl.Empty, qos.DEFAULT)
                          for name in ("pause", "resume", "return_to_start")}
        self._bounds = part.subscription("superex/bounds", idl.PolygonStamped, qos.DEFAULT)
        self._goal_pub = part.publisher(p.goal_topic, idl.PoseStamped, qos.DEFAULT)
        self._path_pub = part.publisher("superex/path", idl.Path, qos.DEFAULT)
        self._prediction_pub = part.publisher("superex/prediction", idl.OccupancyGrid, qos.MAP)
        self._frontier_pub = part.publisher("superex/frontiers", idl.MarkerArray, qos.DEFAULT)
        self._status_pub = part.publisher("superex/status", idl.ExplorerStatus, qos.DEFAULT)
        self._waited = [s for s in (self._scan, self._tf, self._tf_static, self._map, self._spad, self._pose,
                                    self._clock, self._bounds, *self._commands.values()) if s is not None]
        self._sim_now: Optional[float] = None
        self._last_status_wall = -math.inf
        self._last_prediction_s = -math.inf
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._recorder = None
        self.error: Optional[BaseException] = None
        self.latencies_s: list[float] = []
        self.steps = self.goals_sent = 0
        self.finished_at_s: Optional[float] = None
        self.states: list[tuple[float, str, str]] = []

    # -- life ------------------------------------------------------------------------------------------------------

    def __enter__(self) -> "ExplorationNode":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> "ExplorationNode":
        """Run the loop on its own thread (:meth:`spin`) until :meth:`close`."""
        self._thread = threading.Thread(target=self._spin_safely, name="superex-node", daemon=True)
        self._thread.start()
        return self

    def _spin_safely(self) -> None:
        try:
            self.spin()
        except BaseException as error:  # kept for the caller (close raises it): the thread never dies silently
            self.error = error

    def spin(self, duration_s: Optional[float] = None) -> None:
        """Run the loop in this thread until :meth:`close` (or ``duration_s`` seconds of wall time)."""
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        while not self._stop.is_set() and time.monotonic() < end:
            self.participant.wait(self._waited, min(0.1, self.params.status_period))
            self.spin_once()

    def close(self) -> None:
        """Stop the loop, close the explorer, the recording and the participant. Raises the error that stopped
        the loop thread, if one did."""
        self._stop.set()
        if self._thread is not None:
            self.participant.wake()
            self._thread.join(timeout=30.0)
        if self.core.explorer is not None:
            self.core.explorer.close()
        if self._recorder is not None:
            recorder, self._recorder = self._recorder, None
            recorder.close()
        self.participant.close()
        if self.error is not None and not isinstance(self.error, KeyboardInterrupt):
            error, self.error = self.error, None
            raise error

    def now(self) -> float:
        """The node's clock (seconds): the newest ``/clock`` with ``use_sim_time`` (0 before any), else the
        system's."""
        if self.params.use_sim_time:
            return self._sim_now or 0.0
        return time.time()

    # -- one turn of the loop --------------------------------------------------------------------------------------

    def spin_once(self) -> Optional[StepOutputs]:
        """Take what arrived, step the core if a scan is ready, publish; returns the step's outputs or None."""
        core = self.core
        if self._clock is not None:
            clock = self._clock.take_newest()
            if clock is not None:
                self._sim_now = stamp_seconds(clock.clock)
        for message, _ in self._tf_static.take():
            core.add_tf_message(message, static=True)
        for message, _ in self._tf.take():
            core.add_tf_message(message)
        if self._map is not None:
            message = self._map.take_newest()
            if message is not None:
                self._take_map(message)
        if self._pose is not None:
            message = self._pose.take_newest()
            if message is not None:
                self._take_pose(message)
        if self._spad is not None:
            for message, _ in self._spad.take():
                try:
                    core.add_spad(stamp_seconds(message.header.stamp), spad_frame(message))
                except ValueError as error:
                    core.refuse("bad spad", f"a bad SPAD frame on {self.params.spad_topic}: {error}")
        received = time.perf_counter()
        for message, _ in self._scan.take():
            self._take_scan(message, received)
        self._operator()
        now = self.now()
        step = core.step(now)
        if step is not None:
            self._publish(step, now)
        if step is not None or time.monotonic() - self._last_status_wall >= self.params.status_period:
            self._publish_status(now)
        return step

    def _take_map(self, message) -> None:
        try:
            self.core.add_map(occupancy_grid(message))
        except ValueError as error:
            self.core.refuse("bad map", f"the map on {self.params.costmap_topic} is refused: {error}")

    def _take_pose(self, message) -> None:
        try:
            self.core.add_pose_covariance(stamp_seconds(message.header.stamp), pose_covariance(message.pose.covariance))
        except ValueError as error:
            self.core.refuse("bad pose", f"a bad pose on {self.params.pose_topic}: {error}")

    def _take_scan(self, message, received_s: float) -> None:
        try:
            scan = laser_scan(message)
        except ValueError as error:
            self.core.refuse("bad scan", f"a malformed scan on {self.params.scan_topic}: {error}")
            return
        self.core.add_scan(stamp_seconds(message.header.stamp), message.header.frame_id, scan, received_s=received_s)

    def _operator(self) -> None:
        commands = self._commands
        if commands["pause"].take():
            self.core.pause()
        if commands["resume"].take():
            self.core.resume()
        if commands["return_to_start"].take():
            self.core.return_to_start()
        message = self._bounds.take_newest()
        if message is not None:
            points = [(float(p.x), float(p.y)) for p in message.polygon.points]
            try:
                if message.header.frame_id and message.header.frame_id.lstrip("/") != self.params.global_frame:
                    raise ValueError(f"the polygon is in frame {message.header.frame_id!r}, the node's is "
                                     f"{self.params.global_frame!r}")
                self.core.set_bounds(points or None)
            except ValueError as error:
                self.core.refuse("bad bounds", f"the bounds on superex/bounds are refused: {error}", lasting_s=10.0)

    # -- publishing ------------------------------------------------------------------------------------------------

    def _publish(self, step: StepOutputs, now: float) -> None:
        frame_id, command = self.params.global_frame, step.command
        stamp = step.observation.stamp_s
        if step.goal_changed and command.goal_xy is not None:
            robot = (step.observation.pose.x, step.observation.pose.y)
            self._goal_pub.publish(outputs.goal_message(command.goal_xy, robot, stamp, frame_id))
            self.goals_sent += 1
        self.core.latency_s = time.perf_counter() - step.received_s
        self.latencies_s.append(self.core.latency_s)
        self.steps += 1
        if command.finished and self.finished_at_s is None:
            self.finished_at_s = stamp
        self._path_pub.publish(outputs.path_message(command.path_xy, stamp, frame_id))
        explorer = self.core.explorer
        if self.params.visualize:
            grid = explorer.planning_grid
            regions = [explorer.frame.centres_xy(grid.fine_frontier(f).cells) for f in explorer.frontiers]
            self._frontier_pub.publish(outputs.frontier_markers(regions, command.goal_xy, stamp, frame_id,
                                                                explorer.frame.resolution_m))
            if command.prediction is not None and now - self._last_prediction_s >= self.params.prediction_period:
                self._last_prediction_s = now
                self._prediction_pub.publish(outputs.prediction_message(
                    command.prediction.mean, explorer.observed, step.frame, stamp, frame_id))
        if self.params.record:
            self._record(step)

    def _publish_status(self, now: float) -> None:
        status = self.core.status(now)
        self._last_status_wall = time.monotonic()
        if not self.states or self.states[-1][1:] != (status.state, status.reason):
            self.states.append((now, status.state, status.reason))
        self._status_pub.publish(outputs.status_message(status, self.params.global_frame))

    def _record(self, step: StepOutputs) -> None:
        from superex_deploy.recording import EpisodeRecorder

        explorer = self.core.explorer
        if self._recorder is None:
            self._recorder = EpisodeRecorder(self.params.record, step.frame, self.recording_metadata())
        self._recorder.write(step.observation, step.command, explorer.observed, explorer.frame)

    def recording_metadata(self) -> dict:
        """What a replay needs to rebuild this node's explorer
        (:func:`superex_deploy.recording.metadata.recording_metadata`): the planner's whole configuration, the
        predictor, the sensing, the explorer's configuration and the profile."""
        from superex_deploy.recording.metadata import recording_metadata

        explorer, p = self.core.explorer, self.params
        spad = explorer.spad_processing
        return recording_metadata(map_name="", planner_name=p.planner, planner=explorer.planner, planner_options={},
                                  predictor=p.predictor_name, seed=p.seed,
                                  sensor=None if spad is None else spad.sensor,
                                  nlos_cfg=None if spad is None else spad.nlos_cfg, explorer_cfg=explorer.cfg,
                                  profile=p.profile, models=self.core.models)

    def summary(self) -> dict:
        """What the run did: steps, goals, latency percentiles (ms), scans received / dropped, the states the status
        went through, when ``finished`` first held (the node's clock)."""
        latencies = np.asarray(self.latencies_s) * 1e3
        percentiles = {} if not len(latencies) else {
            "mean": float(latencies.mean()), "p50": float(np.percentile(latencies, 50)),
            "p99": float(np.percentile(latencies, 99)), "max": float(latencies.max())}
        core = self.core
        return {"steps": self.steps, "goals_sent": self.goals_sent, "latency_ms": percentiles,
                "scans_received": core.scans_received, "scans_dropped": core.scans_dropped,
                "steps_skipped": core.steps_skipped, "refused": dict(core.refused),
                "finished_at_s": self.finished_at_s, "states": [list(s) for s in self.states],
                "params": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self.params).items()}}

    def write_summary(self, path) -> None:
        """Write :meth:`summary` as JSON to ``path``."""
        from superex_deploy.files import write_atomically

        write_atomically(Path(path), json.dumps(self.summary(), indent=2) + "\n")
