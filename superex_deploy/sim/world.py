"""The simulated world: the ground-truth grid, the robot in it, its sensors, and the metrics only the truth allows.

The world owns the truth; the explorer (:mod:`superex_deploy.onboard`) sees only the
:class:`~superex_deploy.messages.Observation` that :meth:`World.observe` produces. By default (the paper's protocol)
the simulated robot is holonomic and moves on grid cells; its pose is the centre of its cell with yaw 0 (the
scanners are aligned with the map frame), and the observations carry it exactly.

Imperfection, all off by default (:class:`WorldConfig`'s ``noise``, a :class:`~superex_deploy.sim.noise.model.SimNoise`):

* ``noise.pose`` (:class:`~superex_deploy.sim.noise.pose.PoseNoise`): the observation's pose is the truth plus a
  localisation error and carries its covariance; the robot then moves continuously (:mod:`.kinematics`: position
  off the cell centres, heading along the direction of travel) and follows each command from where it believes it
  is. The scans are cast from the true pose.
* ``noise.lidar`` (:class:`~superex_deploy.sim.noise.lidar.LidarNoise`): range noise, dropouts, spurious returns.
* The SPAD's photon noise is the sensor's own (``noise.spad`` names its budget for the episode's sensing) (:class:`~superex_deploy.spad_types.SpadNoise`, presets in
  :data:`~superex_deploy.spad_types.SPAD_PRESETS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.geometry import cast_rays
from superex_deploy.maps import OccupancyGrid
from superex_deploy.maps import coverage as coverage_of
from superex_deploy.onboard.checks import cells_within, check_real
from superex_deploy.messages import Command, LaserScan, MapFrame, Observation, Pose2D, SpadFrame, grid_angles
from superex_deploy.spad_types import SpadConfig, SpadScan
from superex_deploy.sim.kinematics import drive_belief_relative
from superex_deploy.sim.noise.lidar import noisy_ranges
from superex_deploy.sim.noise.model import SimNoise
from superex_deploy.sim.noise.pose import PoseErrorModel
from superex_deploy.sim.spad import measured_frame, simulate_scan

__all__ = ["World", "WorldConfig", "LidarConfig", "laser_scan_from_distances", "advance"]


@dataclass(frozen=True)
class LidarConfig(JsonConfig):
    """The simulated robot's line-of-sight 2-D LiDAR (MapEx ``lidar_sim_configs``: 2500 rays over a full turn, 20 m).

    Attributes:
        n_rays: rays per scan, evenly spaced over 360 degrees starting along the robot's heading.
        range_m: maximum range (metres); walls beyond it give no return.
    """

    n_rays: int = 2500
    range_m: float = 20.0

    def __post_init__(self) -> None:
        if int(self.n_rays) < 1 or not (float(self.range_m) > 0.0 and np.isfinite(self.range_m)):
            raise ValueError(f"LidarConfig needs n_rays >= 1 and a positive finite range_m, got n_rays="
                             f"{self.n_rays}, range_m={self.range_m}")


@dataclass(frozen=True)
class WorldConfig(JsonConfig):
    """The simulated robot's sensors and motion.

    Attributes:
        lidar: the line-of-sight LiDAR (rays over a full turn, maximum range).
        spad: the SPAD LiDAR, or None (no SPAD frames).
        step_m: how far the robot drives per :meth:`World.apply` (metres, > 0; MapEx: 3 cells of 0.1 m): along a
            path of cells, the most cells that fit in it (:attr:`World.step_cells`, at least one).
        seed: seed of the SPAD noise generator (used only when ``spad.noise.enabled``).
        step_s: simulated time per step (seconds; the observations' time stamps).
        noise: the simulator's noise (:class:`~superex_deploy.sim.noise.model.SimNoise`): ``noise.pose`` the
            localisation error (None: the observations carry the true pose, and the robot moves from cell centre to
            cell centre; with it the robot moves continuously and drives ``World.step_cells * resolution`` metres
            per step), ``noise.lidar`` the LiDAR's noise (None: exact ranges). Its ``spad`` part is the sensing's
            (``spad`` here is the sensor model as the sensing made it).
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    spad: Optional[SpadConfig] = None
    step_m: float = 0.3
    seed: int = 0
    step_s: float = 0.1
    noise: SimNoise = SimNoise()

    def __post_init__(self) -> None:
        if not isinstance(self.lidar, LidarConfig):
            raise ValueError(f"lidar must be a LidarConfig, got {type(self.lidar).__name__}")
        if self.spad is not None and not isinstance(self.spad, SpadConfig):
            raise ValueError(f"spad must be a SpadConfig or None, got {type(self.spad).__name__}")
        object.__setattr__(self, "step_m", check_real("step_m", self.step_m, 0.0, low_open=True))
        object.__setattr__(self, "step_s", check_real("step_s", self.step_s, 0.0, low_open=True))
        if not isinstance(self.noise, SimNoise):
            raise ValueError(f"noise must be a SimNoise, got {type(self.noise).__name__}")


def _float32_at_least(values_m: np.ndarray) -> np.ndarray:
    """float32 of each value, rounded up where rounding to nearest went below (a range never shrinks)."""
    rounded = values_m.astype(np.float32)
    low = rounded.astype(np.float64) < values_m
    rounded[low] = np.nextafter(rounded[low], np.float32(np.inf))
    return rounded


def laser_scan_from_distances(distances_cells: np.ndarray, hit: np.ndarray, resolution_m: float,
                              angle_min: float, angle_increment: float, range_max_m: float) -> LaserScan:
    """The :class:`LaserScan` of simulated first hits: a ray that hit a wall returns the distance to the wall's
    face, the others (range or grid border reached) return ``inf``.

    Args:
        distances_cells: float64 ``[N]`` distance to each hit (cells).
        hit: bool ``[N]`` rays that hit a wall.
        resolution_m: metres per cell.
        angle_min, angle_increment, range_max_m: the scan's fields (float32 precision).
    """
    ranges = np.full(distances_cells.shape, np.inf, np.float32)
    ranges[hit] = _float32_at_least(distances_cells[hit] * resolution_m)
    return LaserScan(angle_min=angle_min, angle_increment=angle_increment, range_min=0.0, range_max=range_max_m,
                     ranges=ranges)


def advance(path: list[tuple[int, int]], step_cells: int, resolution_m: float
            ) -> tuple[tuple[int, int], list[tuple[int, int]], float]:
    """Move the simulated robot along a path (the world's kinematics: :meth:`World.apply` drives with it).

    Args:
        path: cells from the robot's cell (``path[0]``) to the goal, 8-connected.
        step_cells: cells to advance (fewer if the path ends sooner).
        resolution_m: metres per cell.

    Returns:
        ``(new cell, remaining path starting at the new cell, metres driven)``.
    """
    if not path:
        raise ValueError("cannot advance along an empty path")
    steps = min(int(step_cells), len(path) - 1)
    driven = sum(float(np.hypot(b[0] - a[0], b[1] - a[1])) for a, b in zip(path[:steps], path[1:steps + 1]))
    return path[steps], path[steps:], driven * float(resolution_m)


class World:
    """The ground truth and the robot.

    Args:
        grid: the ground-truth map.
        start_rc: the robot's start cell (row, col): inside the map, in its valid area, not a wall.
        cfg: sensors and motion.

    Attributes:
        grid, cfg: as given.
        frame: the map frame the observations use (the grid's shape and resolution, origin at (0, 0)).
        pose_rc: the robot's cell (setting it puts the robot at the cell's centre).
        step_cells: path cells per :meth:`apply`: the most that fit in ``cfg.step_m`` on this grid, at least one.
        driven_m: metres driven so far.
        steps: observations produced so far.
        collisions: commanded moves stopped by a wall (or the map's edge).
        belief: the pose the last observation carried (None before the first).
        pose_error: the running localisation error (:class:`~superex_deploy.sim.noise.pose.PoseErrorModel`), or
            None without pose noise.
    """

    def __init__(self, grid: OccupancyGrid, start_rc, cfg: WorldConfig = WorldConfig()):
        if not isinstance(grid, OccupancyGrid):
            raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
        if not isinstance(cfg, WorldConfig):
            raise ValueError(f"cfg must be a WorldConfig, got {type(cfg).__name__}")
        start = grid.check_pose(start_rc)
        if not grid.valid[start]:
            raise ValueError(f"start cell {start} lies outside the valid (inside-the-building) area of map "
                             f"{grid.name!r}: nothing there could be explored")
        self.grid, self.cfg = grid, cfg
        self.frame = MapFrame(grid.shape, grid.resolution_m)
        self.pose_rc = start
        self.step_cells = max(1, cells_within(cfg.step_m, grid.resolution_m))
        self.belief: Optional[Pose2D] = None
        self.pose_error = None if cfg.noise.pose is None else PoseErrorModel(cfg.noise.pose)
        self._lidar_rng = None if cfg.noise.lidar is None else cfg.noise.lidar.generator()
        self.driven_m = 0.0
        self.steps = 0
        self.collisions = 0
        n = cfg.lidar.n_rays
        # Stored at float32 precision, as LaserScan holds them; the rays are cast along exactly these angles.
        self._angle_increment = float(np.float32(2.0 * np.pi / n))
        template = LaserScan(0.0, self._angle_increment, 0.0, cfg.lidar.range_m, np.zeros(n, np.float32))
        self._scan_angles = template.angles()
        self._range_max = template.range_max
        self._spad_rng: Optional[np.random.Generator] = None
        self.last_spad_scan: Optional[SpadScan] = None

    @property
    def pose_rc(self) -> tuple[int, int]:
        """The robot's cell ``(row, col)``."""
        return self._pose_rc

    @pose_rc.setter
    def pose_rc(self, rc) -> None:
        self._pose_rc = (int(rc[0]), int(rc[1]))
        self._true_pose: Optional[Pose2D] = None  # None: the cell's centre, yaw 0

    @property
    def pose(self) -> Pose2D:
        """The robot's true pose in the map frame: the centre of its cell, yaw 0 (with pose noise, where its
        continuous motion took it)."""
        if self._true_pose is not None:
            return self._true_pose
        x, y = self.frame.centre_xy(self.pose_rc)
        return Pose2D(x, y, 0.0)

    def _scan(self, pose: Pose2D, origin) -> LaserScan:
        resolution = self.grid.resolution_m
        hits = cast_rays(self.grid.occupied, origin, grid_angles(pose.yaw, self._scan_angles),
                         self._range_max / resolution)
        noise = self.cfg.noise.lidar
        if noise is None:
            return laser_scan_from_distances(hits.distance_cells, hits.hit_mask, resolution, 0.0,
                                             self._angle_increment, self._range_max)
        exact = np.where(hits.hit_mask, hits.distance_cells * resolution, np.inf)
        return LaserScan(angle_min=0.0, angle_increment=self._angle_increment, range_min=noise.range_min_m,
                         range_max=self._range_max, ranges=noisy_ranges(exact, noise, self._range_max, self._lidar_rng))

    def _spad_frame(self, pose: Pose2D, origin) -> SpadFrame:
        if self._spad_rng is None:
            self._spad_rng = np.random.default_rng(self.cfg.seed)
        continuous = self._true_pose is not None
        simulated = simulate_scan(self.grid, self.pose_rc, self.cfg.spad,
                                  rng=self._spad_rng if self.cfg.spad.noise.enabled else None,
                                  origin_yx=origin if continuous else None)
        self.last_spad_scan = simulated  # the truth stays here: labels and tests only
        return measured_frame(simulated, pose.yaw if continuous else 0.0)

    def observe(self) -> Observation:
        """Scan from the robot's true pose: the line-of-sight ranges and, with a SPAD sensor, its frame; the
        observation carries the pose the robot believes it has (the truth without pose noise)."""
        pose = self.pose
        origin, _ = self.frame.locate(pose.x, pose.y)
        scan = self._scan(pose, origin)
        spad = None if self.cfg.spad is None else self._spad_frame(pose, origin)
        belief, covariance = pose, None
        if self.pose_error is not None:
            belief, covariance = self.pose_error.believe(pose), self.pose_error.covariance()
        self.belief = belief
        observation = Observation(stamp_s=self.steps * self.cfg.step_s, pose=belief, scan=scan, spad=spad,
                                  pose_covariance=covariance)
        self.steps += 1
        return observation

    def apply(self, command: Command) -> float:
        """Drive up to :attr:`step_cells` cells (``cfg.step_m``) along the commanded path; returns the metres driven.

        Without pose noise the path must start at the robot's cell and step between 8-connected cells; a move into
        a wall is refused (the robot stops before it and :attr:`collisions` counts it). With pose noise the robot
        follows the path from the pose it believes it has (see :mod:`superex_deploy.sim.kinematics`), up to
        ``step_cells * resolution`` metres; a wall stops it and counts, and no path is refused. A command without a
        path leaves the robot where it is.

        Raises:
            ValueError: not a Command; without pose noise, a path that does not start at the robot's cell or that
                skips cells.
        """
        if not isinstance(command, Command):
            raise ValueError(f"apply() takes a Command, got {type(command).__name__}")
        path_xy = np.asarray(command.path_xy, np.float64).reshape(-1, 2)
        if len(path_xy) == 0:
            return 0.0
        if self.pose_error is not None:
            return self.drive(path_xy, self.step_cells * self.grid.resolution_m)
        path = [self.frame.cell_of(x, y) for x, y in path_xy]
        if path[0] != self.pose_rc:
            raise ValueError(f"the commanded path starts at cell {path[0]}, the robot is at {self.pose_rc}")
        steps = [max(abs(b[0] - a[0]), abs(b[1] - a[1])) for a, b in zip(path, path[1:])]
        if any(step != 1 for step in steps):
            raise ValueError("the commanded path must step between 8-connected neighbouring cells")
        free = 1
        while free < len(path) and free <= self.step_cells and self.grid.is_free(path[free]):
            free += 1
        if free <= min(self.step_cells, len(path) - 1):
            self.collisions += 1  # the next cell is a wall or off the map
        pose, _, metres = advance(path[:free], self.step_cells, self.grid.resolution_m)
        self.pose_rc = (int(pose[0]), int(pose[1]))
        self.driven_m += metres
        return metres

    def drive(self, path_xy, budget_m: float) -> float:
        """Drive continuously up to ``budget_m`` metres along the float ``[N, 2]`` map-frame waypoints ``path_xy``
        (the first one where the robot believes it is), relative to its belief as
        :func:`~superex_deploy.sim.kinematics.drive_belief_relative` does (the truth without pose noise); the pose
        leaves the cell centres from then on. A wall stops it and counts as a collision. Returns the metres driven.

        Raises:
            ValueError: a non-finite waypoint or budget, a negative budget.
        """
        path_xy = np.asarray(path_xy, np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(path_xy)):
            raise ValueError("the commanded path holds a non-finite waypoint")
        budget_m = check_real("budget_m", budget_m, 0.0)
        truth = self.pose
        drive = drive_belief_relative(self.grid, truth, self.belief or truth, path_xy, budget_m)
        self.pose_rc = self.frame.cell_of(drive.pose.x, drive.pose.y)
        self._true_pose = drive.pose
        self.collisions += int(drive.collided)
        self.driven_m += drive.metres
        if self.pose_error is not None:
            self.pose_error.drive(drive.metres)
        return drive.metres

    def believe(self) -> tuple[Pose2D, Optional[object]]:
        """The pose the robot's localisation reports now and its covariance (the truth and None without pose
        noise; with it a fresh draw of the error model), kept as :attr:`belief`."""
        truth = self.pose
        if self.pose_error is None:
            self.belief = truth
            return truth, None
        self.belief = self.pose_error.believe(truth)
        return self.belief, self.pose_error.covariance()

    def coverage(self, known: np.ndarray) -> float:
        """Known share of the valid area for a bool ``[H, W]`` map of known cells (the explorer's)."""
        return coverage_of(np.asarray(known, bool), self.grid.valid)
