"""A simulated robot as a ROS 2 robot presents itself to an exploration node: a LiDAR (and optionally a SPAD)
publishing scans at their rate, a SLAM stand-in publishing the map every few seconds and the ``map -> odom ->
base_link -> laser`` transforms at 20-50 Hz, a goal follower that takes goals as Nav2's navigator takes
``/goal_pose``, and a clock. The simulator owns the truth; what leaves this module is what a robot's drivers,
SLAM and navigation stack publish.

:class:`SimulatedRobot` advances in ticks of ``1 / tf_hz`` seconds of simulated time (:meth:`SimulatedRobot.tick`):

1. the follower drives ``speed_m_s / tf_hz`` metres along its path (planned, as Nav2's planner server plans, on
   the SLAM stand-in's current map from where the localisation says the robot is, again every ``replan_s`` and
   whenever the path is blocked);
2. the localisation's pose is sampled (:meth:`~superex_deploy.sim.world.World.believe`: the truth, or the truth
   plus the pose-noise model's error) and published as ``odom -> base_link`` (``map -> odom`` is the identity);
3. on every ``tf_hz / scan_hz``-th tick the LiDAR (and the SPAD) scan from the true pose; the SLAM stand-in
   integrates the scan at the true pose (an ideal SLAM: its map is what the robot has seen, exactly);
4. every ``map_period_s`` the SLAM stand-in publishes its map (``nav_msgs/OccupancyGrid`` values: -1, 0, 100),
   cropped to its known cells plus ``map_margin_m`` on the floor's lattice, as slam_toolbox grows its map.

A goal is aborted with probability ``goal_failure_rate`` when it arrives (a navigation failure: the robot stops),
and when no path reaches it. The robot is a point in the grid for the truth (the world's collision rule) and a disc
of ``MotionConfig.robot_radius_m`` for the follower's planning.

:func:`run_in_process` runs the exploration node's core (:class:`~superex_deploy.ros.core.ExplorationCore`) on these
events in one process, synchronously, every scan stepping the explorer: the reference the node over DDS
(``superex robot-sim`` + ``superex node``) is compared with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import LaserScan, MapFrame, OccupancyGridMessage, Pose2D, PoseCovariance, SpadFrame
from superex_deploy.onboard.checks import check_real
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.frontiers import Pockets, find_frontiers, open_frontiers
from superex_deploy.onboard.planning.motion import MotionConfig, path_is_clear, planning_map
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.sim.noise.model import SimNoise
from superex_deploy.sim.world import LidarConfig, World, WorldConfig
from superex_deploy.spad_types import SpadConfig

__all__ = ["RobotSimConfig", "TfSample", "RobotTick", "GoalFollower", "SimulatedRobot", "RobotRun", "run_in_process",
           "MAP_FRAME", "ODOM_FRAME", "BASE_FRAME", "LASER_FRAME"]

MAP_FRAME, ODOM_FRAME, BASE_FRAME, LASER_FRAME = "map", "odom", "base_link", "laser"


@dataclass(frozen=True)
class RobotSimConfig(JsonConfig):
    """The simulated robot's sensors, SLAM stand-in and navigation, in seconds and metres.

    Attributes:
        scan_hz: LiDAR (and SPAD) frames per second of simulated time.
        tf_hz: transforms per second (20-50 Hz as SLAM packages and odometry publish them); a whole multiple of
            ``scan_hz``.
        map_period_s: the SLAM stand-in publishes its map every this many seconds (slam_toolbox's
            ``map_update_interval``, 5 s); the first map with the first scan.
        speed_m_s: the follower's speed along its path.
        replan_s: the follower plans its path again this often (Nav2's navigator replans at 1 Hz).
        goal_tolerance_m: the follower stops within this distance of its goal (Nav2's ``xy_goal_tolerance``).
        goal_failure_rate: the chance that a goal is aborted when it arrives (the robot then stands still until the
            next goal), in ``[0, 1]``.
        lidar: the line-of-sight LiDAR.
        spad: the SPAD sensor model, or None (no SPAD frames).
        noise: the localisation error and the LiDAR's noise (:class:`~superex_deploy.sim.noise.model.SimNoise`;
            its ``spad`` budget is applied to ``spad`` by whoever makes it: :meth:`SimNoise.sensing`).
        map_margin_m: unknown space kept around the published map's known cells.
        seed: seed of the sensors' noise and of the goal failures.
    """

    scan_hz: float = 10.0
    tf_hz: float = 20.0
    map_period_s: float = 5.0
    speed_m_s: float = 0.5
    replan_s: float = 1.0
    goal_tolerance_m: float = 0.25
    goal_failure_rate: float = 0.0
    lidar: LidarConfig = field(default_factory=LidarConfig)
    spad: Optional[SpadConfig] = None
    noise: SimNoise = SimNoise()
    map_margin_m: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("scan_hz", "tf_hz", "map_period_s", "speed_m_s", "replan_s"):
            object.__setattr__(self, name, check_real(name, getattr(self, name), 0.0, low_open=True))
        object.__setattr__(self, "goal_tolerance_m", check_real("goal_tolerance_m", self.goal_tolerance_m, 0.0))
        object.__setattr__(self, "goal_failure_rate", check_real("goal_failure_rate", self.goal_failure_rate, 0.0,
                                                                 1.0))
        object.__setattr__(self, "map_margin_m", check_real("map_margin_m", self.map_margin_m, 0.0))
        if not isinstance(self.noise, SimNoise):
            raise ValueError(f"noise must be a SimNoise, got {type(self.noise).__name__}")
        ratio = self.tf_hz / self.scan_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(f"tf_hz must be a whole multiple of scan_hz, got {self.tf_hz} and {self.scan_hz}")

    @property
    def ticks_per_scan(self) -> int:
        """Ticks (transforms) per scan."""
        return int(round(self.tf_hz / self.scan_hz))


@dataclass(frozen=True)
class TfSample:
    """One planar transform: ``child``'s pose in ``parent`` at ``stamp_s`` (metres, radians)."""

    stamp_s: float
    parent: str
    child: str
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class RobotTick:
    """What the robot published during one tick (stamped ``stamp_s``, seconds of simulated time).

    Attributes:
        stamp_s: the tick's time.
        transforms: the dynamic transforms (``map -> odom``, ``odom -> base_link``).
        scan: the LiDAR scan (in ``laser``), or None on a tick without one.
        spad: the SPAD frame taken with it, or None.
        covariance: the localisation's covariance at the scan (a ``PoseWithCovarianceStamped``'s), or None.
        slam_map: the SLAM stand-in's map when it published one this tick, else None.
    """

    stamp_s: float
    transforms: tuple
    scan: Optional[LaserScan] = None
    spad: Optional[SpadFrame] = None
    covariance: Optional[PoseCovariance] = None
    slam_map: Optional[OccupancyGridMessage] = None


def slam_codes(mapper: Mapper) -> np.ndarray:
    """int8 ``[H, W]`` the SLAM stand-in's map as UNKNOWN / FREE / OCCUPIED codes (what it has seen)."""
    return mapper.observed(include_carved=False)


class GoalFollower:
    """Drives to the latest goal as Nav2 does with ``/goal_pose``: a least-cost path on the current map from the
    localisation's pose, planned again every ``replan_s`` and when blocked, followed at ``speed_m_s``.

    Attributes:
        goal_xy: the goal (map-frame metres), or None (standing still).
        aborted: goals given up (no path, or a drawn failure).
        reached: goals reached (within ``goal_tolerance_m``).
        goals: goals received.
    """

    def __init__(self, cfg: RobotSimConfig, frame: MapFrame, motion: MotionConfig = MotionConfig()):
        self.cfg, self.frame, self.motion = cfg, frame, motion
        self.goal_xy: Optional[tuple[float, float]] = None
        self._path_xy = np.zeros((0, 2))
        self._path_rc: list = []
        self._planned_at = -math.inf
        self._rng = np.random.default_rng([cfg.seed, 0x6E6176])  # "nav"
        self.aborted = self.reached = self.goals = 0

    def set_goal(self, x: float, y: float) -> None:
        """A new goal (``geometry_msgs/PoseStamped`` position): planned at the next tick; aborted at once with
        probability ``goal_failure_rate``."""
        self.goals += 1
        if self._rng.random() < self.cfg.goal_failure_rate:
            self.aborted += 1
            self.goal_xy = None
            return
        self.goal_xy = (float(x), float(y))
        self._planned_at = -math.inf

    def path(self, observed: np.ndarray, belief: Pose2D, stamp_s: float) -> np.ndarray:
        """float ``[N, 2]`` the waypoints to drive along from ``belief`` (the first one) on the map ``observed``
        (UNKNOWN / FREE / OCCUPIED codes on the floor's frame); empty when standing still."""
        if self.goal_xy is None:
            return np.zeros((0, 2))
        if math.hypot(self.goal_xy[0] - belief.x, self.goal_xy[1] - belief.y) <= self.cfg.goal_tolerance_m:
            self.reached += 1
            self.goal_xy = None
            return np.zeros((0, 2))
        pose = self.frame.cell_of(belief.x, belief.y)
        if not self.frame.contains(pose):
            return np.zeros((0, 2))
        stale = stamp_s - self._planned_at >= self.cfg.replan_s
        if pose in self._path_rc:
            self._path_rc = self._path_rc[self._path_rc.index(pose):]
        else:
            stale = True
        if stale or not path_is_clear(observed, self._path_rc[1:], self.motion.robot_radius_m
                                      / self.frame.resolution_m):
            goal = self.frame.cell_of(*self.goal_xy)
            self._path_rc = planning_map(observed, pose, self.frame.resolution_m, self.motion).path_to(goal) \
                if self.frame.contains(goal) else []
            self._planned_at = stamp_s
            if not self._path_rc:
                self.aborted += 1
                self.goal_xy = None
                return np.zeros((0, 2))
        waypoints = self.frame.centres_xy(np.asarray(self._path_rc[1:], np.int64).reshape(-1, 2))
        return np.vstack([[belief.x, belief.y], waypoints, [self.goal_xy]])


class SimulatedRobot:
    """The simulated robot (see the module docstring).

    Args:
        grid: the ground truth.
        start_rc: the start cell (free, in the valid area).
        cfg: sensors, SLAM stand-in, navigation.

    Attributes:
        world: the :class:`~superex_deploy.sim.world.World` (the truth, the sensors).
        slam: the SLAM stand-in's :class:`~superex_deploy.onboard.mapping.mapper.Mapper` (every scan, at the true
            pose).
        follower: the :class:`GoalFollower`.
        stamp_s: the time of the latest tick (seconds of simulated time; -1 tick before the first).
        ticks, scans: ticks and scans so far.
        map_stamps: the stamps at which a map was published.
    """

    def __init__(self, grid: OccupancyGrid, start_rc, cfg: RobotSimConfig = RobotSimConfig(),
                 motion: MotionConfig = MotionConfig()):
        if not isinstance(cfg, RobotSimConfig):
            raise ValueError(f"cfg must be a RobotSimConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self.world = World(grid, start_rc, WorldConfig(lidar=cfg.lidar, spad=cfg.spad, seed=cfg.seed,
                                                       step_s=1.0 / cfg.scan_hz, noise=cfg.noise))
        self.slam = Mapper(grid.shape)
        self.follower = GoalFollower(cfg, self.world.frame, motion)
        self.ticks = self.scans = 0
        self.stamp_s = -1.0 / cfg.tf_hz
        self.map_stamps: list[float] = []
        self._next_map_s = 0.0
        self._reachable: Optional[np.ndarray] = None
        self._stood = np.zeros(grid.shape, bool)  # the cells the robot has stood in (the truth)

    @property
    def frame(self) -> MapFrame:
        """The floor's map frame (origin at its lower-left corner)."""
        return self.world.frame

    def static_transforms(self) -> tuple[TfSample, ...]:
        """The static transforms (``/tf_static``): the laser at ``base_link``'s origin."""
        return (TfSample(0.0, BASE_FRAME, LASER_FRAME, 0.0, 0.0, 0.0),)

    def coverage(self) -> float:
        """The share of the floor's valid area the robot has seen (the SLAM stand-in's known cells)."""
        return self.world.coverage(self.slam.known(include_carved=False))

    def tick(self) -> RobotTick:
        """Advance one tick of ``1 / tf_hz`` seconds (see the module docstring) and return what was published."""
        cfg = self.cfg
        self.stamp_s = self.ticks / cfg.tf_hz
        if self.ticks > 0:
            belief = self.world.belief or self.world.pose
            path = self.follower.path(slam_codes(self.slam), belief, self.stamp_s)
            if len(path):
                self.world.drive(path, cfg.speed_m_s / cfg.tf_hz)
        self._stood[self.world.pose_rc] = True
        belief, covariance = self.world.believe()
        transforms = (TfSample(self.stamp_s, MAP_FRAME, ODOM_FRAME, 0.0, 0.0, 0.0),
                      TfSample(self.stamp_s, ODOM_FRAME, BASE_FRAME, belief.x, belief.y, belief.yaw))
        scan = spad = slam_map = None
        if self.ticks % cfg.ticks_per_scan == 0:
            truth = self.world.pose
            observation = self.world.observe()
            self.world.belief = belief  # observe() drew another belief for its own observation: keep the tick's
            scan, spad = observation.scan, observation.spad
            self.slam.integrate_scan(self.frame, truth, scan)
            self.scans += 1
            if self.stamp_s >= self._next_map_s - 1e-9:
                slam_map = self.slam_message(self.stamp_s)
                self.map_stamps.append(self.stamp_s)
                self._next_map_s = self.stamp_s + cfg.map_period_s
        self.ticks += 1
        return RobotTick(self.stamp_s, transforms, scan, spad, covariance, slam_map)

    def slam_message(self, stamp_s: float) -> OccupancyGridMessage:
        """The SLAM stand-in's map as published: -1 / 0 / 100, cropped to the known cells plus ``map_margin_m``
        (whole cells of the floor's lattice), stamped ``stamp_s``."""
        codes = slam_codes(self.slam)
        percent = np.where(codes == UNKNOWN, -1, np.where(codes == OCCUPIED, 100, 0)).astype(np.int8)
        rows, cols = np.flatnonzero((codes != UNKNOWN).any(axis=1)), np.flatnonzero((codes != UNKNOWN).any(axis=0))
        frame = self.frame
        margin = int(math.ceil(self.cfg.map_margin_m / frame.resolution_m))
        if rows.size == 0:
            r0, r1, c0, c1 = 0, 1, 0, 1
        else:
            r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, frame.shape[0])
            c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, frame.shape[1])
        crop = MapFrame((r1 - r0, c1 - c0), frame.resolution_m,
                        (frame.origin_xy[0] + c0 * frame.resolution_m,
                         frame.origin_xy[1] + (frame.shape[0] - r1) * frame.resolution_m))
        message = OccupancyGridMessage.from_frame_grid(crop, percent[r0:r1, c0:c1])
        return OccupancyGridMessage(message.resolution_m, message.width, message.height, message.origin_xy,
                                    message.data, stamp_s=stamp_s)

    def frontier_left(self, min_m: float, visit_m: float = 0.4) -> bool:
        """Whether the SLAM stand-in's current map (every scan, exact: no staleness) holds a frontier the node's
        finish rule counts (:mod:`superex_deploy.onboard.finishing`): a region of at least ``min_m`` metres that
        borders unknown space a robot could enter and has a cell a path reaches from the robot's true cell (the
        explorer's planning rules), and whose goal cell the robot has not stood within ``visit_m`` of (a frontier
        still there after that, the node gives up as one no viewpoint resolves). The truth against which the node's
        ``finished`` is judged."""
        from scipy import ndimage

        codes, res = slam_codes(self.slam), self.frame.resolution_m
        regions = [f for f in find_frontiers(codes, 1) if f.size * res >= min_m - 1e-9]
        if not regions:
            return False
        stood = ndimage.distance_transform_edt(~self._stood) * res <= visit_m
        regions = [f for f in regions if not stood[f.cell_rc]]
        regions = open_frontiers(tuple(regions), Pockets(codes, self.follower.motion.robot_radius_m, res))
        if not regions:
            return False
        plan = planning_map(codes, self.world.pose_rc, res, self.follower.motion)
        return any(np.isfinite(plan.travel_cost[f.cells[:, 0], f.cells[:, 1]]).any() for f in regions)

    def unseen_reachable_m2(self) -> float:
        """The area (square metres) of the largest connected part (8-connected) of the floor that the robot could
        drive into from its start (the truth, walls grown by the robot's radius) and that its SLAM map has not seen:
        what was really left to explore (the node cannot know a passage is too narrow before it sees it)."""
        from scipy import ndimage

        if self._reachable is None:
            truth = np.where(self.world.grid.occupied, OCCUPIED, FREE).astype(np.int8)
            plan = planning_map(truth, self.world.pose_rc, self.frame.resolution_m, self.follower.motion)
            self._reachable = np.isfinite(plan.travel_cost) & self.world.grid.valid
        unseen = self._reachable & ~self.slam.known(include_carved=False)
        labels, count = ndimage.label(unseen, structure=np.ones((3, 3), bool))
        if count == 0:
            return 0.0
        return float(np.bincount(labels.ravel())[1:].max()) * self.frame.resolution_m ** 2


