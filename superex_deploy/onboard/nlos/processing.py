"""NLOS processing of measured SPAD frames on the robot: space carving and (filtered) back-projection evidence.

Reads only the :class:`~superex_deploy.messages.SpadFrame`, the pose (and its covariance, which widens the carving
margins: :mod:`superex_deploy.onboard.nlos.carving`, point 4) and the explorer's own map; the sensor model
(:class:`~superex_deploy.spad_types.SpadConfig`: bin width, range, noise model, secondary-ray count for the carving cap) is
the robot's calibration of its sensor, not the simulator's truth.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.messages import MapFrame, Pose2D, PoseCovariance, SpadFrame, grid_angles
from superex_deploy.onboard.nlos import NlosConfig, carve, carve_radius_cap_m, estimate_los, process_scan
from superex_deploy.onboard.nlos.back_projection import back_project_patch
from superex_deploy.onboard.nlos.filters import laplacian_filter_patch
from superex_deploy.onboard.prediction.scale import (at_resolution, filter_area, model_resolution, scale_factors,
                                                     upsample_linear)
from superex_deploy.spad_types import SpadConfig, SpadScan, SparseHistograms

__all__ = ["NlosSkips", "SpadProcessing", "scan_from_frame", "check_frame_matches"]


def check_frame_matches(frame: SpadFrame, sensor: SpadConfig) -> None:
    """Refuse a SPAD frame the sensor model cannot read.

    Raises:
        ValueError: not a :class:`~superex_deploy.messages.SpadFrame`, or a bin count or bin width that differs
            from the sensor model's.
    """
    if not isinstance(frame, SpadFrame):
        raise ValueError(f"frame must be a SpadFrame, got {type(frame).__name__}")
    if frame.n_bins != sensor.n_bins:
        raise ValueError(f"the SPAD frame has {frame.n_bins} bins per ray, the sensor model the NLOS processing and "
                         f"its models were built for has {sensor.n_bins} (range {sensor.range_m} m, bin width "
                         f"{sensor.bin_width_s:.6g} s)")
    if not np.isclose(frame.bin_width_s, sensor.bin_width_s, rtol=1e-9, atol=0.0):
        raise ValueError(f"the SPAD frame's bins are {frame.bin_width_s:.9g} s wide, the sensor model's "
                         f"{sensor.bin_width_s:.9g} s")


def scan_from_frame(frame: SpadFrame, map_frame: MapFrame, pose: Pose2D, sensor: SpadConfig) -> SpadScan:
    """The :class:`~superex_deploy.spad_types.SpadScan` (no ground truth) of a measured frame taken at ``pose``.

    Raises:
        ValueError: a frame whose bin count or bin width differs from the sensor model's, or a pose outside the
            map.
    """
    check_frame_matches(frame, sensor)
    origin, cell = map_frame.locate(pose.x, pose.y)
    angles = grid_angles(pose.yaw, frame.angles)
    stored = SparseHistograms(np.asarray(frame.row_start), np.asarray(frame.bins), np.asarray(frame.counts),
                              frame.n_bins)
    return SpadScan(angles=angles, origin_yx=origin, pose_rc=cell, bin_path_m=sensor.bin_path_m,
                    resolution_m=map_frame.resolution_m, grid_shape=map_frame.shape, config=sensor, stored=stored)


@dataclass(frozen=True)
class NlosSkips(JsonConfig):
    """Work the SPAD processing may leave out (all off by default: every frame is processed in full).

    Attributes:
        evidence_every: back-project and filter only every this many frames (1: every frame); the frames between
            are still carved. Not exact: the evidence misses those frames' glimpses (measured in
            docs/benchmarks/realtime.md, "SPAD skips"; the ``realtime`` profile takes 2).
        carving: leave the carving out (no cell is ever carved; the evidence is made as with carving on): the paper
            suite's ablation "without carving", which measures what the carved cells add.

    Five exact skips (frames with no unknown cell in reach, frames from a still robot, the filter on an empty or an
    unchanged window, rays that reach no unknown cell) were measured there and retired: on real episodes they
    cost about what they saved.
    """

    evidence_every: int = 1
    carving: bool = False

    def __post_init__(self) -> None:
        from superex_deploy.onboard.checks import check_int

        if not isinstance(self.carving, bool):
            raise ValueError(f"carving must be True or False, got {self.carving!r}")
        object.__setattr__(self, "evidence_every", check_int("evidence_every", self.evidence_every, 1))


COUNTS = ("frames", "evidence_skipped")
"""The keys of :attr:`SpadProcessing.counts`."""


@dataclass
class SpadProcessing:
    """Turns each SPAD frame into carved free cells and the evidence the predictor reads.

    Each call processes one frame with the currently known cells masked out of the back-projection and returns
    ``(carved bool [H, W], evidence float32 [H, W])``; the evidence is the running maximum of the filtered
    back-projection over the episode, so hidden walls glimpsed earlier stay available to the predictor.

    Attributes:
        sensor: the sensor model (bin width, range, noise) the frames must match.
        nlos_cfg: processing parameters.
        bp_filter: turns the raw back-projection (float32 ``[H, W]`` in [0, 1]) and the robot cell into the
            filtered evidence (float32 ``[H, W]`` in [0, 1]), e.g.
            :meth:`superex_deploy.onboard.prediction.inference.Pix2PixFilter.filter_map`; None: the Laplacian baseline.
            A filter that gives its training resolution (a learned model's) runs at that scale on every scan's grid:
            on a grid finer by an integer factor the raw back-projection is drawn on the model's cells (a block known
            where all its cells are) and the filter's answer interpolated back onto the grid; on a coarser grid
            :func:`~superex_deploy.onboard.prediction.scale.at_resolution` repeats the cells; unchanged at its own
            resolution.
        skips: work left out (:class:`NlosSkips`).
        counts: since :meth:`reset`: ``frames`` seen; frames whose evidence was skipped (``evidence_skipped``:
            ``evidence_every``).
    """

    sensor: SpadConfig = field(default_factory=SpadConfig)
    nlos_cfg: NlosConfig = field(default_factory=NlosConfig)
    bp_filter: Optional[Callable[[np.ndarray, tuple[int, int]], np.ndarray]] = None
    skips: NlosSkips = field(default_factory=NlosSkips)
    _evidence: Optional[np.ndarray] = field(default=None, init=False, repr=False, compare=False)
    _scaled_filter: Optional[tuple] = field(default=None, init=False, repr=False, compare=False)
    counts: dict = field(default_factory=lambda: dict.fromkeys(COUNTS, 0), init=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.skips, NlosSkips):
            raise ValueError(f"skips must be an NlosSkips, got {type(self.skips).__name__}")

    @property
    def reads_map_walls(self) -> bool:
        """Whether the carving reads the map's wall cells (``nlos_cfg.normals_from_map``, carving not skipped): a
        caller derives them only then."""
        return self.nlos_cfg.normals_from_map and not self.skips.carving

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` running maximum of the filtered back-projection so far (None before the first frame)."""
        return self._evidence

    def check_frame(self, frame: SpadFrame) -> None:
        """Refuse a frame this processing cannot read (:func:`check_frame_matches`), before anything else of its
        step is integrated.

        Raises:
            ValueError: see :func:`check_frame_matches`.
        """
        check_frame_matches(frame, self.sensor)

    def check_resolution(self, resolution_m: float) -> None:
        """Refuse a grid the filter's model cannot serve, before the first frame.

        Raises:
            ValueError: see :func:`~superex_deploy.onboard.prediction.scale.scale_factors`.
        """
        self._filter_at(resolution_m)

    def _filter_at(self, resolution_m: float):
        """The filter serving a grid of ``resolution_m`` (``bp_filter`` itself at its model's resolution), made
        once per filter and resolution."""
        key = (self.bp_filter, float(resolution_m))
        if self.bp_filter is None:
            return None
        if self._scaled_filter is None or self._scaled_filter[0] != key:
            self._scaled_filter = (key, at_resolution(self.bp_filter, resolution_m))
        return self._scaled_filter[1]

    def regrid(self, regrid) -> None:
        """Move to a larger grid (a :class:`~superex_deploy.onboard.mapping.growth.Regrid`): the evidence keeps its
        values at the new indices (0 in new cells)."""
        if self._evidence is not None:
            self._evidence = regrid.embed(self._evidence, 0.0)

    def reset(self) -> None:
        """Forget the evidence and the frame count of an earlier episode."""
        self._evidence = None
        self.counts = dict.fromkeys(COUNTS, 0)

    def reach_cells(self, resolution_m: float) -> int:
        """Half side (cells) of the square around the robot that a frame can carve or back-project into: carved
        discs lie within the carving cap of wall points within the sensor's range; votes lie in the
        back-projection window."""
        carve_m = self.sensor.range_m + carve_radius_cap_m(self.sensor.n_secondary, resolution_m)
        return max(int(np.ceil(carve_m / resolution_m)) + 1, int(np.ceil(self.nlos_cfg.window_m / resolution_m)))

    def process_scan(self, scan: SpadScan, known: np.ndarray, pose_sigma=(0.0, 0.0),
                     map_walls: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
        """Carving and evidence of one scan (simulated or built by :func:`scan_from_frame`); ``known``: bool
        ``[H, W]`` cells the explorer already knows; ``pose_sigma``: ``(sigma_xy_m, sigma_yaw_rad)`` of the pose
        the scan was placed by (zeros: exact); ``map_walls``: bool ``[H, W]`` the map's wall cells, which support
        the carving's wall normals (:func:`~superex_deploy.onboard.nlos.carve`; None: the scan's hits alone)."""
        if self._evidence is None or self._evidence.shape != tuple(scan.grid_shape):
            self._evidence = np.zeros(scan.grid_shape, np.float32)
        self.counts["frames"] += 1
        frame_index = self.counts["frames"] - 1
        if frame_index % self.skips.evidence_every:
            self.counts["evidence_skipped"] += 1
            if self.skips.carving:  # the line-of-sight estimate would only feed the carving
                return np.zeros(scan.grid_shape, bool), self._evidence
            los = estimate_los(scan, self.nlos_cfg)
            return self._carve(scan, los, pose_sigma, map_walls), self._evidence
        if self.bp_filter is None and not self.skips.carving:
            result = process_scan(scan, self.nlos_cfg, known=known, pose_sigma=pose_sigma, map_walls=map_walls)
            # Only the filtered window can raise the running maximum.
            area = result.bp_filtered_patch.slices
            np.maximum(self._evidence[area], result.bp_filtered_patch.values, out=self._evidence[area])
            return result.carved, self._evidence
        los = estimate_los(scan, self.nlos_cfg)
        if self.bp_filter is None:
            bp = self._back_projection(scan, los, known)
            filtered = laplacian_filter_patch(bp, self.nlos_cfg.in_cells(scan.resolution_m).laplacian_sigma)
            area = filtered.slices
            np.maximum(self._evidence[area], filtered.values, out=self._evidence[area])
            return self._carve(scan, los, pose_sigma, map_walls), self._evidence
        # The learned filter replaces the Laplacian one (that is not computed), at its model's scale: on a finer
        # grid the back-projection itself is drawn on the model's cells (model_scan), as the filter would pool it.
        model, k = self._model_scan(scan, los, known)
        bp = self._back_projection(*model)
        self._filter_into_evidence(model[0], bp, k)
        return self._carve(scan, los, pose_sigma, map_walls), self._evidence

    def _carve(self, scan: SpadScan, los, pose_sigma, map_walls) -> np.ndarray:
        """bool ``[H, W]``: the cells this frame carves (none with ``skips.carving``)."""
        if self.skips.carving:
            return np.zeros(scan.grid_shape, bool)
        return carve(scan, los, self.nlos_cfg, pose_sigma, map_walls)

    def _model_scan(self, scan: SpadScan, los, known: np.ndarray) -> tuple[tuple, int]:
        """``((scan, los, known), k)``: the scan, its line-of-sight estimate and the known cells on the grid the
        filter's model was trained at, when this grid is ``k`` times finer (a block known only where all its cells
        are, within the back-projection window); this grid's own, ``k = 1``, otherwise."""
        model_m = model_resolution(self.bp_filter)
        k = 1 if model_m is None else scale_factors(scan.resolution_m, model_m)[0]
        if k == 1:
            return (scan, los, known), 1
        rows, cols = -(-scan.grid_shape[0] // k), -(-scan.grid_shape[1] // k)
        coarse = dataclasses.replace(scan, origin_yx=(scan.origin_yx[0] / k, scan.origin_yx[1] / k),
                                     pose_rc=(int(scan.pose_rc[0]) // k, int(scan.pose_rc[1]) // k),
                                     resolution_m=scan.resolution_m * k, grid_shape=(rows, cols))
        half = int(np.ceil(self.nlos_cfg.window_m / coarse.resolution_m)) + 1
        r0, c0 = max(coarse.pose_rc[0] - half, 0), max(coarse.pose_rc[1] - half, 0)
        r1, c1 = min(coarse.pose_rc[0] + half + 1, rows), min(coarse.pose_rc[1] + half + 1, cols)
        block_known = np.zeros((rows, cols), bool)
        fine = np.zeros(((r1 - r0) * k, (c1 - c0) * k), bool)  # cells past the map's edge: not known
        inside = known[r0 * k:r1 * k, c0 * k:c1 * k]
        fine[:inside.shape[0], :inside.shape[1]] = inside
        block_known[r0:r1, c0:c1] = fine.reshape(r1 - r0, k, c1 - c0, k).all(axis=(1, 3))
        return (coarse, estimate_los(coarse, self.nlos_cfg), block_known), k

    def _filter_into_evidence(self, scan: SpadScan, bp, k: int) -> None:
        """Run the learned filter on the rectangle of ``scan``'s grid it reads and writes (the same answer as on
        the whole grid: :func:`~superex_deploy.onboard.prediction.scale.filter_area`) and raise the evidence there
        to it; on a model grid ``k`` times coarser than the evidence's, its answer interpolated onto the cells."""
        bp_filter = self._filter_at(scan.resolution_m)
        rows, cols = filter_area(self.bp_filter, scan.resolution_m, scan.pose_rc, scan.grid_shape, bp.slices)
        sub = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.float32)
        inside = bp.slices
        sub[inside[0].start - rows.start:inside[0].stop - rows.start,
            inside[1].start - cols.start:inside[1].stop - cols.start] = bp.values
        filtered = bp_filter(sub, (int(scan.pose_rc[0]) - rows.start, int(scan.pose_rc[1]) - cols.start))
        if k > 1:
            height, width = self._evidence.shape
            rows = slice(rows.start * k, min(rows.stop * k, height))
            cols = slice(cols.start * k, min(cols.stop * k, width))
            filtered = upsample_linear(np.asarray(filtered, np.float32), k,
                                       (rows.stop - rows.start, cols.stop - cols.start))
        area = self._evidence[rows, cols]
        np.maximum(area, filtered, out=area)

    def _back_projection(self, scan: SpadScan, los, known: np.ndarray):
        """The raw back-projection patch of the window."""
        return back_project_patch(scan, los, self.nlos_cfg, known)

    def __call__(self, frame: SpadFrame, map_frame: MapFrame, pose: Pose2D, known: np.ndarray,
                 pose_covariance: Optional[PoseCovariance] = None, map_walls: Optional[np.ndarray] = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Process a measured frame taken at ``pose`` (see the class docstring); ``pose_covariance``: the pose's
        uncertainty, which widens the carving margins (None: the pose is exact); ``map_walls``: the map's wall
        cells (see :meth:`process_scan`)."""
        if pose_covariance is not None and not isinstance(pose_covariance, PoseCovariance):
            raise ValueError(f"pose_covariance must be a PoseCovariance or None, got {type(pose_covariance).__name__}")
        sigma = (0.0, 0.0) if pose_covariance is None else (pose_covariance.sigma_xy_m, pose_covariance.sigma_yaw_rad)
        return self.process_scan(scan_from_frame(frame, map_frame, pose, self.sensor), known, sigma, map_walls)
