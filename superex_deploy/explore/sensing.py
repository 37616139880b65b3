"""NLOS sensing inside an episode: a SPAD scan at every step, its carved cells and filtered evidence."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.explore.types import UNKNOWN
from superex_deploy.maps import OccupancyGrid
from superex_deploy.nlos import NlosConfig, back_project, carve, estimate_los, process_scan
from superex_deploy.spad import SpadConfig, simulate_scan

__all__ = ["SpadSensing"]


@dataclass
class SpadSensing:
    """The :class:`~superex_deploy.explore.episode.NlosHook` of the SPAD pipeline.

    Each call simulates a scan at the robot's cell, processes it with the currently known cells masked out of
    the back-projection, and returns ``(carved bool [H, W], evidence float32 [H, W])``. The evidence is the
    running maximum of the filtered back-projection over the episode, so hidden walls glimpsed
    earlier stay available to the predictor.

    Attributes:
        spad: sensor configuration.
        nlos: processing configuration.
        seed: seed of the noise generator (used only when ``spad.noise.enabled``).
        bp_filter: turns the raw back-projection (float32 ``[H, W]`` in [0, 1]) and the robot cell into the
            filtered evidence (float32 ``[H, W]`` in [0, 1]), e.g.
            :meth:`superex_deploy.inference.Pix2PixFilter.filter_map`; None: the Laplacian baseline.
    """

    spad: SpadConfig = field(default_factory=SpadConfig)
    nlos: NlosConfig = field(default_factory=NlosConfig)
    seed: int = 0
    bp_filter: Optional[Callable[[np.ndarray, tuple[int, int]], np.ndarray]] = None
    _evidence: Optional[np.ndarray] = field(default=None, init=False, repr=False)
    _rng: Optional[np.random.Generator] = field(default=None, init=False, repr=False)

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` running maximum of the filtered back-projection so far (None before the first scan)."""
        return self._evidence

    def __call__(self, grid: OccupancyGrid, pose_rc: tuple[int, int], observed: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        if self._rng is None:
            self._rng = np.random.default_rng(self.seed)
        scan = simulate_scan(grid, pose_rc, self.spad, rng=self._rng if self.spad.noise.enabled else None)
        if self._evidence is None or self._evidence.shape != grid.shape:
            self._evidence = np.zeros(grid.shape, np.float32)
        if self.bp_filter is None:
            result = process_scan(scan, self.nlos, known=observed != UNKNOWN)
            # Only the filtered window can raise the running maximum.
            area = result.bp_filtered_patch.slices
            np.maximum(self._evidence[area], result.bp_filtered_patch.values, out=self._evidence[area])
            return result.carved, self._evidence
        # The learned filter replaces the Laplacian one: do not compute that too.
        los = estimate_los(scan, self.nlos)
        filtered = self.bp_filter(back_project(scan, los, self.nlos, observed != UNKNOWN), pose_rc)
        np.maximum(self._evidence, filtered, out=self._evidence)
        return carve(scan, los, self.nlos), self._evidence
