"""The robot's own map: a probabilistic occupancy grid in log-odds, built from measured line-of-sight scans (or
taken from a SLAM map) and, in a layer of its own, from NLOS space carving.

Line of sight (as costmap_2d's voxel layer and OctoMap keep it): each scan is walked ray by ray with the exact DDA
of :mod:`superex_deploy.geometry` (the cells a ray leaves before its return were crossed, the cell of the return
was hit: :func:`~superex_deploy.geometry.mark_ranges`); then every cell the scan touched gets **one** update, a
hit if at least as many rays returned in it as crossed it (a hit wins a tie), else a miss:
``l += hit`` or ``l += miss`` (negative), clamped to ``[lowest, highest]``. A cell is **occupied** at
``l >= occupied_threshold``, **free** at ``l <= free_threshold``, unknown in between. Clamping bounds what any
history weighs, so no cell is decided for good by one reading: a wall hit once is cleared by a few scans that see
through it, and a cell seen free becomes a wall with one hit.

The defaults (:class:`OccupancyConfig`) make the map binary on noise-free data: one miss makes an unknown cell
free, one hit makes any cell occupied (a wall wins over a free history), and a wall hit once stays occupied through
5 scans that cross it (through 8 once confirmed). On noise-free episodes no cell is ever both hit and crossed, so
the thresholded map is the plain "hit: wall, crossed: free" map.

**A noisy LiDAR.** The per-scan vote is an inverse sensor model: a spurious short return in free
space is one return against the many rays of the same scan that cross its cell, so it never becomes a wall (under the
rule "a hit wins" it would, and take 7 scans to clear); and a few rays that return in a cell they
only grazed do not outvote those that crossed it. Range noise needs one more thing: a wall's face is where the
exact ranges end, and ``N(0, sigma)`` puts half of the returns in the free cell in front of it, which then holds
as many returns as crossings and becomes a wall (walls thicken towards the robot, doorways close). With
``range_sigma_m`` set (the LiDAR's calibration) each return is placed ``range_hit_sigmas`` sigmas farther (2: 2.3 %
of the returns still fall short), and the misses stop before that cell; at ``range_sigma_m = 0`` (the default) the
ranges are taken as they are. A return placed beyond a thin wall (2.3 % of them at 2 sigmas, with 2 cm at 10 cm
cells only beyond 3 sigmas) is outvoted in the wall's cell by the returns that end there.

**Footprint clearing** (costmap_2d's): the robot's body is free space. Each step the explorer frees the known cells
under a disc of the robot radius less ``footprint_margin_sigmas`` position sigmas of the pose covariance
(:meth:`Mapper.clear_footprint`), so that a phantom under the robot (which makes every neighbour untraversable,
and no path, and the explorer "finished") is gone at once. A cell at the ``highest`` clamp (hit by at least two
scans) is kept: a pose error can put a true wall under the believed footprint, and a wall seen twice is safer
kept than driven through. Unknown cells stay unknown. In the noise-free protocol the cells under the robot are
known free already (the robot starts and moves clear of walls), so no class changes. The disc is the cells whose
centre lies within the radius (``<=``) of a position anywhere in a cell; ``skimage.draw.disk`` keeps only those
strictly inside, and drew 138 of 3000 random footprints differently, by cells at exactly the radius
(``benchmarks/skimage``).

**SLAM map.** :meth:`Mapper.set_line_of_sight` replaces the line-of-sight layer by a published map
(``nav_msgs/OccupancyGrid`` percentages, thresholded as costmap_2d does: occupied at or above
``slam_occupied_percent``, free at or below ``slam_free_percent``).

**Carving** enters as evidence, in a layer of its own so coverage can be reported with and without it: each
carving pushes a cell's carving log-odds down by ``carve_step``, to at most ``carve_lowest`` in all. A carved cell
counts as free when the line-of-sight log-odds plus the carving log-odds reach the free threshold, and never where
the line of sight holds a wall (``l >= occupied_threshold``).
"""

