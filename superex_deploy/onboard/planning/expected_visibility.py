"""Expected visibility: a viewpoint scored by the expected number of unknown cells it reveals.

The thresholded gain of :mod:`~superex_deploy.onboard.planning.visibility` turns the prediction into a map (a cell blocks a
ray when its wall probability reaches a threshold) and counts what that map shows. Here the prediction is read as
what it is, a probability per cell (the ensembles are calibrated: the mean is the expected wall indicator):

* every cell has a wall probability ``p``: known free cells 0, known walls 1, unknown cells the prediction's mean;
* along ray ``k`` the cells are walls together (comonotone: one uniform draw ``u`` per ray, a cell is a wall when
  ``u < p``), so the **transmittance** to a cell, the probability that the ray reaches it, is ``1 - max p`` over
  the cells the ray crossed before it: the largest probability any dependence between the cells allows (Frechet);
* a cell reached is revealed, wall or free (seeing a wall is information too), so an unknown cell contributes
  the transmittance *up to and including it*, i.e. over the cells before it, not of the cell itself;
* each unknown cell counts once per viewpoint (and once per group of viewpoints, the pathwise gain), with the
  **largest** transmittance of the rays that reach it: ``P(seen) ~ max_k P(ray k reaches the cell)``.

Rays that leave the robot side by side cross the same cells near it, so their events are strongly correlated: the
product rule ``1 - prod(1 - T_k)`` would treat them as independent and overcount. Where a single uncertain cell,
or none, lies in front of a cell on every ray, the gain is exact whatever the dependence
(``tests/test_expected_visibility.py`` checks it against a brute-force enumeration of every wall configuration).

The rays are those of the thresholded cast (``n_rays`` over a full turn from the viewpoint cell's centre, out to
``range_m``; Amanatides-Woo stepping), without the polygon fill: a cell between two rays far from the viewpoint
is not counted, so on a binary map the expected gain counts the cells the rays cross, fewer than the filled
polygon at long range. The viewpoint's own cell is taken as free (the robot stands in it) and counted with
probability 1 if unknown; a viewpoint on a known wall sees nothing. A ray stops when its transmittance falls to
``min_transmittance`` (default 1e-3: what it could still add is below a thousandth of a cell per cell) or
leaves the grid.

The cells of a ray taken as independent walls (the product of ``1 - p``) was measured and retired: a learned
prediction spreads a little wall probability over every unknown cell, and the product over many such cells soon
vanishes (over 60 cells of 0.05 it is 0.05), so it cut the rays much shorter than the thresholded cast
(docs/benchmarks/better-map.md, "Reading predictions as probabilities").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.geometry import dda_start, dda_step
from superex_deploy.onboard.types import check_observed
from superex_deploy.onboard.planning.visibility import MAX_RAYS, check_cells, check_map

__all__ = ["ExpectedVisibility", "expected_visible_gains"]


@dataclass(frozen=True)
class ExpectedVisibility(JsonConfig):
    """The rays of an expected-visibility cast.

    Attributes:
        n_rays: rays over a full turn from each viewpoint, an integer in ``[3,`` :data:`MAX_RAYS` ``]``.
        range_m: ray range in metres (positive, finite).
        min_transmittance: a ray stops once its transmittance is at most this, in ``[0, 1)`` (0: only a certain
            wall or the range stops it).

    Raises:
        ValueError: a field of another type or out of its range, named.
    """

    n_rays: int = 250
    range_m: float = 20.0
    min_transmittance: float = 1e-3

    def __post_init__(self) -> None:
        from superex_deploy.onboard.checks import check_int, check_real

        object.__setattr__(self, "n_rays", check_int("n_rays", self.n_rays, 3, MAX_RAYS))
        object.__setattr__(self, "range_m", check_real("range_m", self.range_m, 0.0, low_open=True))
        object.__setattr__(self, "min_transmittance", check_real("min_transmittance", self.min_transmittance, 0.0,
                                                                 1.0, high_open=True))


@numba.njit(cache=True)
def _cast_expected(mean, observed, rows, cols, n_rays, max_t, min_transmittance, stamp, slot):
    """Per viewpoint ``v`` (cell ``rows[v], cols[v]``), the unknown cells its rays reach and the largest
    transmittance to each (``1 - max p`` over the cells a ray crossed before the cell; ``p`` = 0 on known free
    cells, 1 on known walls, ``mean`` on unknown ones). The
    viewpoint's own cell, unless a known wall (then nothing is seen), is seen with transmittance 1.

    ``stamp`` (int32 ``[H, W]``, all -1) and ``slot`` (int64 ``[H, W]``) are scratch: a cell stamped ``v`` holds
    its index into the output in ``slot``. Returns ``(cells int64 [M], transmittance float64 [M], offsets int64
    [V + 1])``: viewpoint ``v``'s flat cell indices and transmittances are ``[offsets[v], offsets[v + 1])``."""
    n_rows, n_cols = mean.shape
    n_view = rows.shape[0]
    # A ray of length L enters at most 2 L + 2 cells; a viewpoint adds at most that many entries per ray, bounded
    # by the map's size.
    per_view = min(n_rays * (2 * int(np.ceil(max_t)) + 2) + 1, n_rows * n_cols)
    cells = np.empty(per_view, np.int64)
    trans = np.empty(per_view, np.float64)
    offsets = np.zeros(n_view + 1, np.int64)
    n = 0
    for v in range(n_view):
        r0, c0 = rows[v], cols[v]
        if observed[r0, c0] == 1:
            offsets[v + 1] = n
            continue
        if n + per_view > cells.shape[0]:  # room for this viewpoint's entries (amortised doubling)
            size = max(2 * cells.shape[0], n + per_view)
            grown_cells = np.empty(size, np.int64)
            grown_trans = np.empty(size, np.float64)
            grown_cells[:n] = cells[:n]
            grown_trans[:n] = trans[:n]
            cells, trans = grown_cells, grown_trans
        if observed[r0, c0] == -1:
            stamp[r0, c0] = v
            slot[r0, c0] = n
            cells[n] = r0 * n_cols + c0
            trans[n] = 1.0
            n += 1
        y0, x0 = r0 + 0.5, c0 + 0.5
        for k in range(n_rays):
            angle = 2.0 * np.pi * k / n_rays
            r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c, t_delta_c = dda_start(
                y0, x0, np.sin(angle), np.cos(angle))
            transmittance = 1.0
            blocked = 0.0  # the largest wall probability crossed so far
            while True:
                r, c, t_next_r, t_next_c, t, _ = dda_step(r, c, step_r, t_next_r, t_delta_r, step_c, t_next_c,
                                                          t_delta_c)
                if t >= max_t or r < 0 or r >= n_rows or c < 0 or c >= n_cols:
                    break
                code = observed[r, c]
                if code == 1:
                    break
                if code == -1:
                    if stamp[r, c] != v:
                        stamp[r, c] = v
                        slot[r, c] = n
                        cells[n] = r * n_cols + c
                        trans[n] = transmittance
                        n += 1
                    elif transmittance > trans[slot[r, c]]:
                        trans[slot[r, c]] = transmittance
                    blocked = max(blocked, mean[r, c])
                    transmittance = 1.0 - blocked
                    if transmittance <= min_transmittance:
                        break
        offsets[v + 1] = n
    return cells[:n], trans[:n], offsets


