"""NLOS processing of measured SPAD frames on the robot: space carving and (filtered) back-projection evidence.

Reads only the :class:`~superex_deploy.messages.SpadFrame`, the pose and the explorer's own map; the sensor model
(:class:`~superex_deploy.spad_types.SpadConfig`: bin width, range, noise model, secondary-ray count for the carving cap) is
the robot's calibration of its sensor, not the simulator's truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.messages import MapFrame, Pose2D, SpadFrame, grid_angles
from superex_deploy.onboard.nlos import NlosConfig, back_project, carve, estimate_los, process_scan
from superex_deploy.spad_types import SpadConfig, SpadScan, SparseHistograms

__all__ = ["SpadProcessing", "scan_from_frame"]


def scan_from_frame(frame: SpadFrame, map_frame: MapFrame, pose: Pose2D, sensor: SpadConfig) -> SpadScan:
    """The :class:`~superex_deploy.spad_types.SpadScan` (no ground truth) of a measured frame taken at ``pose``.

    Raises:
        ValueError: a frame whose bin count or bin width differs from the sensor model's, or a pose outside the
            map.
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
    origin, cell = map_frame.locate(pose.x, pose.y)
    angles = grid_angles(pose.yaw, frame.angles)
    stored = SparseHistograms(np.asarray(frame.row_start), np.asarray(frame.bins), np.asarray(frame.counts),
                              frame.n_bins)
    return SpadScan(angles=angles, origin_yx=origin, pose_rc=cell, bin_path_m=sensor.bin_path_m,
                    resolution_m=map_frame.resolution_m, grid_shape=map_frame.shape, config=sensor, stored=stored)


@dataclass
class SpadProcessing:
    """Turns each SPAD frame into carved free cells and the evidence the predictor reads.

    Each call processes one frame with the currently known cells masked out of the back-projection and returns
    ``(carved bool [H, W], evidence float32 [H, W])``; the evidence is the running maximum of the filtered
    back-projection over the episode, so hidden walls glimpsed earlier stay available to the predictor.

    Attributes:
        sensor: the sensor model (bin width, range, noise) the frames must match.
        nlos: processing parameters.
        bp_filter: turns the raw back-projection (float32 ``[H, W]`` in [0, 1]) and the robot cell into the
            filtered evidence (float32 ``[H, W]`` in [0, 1]), e.g.
            :meth:`superex_deploy.onboard.inference.Pix2PixFilter.filter_map`; None: the Laplacian baseline.
    """

    sensor: SpadConfig = field(default_factory=SpadConfig)
    nlos: NlosConfig = field(default_factory=NlosConfig)
    bp_filter: Optional[Callable[[np.ndarray, tuple[int, int]], np.ndarray]] = None
    _evidence: Optional[np.ndarray] = field(default=None, init=False, repr=False, compare=False)

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` running maximum of the filtered back-projection so far (None before the first frame)."""
        return self._evidence

    def reset(self) -> None:
        """Forget the evidence of an earlier episode."""
        self._evidence = None

    def process_scan(self, scan: SpadScan, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Carving and evidence of one scan (simulated or built by :func:`scan_from_frame`); ``known``: bool
        ``[H, W]`` cells the explorer already knows."""
        if self._evidence is None or self._evidence.shape != tuple(scan.grid_shape):
            self._evidence = np.zeros(scan.grid_shape, np.float32)
        if self.bp_filter is None:
            result = process_scan(scan, self.nlos, known=known)
            # Only the filtered window can raise the running maximum.
            area = result.bp_filtered_patch.slices
            np.maximum(self._evidence[area], result.bp_filtered_patch.values, out=self._evidence[area])
            return result.carved, self._evidence
        # The learned filter replaces the Laplacian one: do not compute that too.
        los = estimate_los(scan, self.nlos)
        filtered = self.bp_filter(back_project(scan, los, self.nlos, known), scan.pose_rc)
        np.maximum(self._evidence, filtered, out=self._evidence)
        return carve(scan, los, self.nlos), self._evidence

    def __call__(self, frame: SpadFrame, map_frame: MapFrame, pose: Pose2D, known: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Process a measured frame taken at ``pose`` (see the class docstring)."""
        return self.process_scan(scan_from_frame(frame, map_frame, pose, self.sensor), known)