from __future__ import annotations

import threading
from typing import Optional

import numpy as np

from superex_deploy.messages import LaserScan, MapFrame, Pose2D, PoseCovariance, grid_angles
from superex_deploy.onboard.mapping.blocks import coarsen_observed
from superex_deploy.onboard.mapping.log_odds import OccupancyConfig, integrate_log_odds
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

__all__ = ["Mapper"]


class Mapper:
    """Observed map over a grid of shape ``[H, W]`` (``[row, col]``), in log-odds (see the module docstring).

    Args:
        shape: ``(rows, cols)``.
        cfg: the log-odds parameters.

    Attributes:
        cfg: as given.

    The masks below are derived from the two layers (:attr:`log_odds`, :attr:`carve_log_odds`) and are fresh
    arrays at each read; the map keeps its classes and derives them again only where a write changed them since.
    """

    def __init__(self, shape: tuple[int, int], cfg: OccupancyConfig = OccupancyConfig()):
        shape = tuple(int(n) for n in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be a positive (rows, cols) pair, got {shape}")
        if not isinstance(cfg, OccupancyConfig):
            raise ValueError(f"cfg must be an OccupancyConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self._log_odds = np.zeros(shape, np.float32)
        self._carve_log_odds = np.zeros(shape, np.float32)
        self._touched = np.zeros(shape + (2,), np.int32)  # the scan kernel's ray counts, all zero between scans
        # The classes (int8, with and without carving), kept up to date over the rectangle each write changed.
        self._classes = {True: np.full(shape, UNKNOWN, np.int8), False: np.full(shape, UNKNOWN, np.int8)}
        self._blocks: dict = {}  # (k, include_carved) -> the classes on blocks of k x k cells (blocks())
        self._stale: Optional[list] = None  # [r0, r1, c0, c1] changed since the classes were derived
        self._lock = threading.RLock()  # reads derive: a reader in another thread and a step's marks in turn

    @property
    def log_odds(self) -> np.ndarray:
        """float32 ``[H, W]`` line-of-sight log-odds (0: nothing measured), to write in place right after reading it
        here (a read marks the whole map changed; a reference kept across a derivation is not watched)."""
        self._changed()
        return self._log_odds

    @property
    def carve_log_odds(self) -> np.ndarray:
        """float32 ``[H, W]`` carving log-odds in ``[cfg.carve_lowest, 0]`` (written in place as :attr:`log_odds`)."""
        self._changed()
        return self._carve_log_odds

    def _changed(self, r0: int = 0, r1: Optional[int] = None, c0: int = 0, c1: Optional[int] = None) -> None:
        """Mark the rectangle ``[r0:r1, c0:c1]`` (clipped to the map; default: all of it) as changed."""
        rows, cols = self._log_odds.shape
        box = [max(r0, 0), rows if r1 is None else min(r1, rows), max(c0, 0), cols if c1 is None else min(c1, cols)]
        if box[0] < box[1] and box[2] < box[3]:
            with self._lock:  # a reader deriving meanwhile (another thread) must not drop this mark
                old = self._stale or box
                self._stale = [min(old[0], box[0]), max(old[1], box[1]), min(old[2], box[2]), max(old[3], box[3])]

    def _derived(self, include_carved: bool) -> np.ndarray:
        """The int8 classes (see :meth:`observed`), derived again over the changed rectangle; not a copy."""
        with self._lock:
            if self._stale is not None:
                r0, r1, c0, c1 = self._stale
                cfg = self.cfg
                log_odds, carve = self._log_odds[r0:r1, c0:c1], self._carve_log_odds[r0:r1, c0:c1]
                wall = log_odds >= cfg.occupied_threshold
                free = log_odds <= cfg.free_threshold
                carved_free = (carve < 0.0) & ~wall & (log_odds + carve <= cfg.free_threshold)
                for carving, classes in self._classes.items():
                    area = classes[r0:r1, c0:c1]
                    area[...] = UNKNOWN
                    area[(free | carved_free) if carving else free] = FREE
                    area[wall] = OCCUPIED
                for (k, carving), blocks in self._blocks.items():  # the blocks that hold a changed cell
                    b0, b1, d0, d1 = r0 // k, -(-r1 // k), c0 // k, -(-c1 // k)
                    blocks[b0:b1, d0:d1] = coarsen_observed(self._classes[carving][b0 * k:b1 * k, d0 * k:d1 * k], k)
                self._stale = None
            return self._classes[bool(include_carved)]

    def blocks(self, k: int, include_carved: bool = True) -> np.ndarray:
        """int8 ``[ceil(H/k), ceil(W/k)]``: :meth:`observed` on blocks of ``k x k`` cells (the planning grid of a
        fine map, :func:`~superex_deploy.onboard.mapping.blocks.coarsen_observed`), kept up to date; a fresh array.

        Raises:
            ValueError: ``k`` not an integer >= 1.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"the block size must be an integer >= 1, got {k!r}")
        key = (int(k), bool(include_carved))
        with self._lock:
            classes = self._derived(include_carved)
            if key not in self._blocks:
                self._blocks[key] = coarsen_observed(classes, key[0]).copy()
            return self._blocks[key].copy()

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self._log_odds.shape  # type: ignore[return-value]

    @property
    def seen_wall(self) -> np.ndarray:
        """Cells the line of sight holds occupied (``log_odds >= occupied_threshold``)."""
        return self._derived(False) == OCCUPIED

    @property
    def seen_free(self) -> np.ndarray:
        """Cells the line of sight holds free with confidence (``log_odds <= free_threshold``)."""
        return self._derived(False) == FREE

    @property
    def carved(self) -> np.ndarray:
        """Cells NLOS carving pushed towards free (may overlap the two above)."""
        return self._carve_log_odds < 0.0

    @property
    def carved_free(self) -> np.ndarray:
        """Cells free by carving: carved, not held occupied, and line-of-sight plus carving log-odds at or below
        the free threshold."""
        return (self._carve_log_odds < 0.0) & (self._derived(True) == FREE)

    def integrate_scan(self, frame: MapFrame, pose: Pose2D, scan: LaserScan,
                       footprint_radius_cells: Optional[float] = None,
                       pose_covariance: Optional[PoseCovariance] = None) -> int:
        """Update the map with a measured scan taken at ``pose``; with ``footprint_radius_cells``, then clear the
        robot's footprint there (:meth:`clear_footprint`), judging which cells are confirmed walls by their values
        *before* this scan: the scan's own misses start in the robot's cells, and a scan given at a wrong pose
        (inside a wall) must not first lower a confirmed wall below the clamp and then let the clearing free it.
        Returns how many occupied cells the clearing freed (0 without a footprint). With ``pose_covariance`` (the
        observation's: the pose is uncertain) each ray clears only as far as its neighbours within
        ``cfg.pose_clearing_sigmas`` lateral sigmas reach (:func:`~superex_deploy.onboard.mapping.log_odds.clear_limits`).

        A range in ``[range_min, range_max)`` up to ``cfg.usable_range_m`` is a return; ``+inf``, a range at or
        above ``range_max`` (drivers and Gazebo report no return as exactly ``range_max``, a SICK LMS above it)
        or beyond the usable range says only that nothing was met: free up to the usable range and ``range_max``,
        stopping at a cell the map holds occupied. NaN, ``-inf`` and ranges below ``range_min`` are invalid
        readings (REP 117: too close, or a dropout) and the ray is skipped, so a scan without a valid reading
        leaves the map as it was.
        Angles are turned from the robot's frame (counter-clockwise from its heading) into grid angles.

        Raises:
            ValueError: a frame of another shape, a pose outside the map, a negative or non-finite radius.
        """
        if tuple(frame.shape) != self.shape:
            raise ValueError(f"the map frame has shape {frame.shape}, the map {self.shape}")
        origin, _ = frame.locate(pose.x, pose.y)
        confirmed = None
        if footprint_radius_cells is not None:
            area, _ = self._footprint(origin, footprint_radius_cells)
            confirmed = self._log_odds[area] >= np.float32(self.cfg.highest)
        resolution = frame.resolution_m
        ranges = scan.ranges.astype(np.float64)
        valid = ~np.isnan(ranges) & (ranges >= scan.range_min)
        returned = valid & (ranges < scan.range_max) & (ranges <= self.cfg.usable_range_m)
        angles = grid_angles(pose.yaw, scan.angles())
        self.integrate_ranges(origin, angles[valid], np.where(returned, ranges / resolution, np.inf)[valid],
                              scan.range_max / resolution,
                              hit_shift_cells=self.cfg.range_hit_sigmas * self.cfg.range_sigma_m / resolution,
                              usable_range_cells=self.cfg.usable_range_m / resolution,
                              pose_sigmas=None if pose_covariance is None else (
                                  pose_covariance.sigma_xy_m / resolution, pose_covariance.sigma_yaw_rad))
        if footprint_radius_cells is None:
            return 0
        return self.clear_footprint(origin, footprint_radius_cells, keep=confirmed)

    def integrate_observation(self, frame: MapFrame, obs, footprint_cells: Optional[float], scan_matcher=None):
        """Integrate an :class:`~superex_deploy.messages.Observation`'s line of sight: its SLAM map
        (``obs.occupancy_grid``) replaces the line-of-sight layer (the robot's footprint cleared on it: the robot
        stands on free space, whatever a stale map says there); otherwise its scan is integrated
        (:meth:`integrate_scan`), first matched against the walls held so far when the pose carries a covariance and
        a ``scan_matcher`` (:class:`~superex_deploy.onboard.mapping.scan_matching.ScanMatcher`) is given.

        Returns:
            ``(pose, scan_match)``: the pose the scan was integrated at (the observation's, or the accepted match's
            correction) and the :class:`~superex_deploy.onboard.mapping.scan_matching.ScanMatch` (None when no match
            was tried).
        """
        if obs.occupancy_grid is not None:
            self.set_line_of_sight(obs.occupancy_grid.in_frame(frame))
            if footprint_cells is not None:
                self.clear_footprint(frame.locate(obs.pose.x, obs.pose.y)[0], footprint_cells, everything=True)
            return obs.pose, None
        pose, match = obs.pose, None
        if obs.pose_covariance is not None and scan_matcher is not None:
            match = scan_matcher.match(frame, self.seen_wall, obs.pose, obs.pose_covariance, obs.scan)
            if match.accepted:
                pose = match.pose
        self.integrate_scan(frame, pose, obs.scan, footprint_radius_cells=footprint_cells)
        return pose, match

    def integrate_ranges(self, origin_yx, angles, ranges_cells, max_range_cells: float,
                         hit_shift_cells: float = 0.0, usable_range_cells: float = np.inf,
                         pose_sigmas: Optional[tuple[float, float]] = None) -> None:
        """Update the map with a measured scan, in grid units: see :func:`integrate_log_odds`.

        Args:
            origin_yx: sensor position ``(y, x)`` in cells, inside the map.
            angles: float64 ``[N]`` ray angles (radians, grid convention: ``(dy, dx) = (sin, cos)``).
            ranges_cells: float64 ``[N]`` measured ranges (cells), ``inf`` for no return.
            max_range_cells: the sensor's maximum range (cells).
            hit_shift_cells: how much farther each return's hit is placed (cells; :meth:`integrate_scan` passes
                ``range_hit_sigmas * range_sigma_m`` over the resolution).
            usable_range_cells: how far a ray without a return clears (cells; :meth:`integrate_scan` passes
                ``usable_range_m`` over the resolution).
            pose_sigmas: ``(sigma_xy cells, sigma_yaw radians)`` of the pose's error, or None (exact).
        """
        integrate_log_odds(self._log_odds, origin_yx, angles, ranges_cells, max_range_cells, self.cfg, self._touched,
                           hit_shift_cells, usable_range_cells, pose_sigmas)
        # Every cell a ray touched lies within its range or its return (shifted), and a cell further.
        ranges = np.asarray(ranges_cells, np.float64)
        longest = max(float(max_range_cells), float(ranges[np.isfinite(ranges)].max(initial=0.0)))
        reach = int(np.ceil(longest + float(hit_shift_cells))) + 2
        row, col = int(np.floor(float(origin_yx[0]))), int(np.floor(float(origin_yx[1])))
        self._changed(row - reach, row + reach + 1, col - reach, col + reach + 1)

    def _footprint(self, origin_yx, radius_cells: float) -> tuple[tuple[slice, slice], np.ndarray]:
        """The window around a footprint and the bool disc in it: cells whose centre lies within
        ``radius_cells`` of ``origin_yx``, and the cell holding it."""
        y0, x0 = (float(v) for v in origin_yx)
        rows, cols = self.shape
        if not (np.isfinite(y0) and np.isfinite(x0) and 0.0 <= y0 < rows and 0.0 <= x0 < cols):
            raise ValueError(f"origin_yx {origin_yx} lies outside the map of shape {self.shape}")
        radius = float(radius_cells)
        if not (np.isfinite(radius) and radius >= 0.0):
            raise ValueError(f"radius_cells must be finite and >= 0, got {radius_cells!r}")
        reach = int(np.ceil(radius)) + 1
        r0, r1 = max(int(y0) - reach, 0), min(int(y0) + reach + 1, rows)
        c0, c1 = max(int(x0) - reach, 0), min(int(x0) + reach + 1, cols)
        centre_r = np.arange(r0, r1)[:, None] + 0.5
        centre_c = np.arange(c0, c1)[None, :] + 0.5
        disc = (centre_r - y0) ** 2 + (centre_c - x0) ** 2 <= radius * radius
        disc[int(y0) - r0, int(x0) - c0] = True
        return (slice(r0, r1), slice(c0, c1)), disc

    def clear_footprint(self, origin_yx, radius_cells: float, keep: Optional[np.ndarray] = None,
                        everything: bool = False) -> int:
        """The robot's body is free space (costmap_2d's footprint clearing): the known cells whose centre lies
        within ``radius_cells`` of ``origin_yx``, and the cell holding it, become free (``lowest``); a cell held
        occupied at the ``highest`` clamp (hit by several scans) is kept, since a pose error can put a true wall
        under the believed footprint. Unknown cells stay unknown.

        Args:
            origin_yx: the robot's position ``(y, x)`` in cells, inside the map.
            radius_cells: the footprint's radius (cells, >= 0).
            keep: bool, the shape of the footprint's window: the cells to keep instead of those at the clamp now
                (:meth:`integrate_scan` passes the cells that were at the clamp before its scan).
            everything: free every cell of the footprint, unknown and confirmed walls too: for a map taken from
                SLAM (:meth:`set_line_of_sight`), where the robot's own cells must be free for it to plan at all
                (a stale map may hold a wall or nothing where the robot stands), and the pose comes from the
                same SLAM as the map.

        Returns:
            How many occupied cells became free (known free cells are pushed to ``lowest`` without changing class).
        """
        area, disc = self._footprint(origin_yx, radius_cells)
        window = self._log_odds[area]
        self._changed(area[0].start, area[0].stop, area[1].start, area[1].stop)
        cfg = self.cfg
        if everything:
            clear = disc
        else:
            if keep is None:
                keep = window >= np.float32(cfg.highest)
            elif keep.shape != window.shape:
                raise ValueError(f"keep must have the footprint window's shape {window.shape}, got {keep.shape}")
            known = (window <= cfg.free_threshold) | (window >= cfg.occupied_threshold)
            clear = disc & known & ~keep
        changed = int(np.count_nonzero(clear & (window >= cfg.occupied_threshold)))
        window[clear] = cfg.lowest
        return changed

    def regrid(self, regrid) -> None:
        """Move to a larger grid (a :class:`~superex_deploy.onboard.mapping.growth.Regrid`): both layers keep their
        values at the new indices, new cells are unknown (log-odds 0)."""
        self._log_odds = regrid.embed(self._log_odds, 0.0)
        self._carve_log_odds = regrid.embed(self._carve_log_odds, 0.0)
        self._touched = np.zeros(self._log_odds.shape + (2,), np.int32)
        self._classes = {key: np.full(self._log_odds.shape, UNKNOWN, np.int8) for key in self._classes}
        self._blocks = {}
        self._stale = None
        self._changed()

    def set_line_of_sight(self, occupancy_percent: np.ndarray) -> None:
        """Replace the line-of-sight layer by a SLAM map on this grid (the carving layer is kept).

        Args:
            occupancy_percent: int8 ``[H, W]``: -1 unknown, 0..100 occupancy in percent
                (:meth:`superex_deploy.messages.OccupancyGridMessage.in_frame`). Cells at or above
                ``slam_occupied_percent`` become ``highest``, known cells at or below ``slam_free_percent``
                ``lowest``, the others 0 (unknown).
        """
        grid = np.asarray(occupancy_percent)
        if grid.dtype != np.int8 or grid.shape != self.shape:
            raise ValueError(f"occupancy_percent must be int8 of shape {self.shape}, got {grid.dtype} {grid.shape}")
        cfg = self.cfg
        log_odds = self.log_odds  # marks the whole map changed
        log_odds[...] = 0.0
        log_odds[(grid >= 0) & (grid <= cfg.slam_free_percent)] = cfg.lowest
        log_odds[grid >= cfg.slam_occupied_percent] = cfg.highest

    def merge_carved(self, carved: np.ndarray) -> None:
        """Add the cells one NLOS carving proved free: their carving log-odds move by ``carve_step``, clamped at
        ``carve_lowest``.

        Args:
            carved: bool ``[H, W]``.
        """
        carved = np.asarray(carved)
        if carved.dtype != np.bool_ or carved.shape != self.shape:
            raise ValueError(f"carved must be a bool array of shape {self.shape}, got {carved.dtype} "
                             f"{carved.shape}")
        if carved.any():
            rows, cols = np.flatnonzero(carved.any(axis=1)), np.flatnonzero(carved.any(axis=0))
            area = slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)
            inside, layer = carved[area], self._carve_log_odds[area]
            values = layer[inside].astype(np.float64) + self.cfg.carve_step
            layer[inside] = np.maximum(values, self.cfg.carve_lowest)
            self._changed(area[0].start, area[0].stop, area[1].start, area[1].stop)

    def known(self, include_carved: bool = True) -> np.ndarray:
        """bool ``[H, W]``: cells held free or occupied (plus cells free by carving if ``include_carved``)."""
        return self._derived(include_carved) != UNKNOWN

    def drivable(self, include_carved: bool = False) -> np.ndarray:
        """bool ``[H, W]``: cells a path may cross: held free with confidence by the line of sight (plus cells free
        by carving if ``include_carved``)."""
        return self._derived(include_carved) == FREE

    def observed(self, include_carved: bool = True) -> np.ndarray:
        """int8 ``[H, W]``: OCCUPIED where the line of sight holds a wall, FREE where it holds free (or, with
        ``include_carved``, where carving makes it free), else UNKNOWN."""
        return self._derived(include_carved).copy()
