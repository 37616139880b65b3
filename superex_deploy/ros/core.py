"""The exploration node without its transport: what ``superex node`` does with the messages its subscriptions hand
over, step by step, in one class (:class:`ExplorationCore`) that the DDS node (:mod:`superex_deploy.ros.node`) and
the in-process reference run (:func:`superex_deploy.sim.robot.run_in_process`) share, so that both run the same
pipeline.

Inputs (any thread may add them; one lock guards the core):

* transforms (``/tf``, ``/tf_static``) into a :class:`~superex_deploy.ros.tf.TfBuffer`;
* the SLAM map (the newest is kept; a map is *new* until a step has read it);
* scans: only the **newest** is kept (a scan that arrives before the previous one was stepped replaces it and is
  counted as dropped: a node that falls behind skips scans, it never queues them); a scan stamped 0 (a driver
  without a clock) or before the previous step's stamp is refused and counted;
* SPAD frames, paired with the scan of the same stamp (within ``spad_sync``);
* the pose topic's covariance (the newest, at most ``transform_tolerance`` older than the scan).

:meth:`ExplorationCore.step` turns the pending scan into an
:class:`~superex_deploy.messages.Observation` and steps the explorer:

* the scan's pose is its frame's pose in ``global_frame`` at its stamp (tf, interpolated as tf2 does); a scan
  whose transform has not arrived yet waits up to ``transform_tolerance`` (a tf2 message filter), then is dropped
  with the reason; a laser mounted upside down (roll pi) is mirrored, any other tilted mount refused with its frame;
* with ``integrate_scans`` the SLAM map is handed to the explorer when a new one has arrived, and the scans are
  integrated in between (a fresher map between two SLAM maps); without, the latest map every step;
* the explorer is built at the first usable scan: a grid of ``initial_size`` around the robot on the SLAM map's
  lattice, at ``resolution`` (0: the map's), growing as the map and the scans need.

A missing or stale input is a state with a reason (``waiting_for_input``: no map yet, no transform at the scan's
stamp, a non-planar mount, no scan for ``scan_timeout``, a clock that does not advance), never an exception or a
silent stop. Operator commands: :meth:`~ExplorationCore.pause` / :meth:`~ExplorationCore.resume`,
:meth:`~ExplorationCore.return_to_start`, :meth:`~ExplorationCore.set_bounds`.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.messages import (LaserScan, MapFrame, Observation, OccupancyGridMessage, Pose2D, PoseCovariance,
                                     SpadFrame)
from superex_deploy.ros.node_status import PAUSED, WAITING_FOR_INPUT, NodeStatus, StepOutputs
from superex_deploy.ros.params import NodeParams
from superex_deploy.ros.rigid import Transform, planar
from superex_deploy.ros.tf import ExtrapolationError, TfBuffer, TransformError

__all__ = ["ExplorationCore"]


@dataclass
class _Scan:
    stamp_s: float
    frame_id: str
    scan: LaserScan
    spad: Optional[SpadFrame]
    covariance: Optional[PoseCovariance]
    received_s: float


class ExplorationCore:
    """The node's inputs, explorer and state (see the module docstring).

    Args:
        params: the node's :class:`~superex_deploy.ros.params.NodeParams`.
        models: folder of exported models (default: the installed ones).

    Attributes:
        params: as given.
        tf: the :class:`~superex_deploy.ros.tf.TfBuffer`.
        explorer: the :class:`~superex_deploy.onboard.explorer.Explorer`, built at the first usable scan (None
            before).
        paused: the operator paused the exploration.
        latency_s: the latest step's latency (set by the node when it publishes).
    """

    def __init__(self, params: NodeParams = NodeParams(), models=None):
        from superex_deploy.pipeline import PROFILES, check_profile
        from superex_deploy.onboard.planning.planners import make_planner
        from superex_deploy.onboard.prediction.registry import kind_of

        if not isinstance(params, NodeParams):
            raise ValueError(f"params must be NodeParams, got {type(params).__name__}")
        self.params, self.models = params, models
        self._planner = make_planner(params.planner)
        check_profile(params.profile, self._planner, params.predictor_name)
        if kind_of(params.predictor_name).reads_evidence and not params.spad_topic:
            raise ValueError(f"the {params.predictor_name} predictor reads the SPAD evidence: set spad_topic (or "
                             f"predictor: lama_los)")
        self._cfg = params.exploration_config(PROFILES[params.profile].explorer_config("robot"))
        self.tf = TfBuffer(cache_s=10.0)
        self.explorer = None
        self.paused = False
        self.latency_s = math.nan
        self._lock = threading.RLock()
        self._scan: Optional[_Scan] = None
        self._spads: list[tuple[float, SpadFrame]] = []
        self._covariance: Optional[tuple[float, PoseCovariance]] = None
        self._map: Optional[OccupancyGridMessage] = None
        self._map_new = False
        self._map_stamp = math.nan
        self._last_stamp = -math.inf
        self._last_scan_stamp = math.nan
        self._sent_goal: Optional[tuple[float, float]] = None
        self._problem = ""  # why the latest attempt to step failed, until a step succeeds
        self._latest: Optional[StepOutputs] = None
        self._bounds_pending = None
        self._home_pending = False
        self.scans_received = self.scans_dropped = self.steps_skipped = 0
        self.refused: dict[str, int] = {}
        self._predictor_made = None
        self._notice: Optional[tuple] = None  # (reason, seconds, the node's clock when first said)

    # -- inputs --------------------------------------------------------------------------------------------------

    def add_tf_message(self, message, static: bool = False) -> int:
        """A ``tf2_msgs/TFMessage`` (of ``/tf``, or ``/tf_static`` with ``static``); returns the transforms kept."""
        return self.tf.add_message(message, static)

    def add_transform(self, parent: str, child: str, stamp_s: float, transform: Transform,
                      static: bool = False) -> None:
        """One transform (a :class:`~superex_deploy.ros.rigid.Transform` of ``child`` in ``parent``)."""
        self.tf.add(parent, child, stamp_s, transform, static)

    def add_planar_transform(self, sample, static: bool = False) -> None:
        """One planar transform with ``stamp_s``, ``parent``, ``child``, ``x``, ``y``, ``yaw`` (a simulated robot's
        :class:`~superex_deploy.sim.robot.TfSample`)."""
        self.tf.add(sample.parent, sample.child, sample.stamp_s, Transform.from_planar(sample.x, sample.y, sample.yaw),
                    static)

    def add_map(self, grid: OccupancyGridMessage) -> None:
        """The SLAM map (the newest is kept)."""
        if not isinstance(grid, OccupancyGridMessage):
            raise ValueError(f"the map must be an OccupancyGridMessage, got {type(grid).__name__}")
        with self._lock:
            self._map, self._map_new = grid, True
            self._map_stamp = grid.stamp_s if grid.stamp_s is not None else math.nan

    def add_scan(self, stamp_s: float, frame_id: str, scan: LaserScan, spad: Optional[SpadFrame] = None,
                 covariance: Optional[PoseCovariance] = None, received_s: Optional[float] = None) -> bool:
        """A scan (and optionally its SPAD frame and pose covariance): kept as the newest, replacing one not stepped
        yet (counted as dropped). Returns False for a scan refused: stamped 0 (a driver without a clock) or before
        the latest step (counted in :attr:`refused`)."""
        with self._lock:
            self.scans_received += 1
            self._last_scan_stamp = stamp_s
            if stamp_s <= 0.0:
                return self._refuse("stamp 0", f"scans stamped 0 on {self.params.scan_topic} (a driver without a "
                                               f"clock): a scan's pose is looked up at its stamp")
            if stamp_s < self._last_stamp:
                return self._refuse("backwards", f"a scan stamped {stamp_s:.3f} s, before the latest step's "
                                                 f"{self._last_stamp:.3f} s (a looping bag or a restarted /clock: "
                                                 f"restart the node to explore anew)")
            if self._scan is not None:
                self.scans_dropped += 1
            self._scan = _Scan(stamp_s, frame_id, scan, spad, covariance,
                               time.perf_counter() if received_s is None else received_s)
            return True

    def add_spad(self, stamp_s: float, spad: SpadFrame) -> None:
        """A SPAD frame, paired with the scan of its stamp (within ``spad_sync``)."""
        with self._lock:
            self._spads = [(s, f) for s, f in self._spads if s > stamp_s - 1.0] + [(stamp_s, spad)]

    def add_pose_covariance(self, stamp_s: float, covariance: Optional[PoseCovariance]) -> None:
        """The pose topic's covariance at ``stamp_s`` (the newest is kept)."""
        with self._lock:
            self._covariance = None if covariance is None else (stamp_s, covariance)

    def _refuse(self, kind: str, reason: str) -> bool:
        self.refuse(kind, reason)
        self.scans_dropped += 1
        return False

    def refuse(self, kind: str, reason: str, lasting_s: float = 0.0) -> None:
        """An input was refused (a malformed scan, a bad map or pose, an operator's polygon): counted under
        ``kind`` in :attr:`refused`; ``reason`` is the status's until a step succeeds, or with ``lasting_s`` added
        to the status's reason for that long (seconds of the node's clock from the latest status: an operator's
        refused command must be seen)."""
        with self._lock:
            self.refused[kind] = self.refused.get(kind, 0) + 1
            if lasting_s > 0.0:
                self._notice = (reason, lasting_s, None)
            else:
                self._problem = reason

    # -- operator ------------------------------------------------------------------------------------------------

    def pause(self) -> None:
        """Pause: no step runs (scans are dropped), no goal is sent, until :meth:`resume`."""
        with self._lock:
            self.paused = True

    def resume(self) -> None:
        """Resume after :meth:`pause`."""
        with self._lock:
            self.paused = False

    def return_to_start(self) -> None:
        """Drive back to the start now (:meth:`~superex_deploy.onboard.explorer.Explorer.return_to_start`)."""
        with self._lock:
            if self.explorer is None:
                self._home_pending = True
            else:
                self.explorer.return_to_start()

    def set_bounds(self, points) -> None:
        """Bound the exploration to the polygon ``points`` (``(x, y)`` metres in ``global_frame``), or None / empty
        for none (:meth:`~superex_deploy.onboard.explorer.Explorer.set_bounds`).

        Raises:
            ValueError: a polygon the explorer refuses (named).
        """
        from superex_deploy.onboard.planning.bounds import ExplorationBounds

        bounds = ExplorationBounds(tuple(points)) if points is not None and len(points) else None
        if bounds is not None:
            bounds.check_holds(self._cfg.motion.robot_radius_m)
        with self._lock:
            if self.explorer is None:
                self._bounds_pending = (bounds,)
            else:
                self.explorer.set_bounds(bounds)

    # -- stepping ------------------------------------------------------------------------------------------------

    def step(self, now_s: float) -> Optional[StepOutputs]:
        """Step the explorer on the pending scan, if any and if its inputs are there (see the module docstring);
        ``now_s`` is the node's clock (seconds: the scan's transform is waited for until ``now_s`` passes its stamp
        by ``transform_tolerance``). Returns None when no step ran."""
        with self._lock:
            pending = self._scan
            if pending is None:
                return None
            if self.paused:
                self._scan = None
                self.steps_skipped += 1
                return None
            pose = self._pose(pending, now_s)
            if pose is None:
                return None
            self._scan = None
            if self.params.costmap_topic and self._map is None:
                self._problem = f"no map on {self.params.costmap_topic} yet"
                self.steps_skipped += 1
                return None
            (x, y, yaw), mirrored = pose
            scan = pending.scan.mirrored() if mirrored else pending.scan
            return self._run(pending, Pose2D(x, y, yaw), scan)

    def _pose(self, pending: _Scan, now_s: float):
        """The scan frame's planar pose in the global frame at its stamp and whether it is mirrored, or None (the
        transform is awaited, or missing: the scan is then dropped and the reason kept)."""
        frame = self.params.global_frame
        try:
            transform = self.tf.lookup(frame, pending.frame_id, pending.stamp_s)
        except ExtrapolationError as error:
            if now_s - pending.stamp_s < self.params.transform_tolerance:
                return None  # its /tf may still come
            self._drop(f"no transform {frame} -> {pending.frame_id} at the scan's stamp {pending.stamp_s:.3f} s "
                       f"after {self.params.transform_tolerance:g} s: {error}")
            return None
        except TransformError as error:
            if now_s - pending.stamp_s < self.params.transform_tolerance:
                return None
            self._drop(f"no transform {frame} -> {pending.frame_id}: {error}")
            return None
        try:
            x, y, yaw, mirrored = planar(transform, pending.frame_id)
        except ValueError as error:
            self._drop(str(error))
            return None
        return (x, y, yaw), mirrored

    def _drop(self, reason: str) -> None:
        self._scan = None
        self.scans_dropped += 1
        self.steps_skipped += 1
        self._problem = reason

    def _spad_for(self, stamp_s: float) -> Optional[SpadFrame]:
        best = None
        for s, frame in self._spads:
            if abs(s - stamp_s) <= self.params.spad_sync and (best is None or abs(s - stamp_s) < abs(best[0] - stamp_s)):
                best = (s, frame)
        if best is None:
            return None
        self._spads = [(s, f) for s, f in self._spads if s > best[0]]
        return best[1]

    def _predictor(self):
        """The node's predictor, made once (loading the models): the warm-up's explorer and the real one use it in
        turn."""
        if self._predictor_made is None:
            from superex_deploy.onboard.prediction.inference import available_cores
            from superex_deploy.pipeline import PROFILES, make_predictor

            self._predictor_made = make_predictor(self.params.predictor_name, models=self.models,
                                                  profile=PROFILES[self.params.profile],
                                                  cores=self.params.cores or available_cores())
        return self._predictor_made

    def _new_explorer(self, frame: MapFrame):
        from superex_deploy.onboard.prediction.inference import available_cores
        from superex_deploy.pipeline import build_explorer

        params = self.params
        return build_explorer(frame, self._planner, self._predictor(), profile=params.profile,
                              cores=params.cores or available_cores(), spad=bool(params.spad_topic) and (
                                  self._processing(params.predictor_name)), models=self.models, seed=params.seed,
                              cfg=self._cfg)

    def _processing(self, name: str):
        from superex_deploy.pipeline import PROFILES, make_processing

        return make_processing(name, models=self.models, skips=PROFILES[self.params.profile].nlos_skips)

    def warm_up(self) -> float:
        """Load the models and compile the numba kernels the steps run (cached on disk after the first time) by
        two steps of an explorer of the node's pipeline on a small synthetic map, before the robot's first scan
        waits for them; returns the seconds it took."""
        clock = time.perf_counter()
        frame = MapFrame((60, 60), 0.1, (0.0, 0.0))
        grid = np.full(frame.shape, -1, np.int8)
        grid[10:50, 10:50] = 0
        grid[9, 9:51] = grid[50, 9:51] = grid[9:51, 9] = 100
        message = OccupancyGridMessage.from_frame_grid(frame, grid)
        scan = LaserScan(0.0, 2 * math.pi / 360, 0.05, 4.0, np.full(360, 3.0, np.float32))
        explorer = self._new_explorer(frame)
        try:
            for t in (0.0, 0.1):
                explorer.step(Observation(t, Pose2D(3.0, 3.0), scan, occupancy_grid=message if t == 0.0 else None))
        finally:
            explorer.close()
        return time.perf_counter() - clock

    def _build(self, pose: Pose2D) -> None:
        from superex_deploy.onboard.prediction.scale import servable_resolution

        params = self.params
        # The SLAM map's resolution where the models serve it, else the nearest they do (0.05 m for a 0.0504 m map,
        # resampled onto the explorer's cells).
        resolution = params.resolution or (servable_resolution(self._map.resolution_m) if self._map is not None
                                           else 0.1)
        lattice = self._map.origin_xy if self._map is not None else (0.0, 0.0)
        frame = MapFrame.around(pose.x, pose.y, resolution, params.initial_size, lattice_xy=lattice)
        self.explorer = self._new_explorer(frame)
        if self._bounds_pending is not None:
            self.explorer.set_bounds(self._bounds_pending[0])
        if self._home_pending:
            self.explorer.return_to_start()

    def _run(self, pending: _Scan, pose: Pose2D, scan: LaserScan) -> Optional[StepOutputs]:
        covariance = pending.covariance
        if covariance is None and self._covariance is not None and self.params.pose_topic:
            stamp, value = self._covariance
            if abs(pending.stamp_s - stamp) <= max(self.params.transform_tolerance, 1.0):
                covariance = value
        spad = pending.spad if pending.spad is not None else (
            self._spad_for(pending.stamp_s) if self.params.spad_topic else None)
        grid = None
        if self._map is not None:
            grid = self._map if (self._map_new or not self.params.integrate_scans) else None
        try:
            observation = Observation(stamp_s=pending.stamp_s, pose=pose, scan=scan, spad=spad,
                                      pose_covariance=covariance, occupancy_grid=grid)
            if self.explorer is None:
                self._build(pose)
            command = self.explorer.step(observation)
        except ValueError as error:  # an input the explorer refuses: said, the node goes on
            self._drop(f"the explorer refused the step at {pending.stamp_s:.3f} s: {error}")
            return None
        self._map_new = False
        self._last_stamp = pending.stamp_s
        self._problem = "clock not advancing: the scans' stamps stand still" if self.explorer.clock.stalled else ""
        goal = command.goal_xy
        changed = goal is not None and (self._sent_goal is None or math.hypot(goal[0] - self._sent_goal[0],
                                                                             goal[1] - self._sent_goal[1]) > 1e-9)
        if goal is not None:
            self._sent_goal = goal
        outputs = StepOutputs(command=command, observation=observation, state=command.status, reason=command.reason,
                              goal_changed=changed, received_s=pending.received_s, frame=self.explorer.frame)
        self._latest = outputs
        return outputs

    # -- status --------------------------------------------------------------------------------------------------

    def status(self, now_s: float) -> NodeStatus:
        """The node's status at ``now_s`` (its clock): the latest step's state, or the node's own (paused, an input
        missing or stale)."""
        with self._lock:
            latest = self._latest
            state = latest.state if latest is not None else "waiting_for_scan"
            reason = latest.reason if latest is not None else "no scan yet"
            scan_age = now_s - self._last_scan_stamp if math.isfinite(self._last_scan_stamp) else math.nan
            if self.paused:
                state, reason = PAUSED, "paused by the operator"
            elif self._problem:
                state, reason = WAITING_FOR_INPUT, self._problem
            elif math.isnan(scan_age) or scan_age > self.params.scan_timeout:
                if math.isfinite(scan_age) or latest is not None:
                    state, reason = WAITING_FOR_INPUT, (f"no scan on {self.params.scan_topic} for more than "
                                                        f"{self.params.scan_timeout:g} s" if math.isfinite(scan_age)
                                                        else "no scan yet")
            elif self.params.costmap_topic and math.isfinite(self._map_stamp) and \
                    now_s - self._map_stamp > self.params.map_timeout and latest is not None:
                reason = (reason + "; " if reason else "") + (f"no new map on {self.params.costmap_topic} for "
                                                             f"more than {self.params.map_timeout:g} s")
            if self._notice is not None:
                notice, lasting, since = self._notice
                since = now_s if since is None else since
                self._notice = (notice, lasting, since) if now_s - since < lasting else None
                if self._notice is not None:
                    reason = f"{reason}; {notice}" if reason else notice
            status = NodeStatus(stamp_s=now_s, state=state, reason=reason, scans_received=self.scans_received,
                                scans_dropped=self.scans_dropped, steps_skipped=self.steps_skipped,
                                latency_s=self.latency_s, scan_age_s=scan_age,
                                map_age_s=now_s - self._map_stamp if math.isfinite(self._map_stamp) else math.nan)
            newest = self.tf.newest_stamp(self.params.robot_base_frame)
            if newest is not None and math.isfinite(newest):
                status.tf_age_s = now_s - newest
            if latest is not None:
                command, explorer = latest.command, self.explorer
                status.finished, status.goal_xy, status.step = command.finished, self._sent_goal, command.step + 1
                area = explorer.frame.resolution_m ** 2
                observed = explorer.observed
                status.known_area_m2 = float(np.count_nonzero(observed != -1)) * area
                status.free_area_m2 = float(np.count_nonzero(observed == 0)) * area
                status.frontiers = len(explorer.frontiers)
                status.prediction_age_s = math.nan if command.prediction_age_s is None else command.prediction_age_s
                status.stage_s = dict(command.timings_s)
            return status
