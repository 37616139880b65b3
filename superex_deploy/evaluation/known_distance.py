"""Accuracy and calibration of a predicted map by distance from known space, and the strength of a periodic
lattice in it.

A map predictor sees the known cells; how well it does on an unknown cell depends on how far that cell lies from
them (a wall 1 m past a frontier continues what is seen, one 15 m away is a guess from the floor's statistics).
:func:`counts_by_distance` splits the unknown cells of one prediction into distance bins (:data:`DISTANCE_BINS_M`,
metres from the nearest known cell) and keeps, per bin, additive counts (:class:`CalibrationCounts`): adding the
counts of many predictions pools them cell by cell, and :meth:`CalibrationCounts.summary` turns them into wall
IoU, true wall share, mean predicted probability, share predicted walls, expected calibration error, negative
log-likelihood and Brier score.

:func:`lattice_strength` measures a structure no floor has but a network with stride-2 stages can make: a
pattern that repeats every ``period`` cells in rows and columns, locked to the array's origin (the network's
grid). It is the share of the prediction's variance over a region that the ``period x period`` phase means
explain, and the peak-to-peak range of those means (probability).

Everything here is numpy on arrays (the distance transform is :func:`scipy.ndimage.distance_transform_edt`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import NamedTuple, Optional, Sequence

import numpy as np
from scipy import ndimage

__all__ = ["DISTANCE_BINS_M", "PROBABILITY_BINS", "NLL_EPSILON", "CalibrationCounts", "LatticeStrength",
           "distance_to_known", "distance_bin_label", "counts_by_distance", "pool_counts", "phase_means",
           "LATTICE_MIN_CELLS", "lattice_strength"]

DISTANCE_BINS_M: tuple[tuple[float, float], ...] = ((0.0, 2.0), (2.0, 5.0), (5.0, 10.0), (10.0, math.inf))
"""Distance bins, metres from the nearest known cell, ``low < d <= high`` (an unknown cell next to a known one is
one cell, 0.1 m at the models' resolution, away): 0-2 m is what a frontier's surroundings show, past 10 m the
predictor has only the floor's statistics and what it infers from far away."""

PROBABILITY_BINS = 10
"""Equal-width probability bins of the reliability summary (expected calibration error)."""

NLL_EPSILON = 1e-4
"""Predicted probabilities are clipped to ``[eps, 1 - eps]`` for the negative log-likelihood, so one confident
miss costs at most ``-log(eps)`` = 9.2 nats instead of infinity."""


def distance_to_known(unknown: np.ndarray, resolution_m: float) -> np.ndarray:
    """float64 ``[H, W]``: metres from each cell to the nearest known cell (Euclidean, cell centres).

    Args:
        unknown: bool ``[H, W]``, True where the map is unknown.
        resolution_m: metres per cell (> 0).

    Returns:
        0 on known cells; ``inf`` everywhere when no cell is known (no distance to measure from).
    """
    unknown = np.asarray(unknown, bool)
    if unknown.ndim != 2:
        raise ValueError(f"unknown must be a 2-D mask, got shape {unknown.shape}")
    if not resolution_m > 0.0:
        raise ValueError(f"resolution_m must be positive, got {resolution_m}")
    if unknown.all():
        return np.full(unknown.shape, math.inf)
    return ndimage.distance_transform_edt(unknown) * float(resolution_m)


def distance_bin_label(low: float, high: float) -> str:
    """``"0-2 m"``, ``">10 m"``: a bin's name in tables and JSON."""
    return f">{low:g} m" if math.isinf(high) else f"{low:g}-{high:g} m"


@dataclass
class CalibrationCounts:
    """Additive counts of predicted wall probabilities against true walls over a set of cells (``a + b`` pools
    two sets; :meth:`summary` gives the measures).

    Attributes:
        cells: cells counted.
        walls: cells that are true walls.
        predicted: cells predicted walls (probability >= the threshold of :meth:`from_cells`).
        hits: cells both.
        sum_p: sum of the predicted probabilities.
        sum_nll: sum of ``-log p`` on walls and ``-log(1 - p)`` elsewhere (nats, p clipped by :data:`NLL_EPSILON`).
        sum_squared: sum of ``(p - y)^2`` (Brier).
        bin_cells, bin_p, bin_walls: per probability bin (:data:`PROBABILITY_BINS` equal-width bins of [0, 1], 1.0
            in the last): cells, sum of p, true walls.
    """

    cells: int = 0
    walls: int = 0
    predicted: int = 0
    hits: int = 0
    sum_p: float = 0.0
    sum_nll: float = 0.0
    sum_squared: float = 0.0
    bin_cells: list = field(default_factory=lambda: [0] * PROBABILITY_BINS)
    bin_p: list = field(default_factory=lambda: [0.0] * PROBABILITY_BINS)
    bin_walls: list = field(default_factory=lambda: [0] * PROBABILITY_BINS)

    @classmethod
    def from_cells(cls, probability: np.ndarray, wall: np.ndarray, threshold: float = 0.5) -> "CalibrationCounts":
        """Counts of 1-D (or any shape) arrays of the same shape: ``probability`` float in [0, 1], ``wall`` bool."""
        p = np.asarray(probability, np.float64).ravel()
        y = np.asarray(wall, bool).ravel()
        if p.shape != y.shape:
            raise ValueError(f"probability has {p.size} cells, wall has {y.size}")
        if p.size and (not np.isfinite(p).all() or p.min() < 0.0 or p.max() > 1.0):
            raise ValueError("probabilities must be finite and lie in [0, 1]")
        called = p >= threshold
        clipped = np.clip(p, NLL_EPSILON, 1.0 - NLL_EPSILON)
        index = np.minimum((p * PROBABILITY_BINS).astype(np.int64), PROBABILITY_BINS - 1)
        return cls(cells=int(p.size), walls=int(y.sum()), predicted=int(called.sum()), hits=int((called & y).sum()),
                   sum_p=float(p.sum()), sum_nll=float(-np.where(y, np.log(clipped), np.log1p(-clipped)).sum()),
                   sum_squared=float(((p - y) ** 2).sum()),
                   bin_cells=np.bincount(index, minlength=PROBABILITY_BINS).tolist(),
                   bin_p=np.bincount(index, p, minlength=PROBABILITY_BINS).tolist(),
                   bin_walls=np.bincount(index[y], minlength=PROBABILITY_BINS).tolist())

    def __add__(self, other: "CalibrationCounts") -> "CalibrationCounts":
        return CalibrationCounts(
            cells=self.cells + other.cells, walls=self.walls + other.walls, predicted=self.predicted + other.predicted,
            hits=self.hits + other.hits, sum_p=self.sum_p + other.sum_p, sum_nll=self.sum_nll + other.sum_nll,
            sum_squared=self.sum_squared + other.sum_squared,
            bin_cells=[a + b for a, b in zip(self.bin_cells, other.bin_cells)],
            bin_p=[a + b for a, b in zip(self.bin_p, other.bin_p)],
            bin_walls=[a + b for a, b in zip(self.bin_walls, other.bin_walls)])

    def summary(self) -> dict:
        """The measures, each None over no cells.

        ``iou``: wall IoU ``hits / (walls + predicted - hits)`` (1.0 when neither has a cell, as
        :func:`superex_deploy.evaluation.metrics.map_iou`); ``wall_share``: true walls / cells; ``mean_p``: mean
        predicted probability (calibrated: equal to ``wall_share``); ``predicted_share``: cells predicted walls /
        cells; ``ece``: expected calibration error, ``sum_b cells_b / cells * |mean p_b - wall share_b|`` over the
        probability bins; ``nll``: mean negative log-likelihood (nats per cell); ``brier``: mean squared error.
        """
        if self.cells == 0:
            return {"cells": 0, "iou": None, "wall_share": None, "mean_p": None, "predicted_share": None,
                    "ece": None, "nll": None, "brier": None}
        union = self.walls + self.predicted - self.hits
        ece = sum(abs(p - w) for p, w in zip(self.bin_p, self.bin_walls)) / self.cells
        return {"cells": self.cells, "iou": self.hits / union if union else 1.0, "wall_share": self.walls / self.cells,
                "mean_p": self.sum_p / self.cells, "predicted_share": self.predicted / self.cells, "ece": ece,
                "nll": self.sum_nll / self.cells, "brier": self.sum_squared / self.cells}

    def to_dict(self) -> dict:
        """JSON-ready counts (:meth:`from_dict` reads them back)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, values: dict) -> "CalibrationCounts":
        return cls(**{f.name: values[f.name] for f in fields(cls)})


def counts_by_distance(probability: np.ndarray, wall: np.ndarray, unknown: np.ndarray, resolution_m: float,
                       area: Optional[np.ndarray] = None,
                       bins: Sequence[tuple[float, float]] = DISTANCE_BINS_M,
                       threshold: float = 0.5, distance: Optional[np.ndarray] = None) -> dict[str, CalibrationCounts]:
    """The :class:`CalibrationCounts` of the unknown cells of one prediction, per distance bin.

    Args:
        probability: float ``[H, W]`` predicted wall probability in [0, 1].
        wall: bool ``[H, W]`` true walls.
        unknown: bool ``[H, W]`` cells unknown to the predictor (the only cells scored; distances are measured
            from the others).
        resolution_m: metres per cell.
        area: bool ``[H, W]`` where to score (e.g. :func:`superex_deploy.evaluation.metrics.evaluation_area`); None:
            everywhere.
        bins: ``(low, high]`` metres, labelled by :func:`distance_bin_label`.
        threshold: probability from which a cell is predicted a wall.
        distance: :func:`distance_to_known` of ``unknown`` if already computed (metres).

    Returns:
        ``{label: counts}`` in the order of ``bins`` (a bin with no cell has zero counts).
    """
    probability = np.asarray(probability)
    unknown = np.asarray(unknown, bool)
    if probability.shape != unknown.shape or np.shape(wall) != unknown.shape:
        raise ValueError(f"probability {probability.shape}, wall {np.shape(wall)} and unknown {unknown.shape} must "
                         f"have one shape")
    scored = unknown if area is None else unknown & np.asarray(area, bool)
    distance = distance_to_known(unknown, resolution_m) if distance is None else distance
    wall = np.asarray(wall, bool)
    out = {}
    for low, high in bins:
        cells = scored & (distance > low) & (distance <= high)
        out[distance_bin_label(low, high)] = CalibrationCounts.from_cells(probability[cells], wall[cells], threshold)
    return out


def pool_counts(per_prediction: Sequence[dict[str, CalibrationCounts]]) -> dict[str, CalibrationCounts]:
    """Sum of :func:`counts_by_distance` results bin by bin (the bins of the first; empty input: ``{}``)."""
    pooled: dict[str, CalibrationCounts] = {}
    for counts in per_prediction:
        for label, value in counts.items():
            pooled[label] = pooled.get(label, CalibrationCounts()) + value
    return pooled


class LatticeStrength(NamedTuple):
    """How much of a prediction over a region is a pattern of period ``period`` locked to the array's origin.

    Attributes:
        share: variance of the phase means (cell-weighted) over the variance of the prediction, in [0, 1]: 1 for a
            pure lattice, about ``period ** 2 / cells`` for noise with no period.
        amplitude: peak-to-peak range of the phase means (probability units).
        cells: cells of the region.
    """

    share: float
    amplitude: float
    cells: int


LATTICE_MIN_CELLS = 1024
"""Fewer cells than this in a region (16 a phase of a period-8 lattice) give no lattice measure in the model
evaluations (``scripts/eval_models.py``, ``scripts/study_lattice.py``)."""


def phase_means(values: np.ndarray, region: np.ndarray, period: int, offset: int = 0
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(means, counts)``, float64 and int64 ``[period * period]``: the mean of ``values`` (``[H, W]``) over the
    bool ``[H, W]`` ``region`` per phase ``((r - offset) mod period, (c - offset) mod period)`` of cell ``(r, c)``,
    index ``row_phase * period + col_phase``, and the region's cells per phase (a phase without one: mean 0)."""
    rows, cols = np.nonzero(region)
    phase = ((rows - offset) % period) * period + (cols - offset) % period
    counts = np.bincount(phase, minlength=period * period)
    sums = np.bincount(phase, np.asarray(values, np.float64)[rows, cols], minlength=period * period)
    return sums / np.maximum(counts, 1), counts


def lattice_strength(probability: np.ndarray, region: np.ndarray, period: int) -> LatticeStrength:
    """:class:`LatticeStrength` of ``probability`` (float ``[H, W]``) over the bool ``[H, W]`` ``region``.

    Cell ``(r, c)`` has phase ``(r mod period, c mod period)``; the phase means are the region's mean per phase.
    A region with no variance (below 1e-12 per cell: rounding) has share 0.

    Raises:
        ValueError: ``period < 2``, shapes that differ, an empty region.
    """
    if int(period) < 2:
        raise ValueError(f"period must be >= 2 cells, got {period}")
    period = int(period)
    probability = np.asarray(probability, np.float64)
    region = np.asarray(region, bool)
    if probability.shape != region.shape or probability.ndim != 2:
        raise ValueError(f"probability {probability.shape} and region {region.shape} must be one 2-D shape")
    rows, cols = np.nonzero(region)
    if rows.size == 0:
        raise ValueError("the region has no cell")
    values = probability[rows, cols]
    means, counts = phase_means(probability, region, period)
    centre = values.mean()
    total = float(((values - centre) ** 2).sum())
    between = float((counts * (means - centre) ** 2).sum())
    present = means[counts > 0]
    flat = total <= 1e-12 * values.size  # rounding of a constant field, not structure
    return LatticeStrength(share=0.0 if flat else min(between / total, 1.0),
                           amplitude=float(present.max() - present.min()), cells=int(rows.size))
