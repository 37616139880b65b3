"""The simulator's ground truth of one SPAD scan (:class:`SpadTruth`): per primary ray its first wall hit, per fan
its secondary hits, per three-bounce path its photons. Labels and tests read it; the NLOS processing never does.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["SpadTruth"]


@dataclass(frozen=True, eq=False)
class SpadTruth:
    """Simulation-only ground truth (labels and tests; never read by the NLOS processing).

    Stored per fan (one per distinct primary-hit cell) as rows of the grid's fan cache (:class:`FanCache`; rows
    are written once and never changed, so a truth stays valid however the cache grows later); the per-fan and
    per-path arrays are gathered on first access.

    Attributes:
        h1_rc: int32 ``[n_rays, 2]`` first wall cell of each primary ray, -1 where none within range.
        d1_m: float64 ``[n_rays]`` distance to ``h1`` (metres; NaN where no hit).
        normal1: float64 ``[n_rays, 2]`` unit outward normal ``(dy, dx)`` at ``h1`` facing the robot (0 if none).
        cos1: float64 ``[n_rays]`` incidence cosine of the primary at ``h1`` (0 if none).
        ray_fan: int64 ``[n_rays]`` fan index of each primary ray, -1 where it hit nothing.
        fan_rows: int64 ``[n_fans]`` row of each fan in ``fan_store``.
        fan_store: the cache's arrays ``(d2_m, cos2, h2_rc)`` as they were when the scan was taken.
        three_bounce_scale: eq. (2) without its geometric factor (see :meth:`SpadConfig.three_bounce_scale`).
    """

    h1_rc: np.ndarray
    d1_m: np.ndarray
    normal1: np.ndarray
    cos1: np.ndarray
    ray_fan: np.ndarray
    fan_rows: np.ndarray
    fan_store: tuple[np.ndarray, np.ndarray, np.ndarray]
    three_bounce_scale: float

    @cached_property
    def fan_h2_rc(self) -> np.ndarray:
        """int32 ``[n_fans, n_secondary, 2]`` secondary hit cells (-1: no hit within range)."""
        return self.fan_store[2][self.fan_rows]

    @cached_property
    def fan_d2_m(self) -> np.ndarray:
        """float64 ``[n_fans, n_secondary]`` distance from the fan origin ``X1`` to ``h2`` (NaN: no hit)."""
        return self.fan_store[0][self.fan_rows]

    @cached_property
    def fan_cos2(self) -> np.ndarray:
        """float64 ``[n_fans, n_secondary]`` clamped incidence cosine at ``h2`` (0: back-facing)."""
        return self.fan_store[1][self.fan_rows]

    @cached_property
    def _paths(self) -> tuple[np.ndarray, np.ndarray]:
        rays = np.flatnonzero(self.ray_fan >= 0)
        hit = self.fan_h2_rc[self.ray_fan[rays], :, 0] >= 0
        ray_index, slot = np.nonzero(hit)
        return rays[ray_index], slot

    @property
    def h2_ray(self) -> np.ndarray:
        """int32 ``[M]``: the primary ray of every secondary hit, over all primary rays."""
        return self._paths[0].astype(np.int32)

    @property
    def h2_rc(self) -> np.ndarray:
        """int32 ``[M, 2]``: every secondary hit cell (aligned with :attr:`h2_ray`)."""
        rays, slot = self._paths
        return self.fan_h2_rc[self.ray_fan[rays], slot].astype(np.int32)

    @property
    def d2_m(self) -> np.ndarray:
        """float64 ``[M]``: ``d2`` of every secondary hit (metres)."""
        rays, slot = self._paths
        return self.fan_d2_m[self.ray_fan[rays], slot]

    @property
    def h2_counts(self) -> np.ndarray:
        """float64 ``[M]``: expected photons of every three-bounce path (eq. 2; 0 when back-facing)."""
        rays, slot = self._paths
        fan = self.ray_fan[rays]
        return (self.three_bounce_scale * self.cos1[rays] * self.fan_cos2[fan, slot]
                / (self.d1_m[rays] * self.fan_d2_m[fan, slot] ** 2))
