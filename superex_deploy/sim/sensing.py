"""NLOS sensing in simulated episodes: the SPAD sensor (simulated from the truth, in the world) and its processing
(on the robot), configured together.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from superex_deploy.onboard.types import OCCUPIED, UNKNOWN
from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.nlos import NlosConfig
from superex_deploy.onboard.nlos.processing import NlosSkips, SpadProcessing
from superex_deploy.spad_types import SpadConfig
from superex_deploy.sim.spad import simulate_scan

__all__ = ["SpadSensing"]


@dataclass
class SpadSensing:
    """The SPAD pipeline of a simulated episode: the world simulates a scan at every step (:attr:`spad`,
    :attr:`seed`), the explorer processes it (:meth:`processing`: carving and the evidence the predictor reads).

    Attributes:
        spad: sensor configuration (the simulator's and the processing's sensor model).
        nlos_cfg: processing configuration.
        seed: seed of the noise generator (used only when ``spad.noise.enabled``).
        bp_filter: turns the raw back-projection (float32 ``[H, W]`` in [0, 1]) and the robot cell into the
            filtered evidence (float32 ``[H, W]`` in [0, 1]), e.g.
            :meth:`superex_deploy.onboard.prediction.inference.Pix2PixFilter.filter_map`; None: the Laplacian baseline.
        skips: work the processing may leave out (:class:`~superex_deploy.onboard.nlos.processing.NlosSkips`).
    """

    spad: SpadConfig = field(default_factory=SpadConfig)
    nlos_cfg: NlosConfig = field(default_factory=NlosConfig)
    seed: int = 0
    bp_filter: Optional[Callable[[np.ndarray, tuple[int, int]], np.ndarray]] = None
    skips: NlosSkips = field(default_factory=NlosSkips)
    _processing: Optional[SpadProcessing] = field(default=None, init=False, repr=False)
    _rng: Optional[np.random.Generator] = field(default=None, init=False, repr=False)

    def make_processing(self) -> SpadProcessing:
        """The onboard :class:`SpadProcessing` an episode runs (a subclass may return another, e.g. one that also
        measures the processing it would replace)."""
        return SpadProcessing(sensor=self.spad, nlos_cfg=self.nlos_cfg, bp_filter=self.bp_filter, skips=self.skips)

    def processing(self) -> SpadProcessing:
        """A fresh onboard :class:`SpadProcessing` for one episode (:meth:`make_processing`); :attr:`evidence`
        and :attr:`current_processing` follow it."""
        self._processing = self.make_processing()
        return self._processing

    @property
    def current_processing(self) -> Optional[SpadProcessing]:
        """The processing of the current episode (its counters say what it left out), or None before one."""
        return self._processing

    @property
    def evidence(self) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` running maximum of the filtered back-projection so far (None before the first scan)."""
        return None if self._processing is None else self._processing.evidence

    def __call__(self, grid: OccupancyGrid, pose_rc: tuple[int, int], observed: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Simulate one scan at ``pose_rc`` and process it against the int8 ``observed`` map; returns
        ``(carved bool [H, W], evidence float32 [H, W])``. Successive calls share the running evidence."""
        if self._rng is None:
            self._rng = np.random.default_rng(self.seed)
        if self._processing is None:
            self.processing()
        scan = simulate_scan(grid, pose_rc, self.spad, rng=self._rng if self.spad.noise.enabled else None)
        walls = observed == OCCUPIED if self._processing.reads_map_walls else None
        return self._processing.process_scan(scan, observed != UNKNOWN, map_walls=walls)