@dataclass
class RobotRun:
    """A run of the simulated robot under an exploration node.

    Attributes:
        stamps_s: float64 ``[T]`` the scans' stamps (seconds of simulated time).
        coverage: float64 ``[T]`` the share of the valid area seen after each scan.
        finished_s: the stamp at which the node first said ``finished``, or None.
        frontier_gone_s: the stamp from which on the SLAM stand-in's map held no frontier the node's finish rule
            counts (:class:`RunLog`; None: one was left at the end).
        unseen_at_finish_m2: the largest part of the floor the robot could drive into and had not seen when the
            node said ``finished`` (square metres), or None.
        goals: ``[(stamp_s, x, y), ...]`` the goals the node sent.
        goals_in_walls: goals sent on a true wall cell (or off the floor).
        follower: the follower's counters (goals, reached, aborted).
        collisions: moves a wall stopped.
        statuses: ``[(stamp_s, status, reason), ...]`` each change of the node's status.
    """

    stamps_s: np.ndarray
    coverage: np.ndarray
    finished_s: Optional[float]
    frontier_gone_s: Optional[float]
    unseen_at_finish_m2: Optional[float]
    goals: list
    goals_in_walls: int
    follower: dict
    collisions: int
    statuses: list

    def to_json(self) -> dict:
        """JSON values of every field."""
        return {"stamps_s": np.round(self.stamps_s, 6).tolist(), "coverage": np.round(self.coverage, 6).tolist(),
                "finished_s": self.finished_s, "frontier_gone_s": self.frontier_gone_s,
                "unseen_at_finish_m2": self.unseen_at_finish_m2,
                "goals": [list(g) for g in self.goals], "goals_in_walls": self.goals_in_walls,
                "follower": self.follower, "collisions": self.collisions,
                "statuses": [list(s) for s in self.statuses]}