@numba.njit(cache=True)
def _union_expected(cells, trans, offsets, members, group_offsets, variance, stamp, best):
    """Per group ``g`` (viewpoints ``members[group_offsets[g]:group_offsets[g + 1]]``), the sum over the unknown
    cells its viewpoints reach of the largest transmittance to each, and of that transmittance times the cell's
    ``variance`` (flat float32). ``stamp`` (int32 flat, all -1) and ``best`` (float64 flat) are scratch."""
    n_groups = group_offsets.shape[0] - 1
    expected = np.zeros(n_groups)
    expected_variance = np.zeros(n_groups)
    for g in range(n_groups):
        count, var_sum = 0.0, 0.0
        for m in range(group_offsets[g], group_offsets[g + 1]):
            v = members[m]
            for i in range(offsets[v], offsets[v + 1]):
                cell, value = cells[i], trans[i]
                if stamp[cell] != g:
                    stamp[cell] = g
                    best[cell] = value
                    count += value
                    var_sum += value * variance[cell]
                elif value > best[cell]:
                    count += value - best[cell]
                    var_sum += (value - best[cell]) * variance[cell]
                    best[cell] = value
        expected[g] = count
        expected_variance[g] = var_sum
    return expected, expected_variance


def expected_visible_gains(mean: np.ndarray, observed: np.ndarray, viewpoints: list, cfg: ExpectedVisibility,
                           resolution_m: float, variance: Optional[np.ndarray] = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Expected number of currently unknown cells seen from each group of viewpoints (see the module docstring).

    Args:
        mean: float32 ``[H, W]`` wall probability of the unknown cells (known cells are read from ``observed``),
            in [0, 1].
        observed: int8 ``[H, W]`` observed map (UNKNOWN = -1, FREE = 0, OCCUPIED = 1).
        viewpoints: ``N`` lists of viewpoint cells (row, col); a group's unknown cells count once, with the
            largest transmittance from any of its viewpoints; a cell shared by several groups is cast once.
        cfg: rays, range and cut-off.
        resolution_m: metres per cell.
        variance: optional float32 ``[H, W]`` per-cell variance (the ensemble's spread).

    Returns:
        ``(expected float64 [N], expected_variance float64 [N])``: per group the sum over unknown cells of
        ``P(seen)`` (cells), and of ``P(seen) x variance`` (zeros without ``variance``); 0 for an empty group.

    Raises:
        ValueError: arrays of another dtype or shape, a mean outside [0, 1] or not finite, a viewpoint outside
            the map, a resolution that is not positive and finite.
    """
    mean = check_map("mean", mean, np.float32)
    observed = np.ascontiguousarray(check_observed(observed, mean.shape))
    if not np.all((mean >= 0.0) & (mean <= 1.0)):  # also refuses NaN
        raise ValueError("mean must hold wall probabilities in [0, 1]")
    if variance is None:
        variance = np.zeros(mean.shape, np.float32)
    variance = check_map("variance", variance, np.float32, mean.shape)
    if not (np.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"resolution_m must be positive and finite, got {resolution_m}")
    index: dict = {}
    members, group_offsets = [], [0]
    for group in viewpoints:
        for r, c in (check_cells(group, mean.shape) if len(group) else ()):
            members.append(index.setdefault((int(r), int(c)), len(index)))
        group_offsets.append(len(members))
    unique = np.array(list(index), np.int64).reshape(-1, 2)
    stamp = np.full(mean.shape, -1, np.int32)
    cells, trans, offsets = _cast_expected(mean, observed, unique[:, 0].copy(), unique[:, 1].copy(), cfg.n_rays,
                                           cfg.range_m / float(resolution_m), cfg.min_transmittance, stamp,
                                           np.empty(mean.shape, np.int64))
    stamp.fill(-1)
    return _union_expected(cells, trans, offsets, np.array(members, np.int64), np.array(group_offsets, np.int64),
                           variance.ravel(), stamp.ravel(), np.empty(mean.size, np.float64))
