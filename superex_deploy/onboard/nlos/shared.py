"""NLOS processing, the parts every stage shares: the parameters (:class:`NlosConfig`), the per-ray estimates
(:class:`LosEstimate`), the results (:class:`GridPatch`, :class:`NlosResult`), the carve-radius cap
(:func:`carve_radius_cap_m`) and small helpers (the scan check, the thread-part count, :data:`ROW_BLOCK`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.spad_types import SpadScan, SparseHistograms

ROW_BLOCK = 8
"""Rows of the back-projection window and of the carved patch are dealt to the threads in blocks of this many."""


@dataclass(frozen=True)
class NlosConfig(JsonConfig):
    """NLOS processing parameters, in metres (and degrees): the same parameters serve every grid resolution
    (:meth:`in_cells` converts them for one).

    Attributes:
        window_m: back-projection is computed within this distance of the robot (square window, metres).
        apex_margin_m: carve-radius reduction for the wall point's estimate (metres).
        sector_margin_deg: the carved half-disc is narrowed to +-(90 - this) degrees about the normal: near
            grazing, a small error in the estimated normal would carve past the wall's end. 20 carves more than
            35 and no true wall on the benchmark trajectories, 15 carves true walls (measured in
            docs/benchmarks/spad.md, "Carving nearer its bound").
        wall_strip_m: cells within this distance of the wall's own line are never carved (metres).
        false_alarm_rate: noisy mode: probability that a ray's late part holds a false detection.
        normal_radius_m: observed wall hits within this radius of a wall cell estimate its normal (metres; at
            least 1.5 cells of the grid, so that a straight wall gives three hits).
        normal_max_minor_ratio: a normal is trusted for carving only if the hits' minor/major variance ratio is
            below this (the hits lie on a line, not around a corner).
        normal_max_residual_m: ... and only if every one of those hits lies within this distance of the
            fitted line (metres; the cells a straight wall face exposes have centres within sqrt(2)/2 of a cell
            of it; a larger residual means hits from two walls, e.g. a thin wall's face and a wall seen past its
            end, whose fitted line and normal can be tilted far enough to put the carved sector on the far side).
        normal_max_gap_m: ... and only if consecutive hits along that line are at most this far apart (metres, at
            least one cell of the grid: a wider gap can be a wall end followed by another wall, and the end's true
            normal turns away; the property test found a wall-end cell whose line ran on to a second wall 0.4 m
            away).
        normal_interior_m: ... and only if observed hits extend at least this far on both sides of the
            cell along the wall (metres; wall ends and corners carry normals of their own; the margin also covers
            a wall-cell estimate one cell off).
        max_incidence_deg: wall points seen more obliquely than this are not carved: at grazing incidence a
            small error in the estimated normal flips which side of the wall faces the robot.
        pose_sigma_margin: with an uncertain pose, each wall point's carve radius shrinks, and its wall strip
            and the interior distance its normal needs (``normal_interior_m``) widen, by this many times
            ``sigma_xy + rho sigma_yaw`` (the pose covariance's position and yaw standard deviations; ``rho`` the
            distance from the robot; see :mod:`.carving`, point 4). 2 carves no true wall at 5 cm / 1 degree
            nor at 10 cm / 2 degrees, where 1 does (measured in docs/on-a-robot.md, "Carving under
            uncertainty").
        normals_from_map: where the carving is given the map's wall cells, each wall cell the scan's own hits do
            not trust is refitted to those hits and the map's wall cells together (the same tests): a cell at the
            end of this scan's hits where the map's wall runs on is carved from, a cell the map shows beside a
            corner is not (:func:`.normals.map_supported_normals`). Measured sound and a small gain (+0.06 points
            of first-half AUC on the eval trajectories; docs/benchmarks/spad.md, "Normals from the map"); off by
            default until the paper table is re-run with it (its committed SPAD rows ran without).
        laplacian_sigma_m: standard deviation of the Gaussian of the Laplacian baseline filter (metres).
        threads: the parallel kernels (wall normals, votes, carving, the back-projection's rings) split their
            work into this many parts (0: numba's thread count, ``NUMBA_NUM_THREADS`` or
            ``numba.set_num_threads``; 1: sequential). Every part owns its outputs (wall cells, rows), so the
            result does not depend on it.
    """

    window_m: float = 8.0
    apex_margin_m: float = 0.15
    sector_margin_deg: float = 20.0
    wall_strip_m: float = 0.15
    false_alarm_rate: float = 1e-3
    normal_radius_m: float = 0.5
    normal_max_minor_ratio: float = 0.1
    normal_max_residual_m: float = 0.09
    normal_max_gap_m: float = 0.2
    normal_interior_m: float = 0.25
    max_incidence_deg: float = 70.0
    pose_sigma_margin: float = 2.0
    normals_from_map: bool = False
    laplacian_sigma_m: float = 0.1
    threads: int = 0

    def __post_init__(self) -> None:
        for name in ("window_m", "apex_margin_m", "wall_strip_m", "normal_interior_m", "laplacian_sigma_m",
                     "pose_sigma_margin"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"NlosConfig.{name} must be finite and >= 0, got {value}")
        for name in ("normal_radius_m", "normal_max_residual_m", "normal_max_gap_m"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f"NlosConfig.{name} must be > 0, got {value}")
        if not 0.0 <= self.sector_margin_deg < 90.0:
            raise ValueError(f"NlosConfig.sector_margin_deg must lie in [0, 90), got {self.sector_margin_deg}")
        if not 0.0 < self.false_alarm_rate < 1.0:
            raise ValueError(f"NlosConfig.false_alarm_rate must lie in (0, 1), got {self.false_alarm_rate}")
        if not 0.0 < self.max_incidence_deg <= 90.0:
            raise ValueError(f"NlosConfig.max_incidence_deg must lie in (0, 90], got {self.max_incidence_deg}")
        if not isinstance(self.normals_from_map, bool):
            raise ValueError(f"NlosConfig.normals_from_map must be True or False, got {self.normals_from_map!r}")
        if int(self.threads) != self.threads or self.threads < 0:
            raise ValueError(f"NlosConfig.threads must be an integer >= 0, got {self.threads}")

    def in_cells(self, resolution_m: float) -> "NlosCells":
        """The metric lengths in cells of a grid of ``resolution_m`` metres per cell (the kernels work in cells).

        Raises:
            ValueError: a resolution that is not positive, or so coarse that ``normal_radius_m`` is under 1.5 cells
                or ``normal_max_gap_m`` under one cell (no straight wall could then support a normal).
        """
        if not (np.isfinite(resolution_m) and resolution_m > 0):
            raise ValueError(f"resolution_m must be a positive number of metres, got {resolution_m!r}")
        cells = NlosCells(**{name: metres_to_cells(getattr(self, f"{name}_m"), resolution_m)
                             for name in ("apex_margin", "wall_strip", "normal_radius", "normal_max_residual",
                                          "normal_max_gap", "normal_interior", "laplacian_sigma")})
        if cells.normal_radius < 1.5 or cells.normal_max_gap < 1.0:
            raise ValueError(f"NlosConfig.normal_radius_m {self.normal_radius_m} m and normal_max_gap_m "
                             f"{self.normal_max_gap_m} m must span at least 1.5 and 1 cells of a {resolution_m} m "
                             f"grid")
        return cells


def metres_to_cells(value_m: float, resolution_m: float) -> float:
    """``value_m / resolution_m`` rounded to 1e-6 of a cell, so that a length given in metres is the number of
    cells the decimal division says (0.15 m at 0.1 m is 1.5 cells, not 1.4999999999999998), also on a grid whose
    resolution came as float32 (a ROS map's 0.1 is 0.10000000149011612)."""
    return round(float(value_m) / float(resolution_m), 6)


@dataclass(frozen=True)
class NlosCells:
    """:class:`NlosConfig`'s lengths in cells of one grid (:meth:`NlosConfig.in_cells`); each attribute is the
    config's ``<name>_m`` divided by the resolution."""

    apex_margin: float
    wall_strip: float
    normal_radius: float
    normal_max_residual: float
    normal_max_gap: float
    normal_interior: float
    laplacian_sigma: float


@dataclass(frozen=True)
class LosEstimate:
    """Per-ray estimates from the histograms.

    Attributes:
        los_bin: int64 ``[n_rays]`` bin of the direct return, -1 where none was detected.
        d1_m: float64 ``[n_rays]`` distance to the wall point (bin centre; NaN where none).
        h1_rc: int64 ``[n_rays, 2]`` estimated wall cell (-1 where none).
        first_late_bin: int64 ``[n_rays]`` first detected late bin, -1 where the late part is empty.
        empty_radius_m: float64 ``[n_rays]`` lower bound on the distance from the wall point to any sampled
            hidden surface (``(bf - b1 - 1) w / 2``; the secondary range where the late part is empty; NaN where
            there is no direct return).
        wall_cells: int64 ``[U, 2]`` distinct estimated wall cells; ``ray_wall[i]`` indexes them (-1: none).
        wall_normal: float64 ``[U, 2]`` unit normal (dy, dx) at each wall cell, facing the robot.
        wall_apex: float64 ``[U, 2]`` each wall cell's fan origin X1 (cells, (y, x)): where its normal through the
            cell centre leaves the cell; the carved sectors and the back-projected rings are centred there.
        normal_reliable: bool ``[U]`` normals backed by enough elongated wall hits (only these are carved).
        late_threshold: detection threshold on late-bin counts (0 in noise-free mode: any photon).
        detections: the bins whose count exceeds ``late_threshold``, every ray's (what the estimates and the
            back-projection read).
    """

    los_bin: np.ndarray
    d1_m: np.ndarray
    h1_rc: np.ndarray
    first_late_bin: np.ndarray
    empty_radius_m: np.ndarray
    wall_cells: np.ndarray
    ray_wall: np.ndarray
    wall_normal: np.ndarray
    wall_apex: np.ndarray
    normal_reliable: np.ndarray
    late_threshold: float
    detections: SparseHistograms


@dataclass(frozen=True, eq=False)
class GridPatch:
    """A rectangle of a grid's cells, ``grid[top:top + h, left:left + w]``; every other cell of the grid is zero
    (False). The NLOS results cover a small part of the map (the back-projection window, the carved sectors), so
    they are made and kept as patches; :meth:`to_grid` gives the whole map.

    Attributes:
        values: ``[h, w]`` array (``h`` or ``w`` may be 0).
        top, left: grid row and column of ``values[0, 0]``.
        grid_shape: ``(rows, cols)`` of the whole grid.
    """

    values: np.ndarray
    top: int
    left: int
    grid_shape: tuple[int, int]

    @property
    def slices(self) -> tuple[slice, slice]:
        """The patch's rows and columns in the grid: ``grid[patch.slices]`` is the patch's area."""
        height, width = self.values.shape
        return slice(self.top, self.top + height), slice(self.left, self.left + width)

    def to_grid(self) -> np.ndarray:
        """The whole grid, ``grid_shape``, of the values' dtype, zero outside the patch."""
        grid = np.zeros(self.grid_shape, self.values.dtype)
        grid[self.slices] = self.values
        return grid


@dataclass(frozen=True, eq=False)
class NlosResult:
    """Output of :func:`~superex_deploy.onboard.nlos.process_scan`.

    Attributes:
        carved_patch: bool cells proven free (a :class:`GridPatch` around the carved sectors).
        bp_patch: float32 back-projection in [0, 1] (a :class:`GridPatch` of the back-projection window).
        bp_filtered_patch: float32 Laplacian-filtered back-projection in [0, 1] (the window and a margin).
        los: the per-ray :class:`LosEstimate`.
    """

    carved_patch: GridPatch
    bp_patch: GridPatch
    bp_filtered_patch: GridPatch
    los: LosEstimate

    @cached_property
    def carved(self) -> np.ndarray:
        """bool ``[H, W]`` cells proven free."""
        return self.carved_patch.to_grid()

    @cached_property
    def bp(self) -> np.ndarray:
        """float32 ``[H, W]`` back-projection, in [0, 1]."""
        return self.bp_patch.to_grid()

    @cached_property
    def bp_filtered(self) -> np.ndarray:
        """float32 ``[H, W]`` Laplacian-filtered back-projection, in [0, 1]."""
        return self.bp_filtered_patch.to_grid()


def carve_radius_cap_m(n_secondary: int, resolution_m: float) -> float:
    """Largest radius (metres) within which ``n_secondary`` rays over 180 degrees must cross every cell: the fan
    density sets it (8.1 m at 256 rays, the default, and 0.1 m cells; 4.1 m at 128, 2.0 m at 64), not the physics."""
    return resolution_m * n_secondary / np.pi


def check_scan(scan: SpadScan) -> None:
    """Refuse anything but a :class:`SpadScan` whose histograms (dense or sparse) are float32
    ``[n_rays, n_bins]``, one row per angle.

    Raises:
        ValueError: naming the type, dtype or shape found.
    """
    if not isinstance(scan, SpadScan):
        raise ValueError(f"scan must be a SpadScan, got {type(scan).__name__}")
    stored = scan.stored
    if isinstance(stored, SparseHistograms):
        shape = (stored.n_rays, stored.n_bins)
        ok = (stored.counts.dtype == np.float32 and stored.bins.dtype == np.int32
              and stored.bins.shape == stored.counts.shape and stored.row_start.shape == (shape[0] + 1,))
        dtype = stored.counts.dtype
    else:
        shape, dtype = np.shape(stored), getattr(stored, "dtype", None)
        ok = dtype == np.float32 and len(shape) == 2
    if not ok or shape[0] != scan.angles.shape[0]:
        raise ValueError(f"scan histograms must be float32 [n_rays, n_bins] matching the angles, got {dtype} "
                         f"{shape}")