class RunLog:
    """What a run of the simulated robot records as it goes (shared by :func:`run_in_process` and the robot-sim
    over DDS): coverage per scan, the goals and whether they lie in walls, the node's status changes, when the node
    said ``finished``, and when the last reachable frontier went: from when on, checked every ``check_every_s`` (0:
    never; a search over the whole floor, a second at 0.05 m on the largest eval floor),
    the SLAM stand-in's map held no frontier the node's finish rule counts (:meth:`SimulatedRobot.frontier_left`,
    regions of ``finish_frontier_m``, the node's ``min_frontier_size``); with the largest part of the floor the
    robot could drive into and had not seen, when ``finished`` came (:meth:`SimulatedRobot.unseen_reachable_m2`)."""

    def __init__(self, robot: SimulatedRobot, finish_frontier_m: float, check_every_s: float = 0.5):
        self.robot, self.check_every_s, self.finish_frontier_m = robot, check_every_s, finish_frontier_m
        self.stamps, self.coverage, self.goals, self.statuses = [], [], [], []
        self.in_walls = 0
        self.finished_s: Optional[float] = None
        self.gone_s: Optional[float] = None
        self.unseen_at_finish_m2: Optional[float] = None
        self._checked_s = -math.inf

    def scanned(self, stamp_s: float) -> None:
        """A scan was taken at ``stamp_s``: record the coverage and, every ``check_every_s`` (a search over the
        floor), whether a reachable frontier is left."""
        self.stamps.append(stamp_s)
        self.coverage.append(self.robot.coverage())
        if not self.check_every_s or stamp_s - self._checked_s < self.check_every_s - 1e-9:
            return
        self._checked_s = stamp_s
        if self.robot.frontier_left(self.finish_frontier_m):
            self.gone_s = None
        elif self.gone_s is None:
            self.gone_s = stamp_s

    def goal(self, stamp_s: float, x: float, y: float) -> None:
        """The node sent the goal ``(x, y)`` at ``stamp_s``: the follower takes it."""
        self.goals.append((stamp_s, x, y))
        cell = self.robot.frame.cell_of(x, y)
        if not self.robot.frame.contains(cell) or self.robot.world.grid.occupied[cell]:
            self.in_walls += 1
        self.robot.follower.set_goal(x, y)

    def status(self, stamp_s: float, status: str, reason: str, finished: bool) -> None:
        """The node's status at ``stamp_s``: changes are kept, the first ``finished`` timed."""
        if not self.statuses or self.statuses[-1][1:] != (status, reason):
            self.statuses.append((stamp_s, status, reason))
        if finished and self.finished_s is None:
            self.finished_s = stamp_s
            self.unseen_at_finish_m2 = self.robot.unseen_reachable_m2()

    def result(self) -> RobotRun:
        """The :class:`RobotRun` so far."""
        follower = self.robot.follower
        return RobotRun(stamps_s=np.asarray(self.stamps, np.float64), coverage=np.asarray(self.coverage, np.float64),
                        finished_s=self.finished_s, frontier_gone_s=self.gone_s,
                        unseen_at_finish_m2=self.unseen_at_finish_m2, goals=list(self.goals),
                        goals_in_walls=self.in_walls,
                        follower={"goals": follower.goals, "reached": follower.reached, "aborted": follower.aborted},
                        collisions=self.robot.world.collisions, statuses=list(self.statuses))


def run_in_process(grid: OccupancyGrid, start_rc, core, cfg: RobotSimConfig = RobotSimConfig(),
                   duration_s: float = 300.0, stop_when_finished: bool = True,
                   on_tick: Optional[Callable] = None, judge_every_s: float = 0.5) -> RobotRun:
    """Run the exploration node's core ``core`` (:class:`~superex_deploy.ros.core.ExplorationCore`) on the
    simulated robot in one process for ``duration_s`` seconds of simulated time: every tick's transforms, scans and
    maps go to the core as the node's subscriptions would hand them over, the core steps the explorer on every scan,
    and each goal it sends goes to the follower. Stops once the core says ``finished`` (``stop_when_finished``);
    ``judge_every_s`` is the log's check for frontiers left (:class:`RunLog`; 0: never).

    Returns:
        The :class:`RobotRun`.
    """
    robot = SimulatedRobot(grid, start_rc, cfg, core.params.motion())
    log = RunLog(robot, core.params.explorer.finish_frontier_m, judge_every_s)
    for sample in robot.static_transforms():
        core.add_planar_transform(sample, static=True)
    while robot.stamp_s + 1.0 / cfg.tf_hz <= duration_s + 1e-9:
        tick = robot.tick()
        for sample in tick.transforms:
            core.add_planar_transform(sample)
        if tick.slam_map is not None:
            core.add_map(tick.slam_map)
        if tick.scan is None:
            continue
        log.scanned(tick.stamp_s)
        core.add_scan(tick.stamp_s, LASER_FRAME, tick.scan, tick.spad, covariance=tick.covariance)
        outputs = core.step(tick.stamp_s)
        if outputs is not None:
            if outputs.goal_changed and outputs.command.goal_xy is not None:
                log.goal(tick.stamp_s, *outputs.command.goal_xy)
            log.status(tick.stamp_s, outputs.state, outputs.reason, outputs.command.finished)
        if on_tick is not None:
            on_tick(robot, tick, outputs)
        if stop_when_finished and log.finished_s is not None:
            break
    return log.result()
