"""Predict only what changed: keep the last prediction, re-predict a crop around the cells that changed since.

The LaMa ensemble over a whole large map costs tens of times what it costs on a small crop (measured in
docs/benchmarks/exploration.md). Between two goal choices the map changes only around the robot, so
:class:`ReusingPredictor` keeps the last prediction and the map it was made for, and on the next request

1. counts the cells whose map state changed (and those whose evidence rose by more than
   :attr:`PredictionReuse.evidence_change`); below :attr:`PredictionReuse.min_changed_m2` of them the last prediction,
   merged with the current map (:func:`merge_with_map`), is returned without running the predictor;
2. otherwise, with :attr:`PredictionReuse.crop_margin_m` set, predicts only the bounding box of the changed
   cells grown by that margin on every side (the network's context), and writes the inner part of the result
   (the box grown by half the margin) over the last prediction; cells outside keep the last prediction, merged
   with the current map. Cells at least half a margin away from every change had the same surroundings within
   the other half when the last prediction was made, which is why it stays a good answer there (LaMa's Fourier
   units do see the whole input, so it is not the same answer: the run-time-vs-error benchmark measures what it
   costs).
3. so that the crop leaves no seam (a step between the crop's answer and the last prediction along the edge of
   the part written), the crop is feathered into the last prediction over :attr:`PredictionReuse.feather_m`
   outside that inner part (:func:`feather_weights`): weight 1 on the inner part, falling along a linear or
   cosine ramp to 0 one cell past the ramp's end, which never lies beyond the crop (a ramp is shortened to the
   context band on that side). The weight of a cell is the product of its row's and its column's weight. Mean
   and variance are those of the mixture "the crop's ensemble with weight w, the last prediction's with 1 - w":
   ``mean = w m_crop + (1 - w) m_last``, ``variance = w v_crop + (1 - w) v_last + w (1 - w) (m_crop - m_last)^2``
   (the ensemble's own rule for pooled members; where the two disagree the band is uncertain). ``feather_m = 0``
   is the hard write-back. ``scripts/bench_seams.py`` measures the seam error against whole-map predictions and
   chose the default width on the held-out train floors (``benchmarks/seams/``).

Cells that no prediction ever covered (outside every crop so far) are taken as the map says, unknown = free, as
:class:`~superex_deploy.onboard.prediction.baselines.ObservedAsPrediction` does; they lie more than half a margin from every
cell known when the last prediction was made (cells seen since, while less than ``min_changed_m2`` changed,
are not predicted until the threshold is reached).

Crops are used only with predictors that declare ``accepts_crops = True`` (the LaMa ensembles, the observed and
evidence predictors: their output at a cell depends on the input around it); the oracle reads the whole true map
and always gets the whole observed map.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import cells_at_least
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, MapPredictor, Prediction

__all__ = ["PredictionReuse", "ReusingPredictor", "merge_with_map", "changed_box", "feather_weights", "RAMPS",
           "FEATHER_M"]

RAMPS = ("linear", "cosine")
"""The feathering ramps (:attr:`PredictionReuse.feather_ramp`): over a ramp of ``L`` cells the ``d``-th cell
outside the written part has weight ``1 - d / (L + 1)`` (linear, steepest step ``1 / (L + 1)``) or
``(1 + cos(pi d / (L + 1))) / 2`` (cosine, steepest step at most ``pi / (2 (L + 1))``)."""


FEATHER_M = 3.2
"""The default :attr:`PredictionReuse.feather_m`, linear ramp: the whole context band of the ``realtime`` profile's
6.4 m margin. Chosen on the held-out train scenarios by ``scripts/bench_seams.py``: the lowest error against
whole-map predictions near a seam, and a step across a seam no larger than the whole-map prediction's own
(measured in docs/benchmarks/realtime.md, "Seams")."""


@dataclass(frozen=True)
class PredictionReuse(JsonConfig):
    """What the explorer keeps of its last prediction (the defaults keep nothing: every request runs the
    predictor on the whole map).

    Attributes:
        min_changed_m2: run the predictor only when the cells changed since the map of the last prediction cover at
            least this area (square metres, >= 0; 2 m^2 is 200 cells of 0.1 m, 800 of 0.05 m; 0: always).
        crop_margin_m: predict only the box around the changed cells grown by this many metres of context (None:
            the whole map); see the module docstring.
        evidence_change: an evidence cell (the filtered back-projection, in [0, 1]) counts as changed when it
            rose by more than this since the last prediction.
        feather_m: metres over which a crop's answer is blended into the last prediction outside the part it
            writes (0: hard edges; at most the half margin of context is used, see the module docstring).
        feather_ramp: the ramp's shape, one of :data:`RAMPS`.
    """

    min_changed_m2: float = 0.0
    crop_margin_m: Optional[float] = None
    evidence_change: float = 0.05
    feather_m: float = FEATHER_M
    feather_ramp: str = "linear"

    def __post_init__(self) -> None:
        if not (_is_number(self.min_changed_m2) and self.min_changed_m2 >= 0):
            raise ValueError(f"min_changed_m2 must be a number of square metres >= 0, got {self.min_changed_m2!r}")
        if self.crop_margin_m is not None and not (_is_number(self.crop_margin_m) and self.crop_margin_m > 0):
            raise ValueError(f"crop_margin_m must be a positive number of metres or None, got {self.crop_margin_m!r}")
        if not (_is_number(self.evidence_change) and 0.0 <= self.evidence_change < 1.0):
            raise ValueError(f"evidence_change must lie in [0, 1), got {self.evidence_change!r}")
        if not (_is_number(self.feather_m) and self.feather_m >= 0):
            raise ValueError(f"feather_m must be a number of metres >= 0, got {self.feather_m!r}")
        if self.feather_ramp not in RAMPS:
            raise ValueError(f"feather_ramp must be one of {', '.join(RAMPS)}, got {self.feather_ramp!r}")

    @property
    def reuses(self) -> bool:
        """Whether anything is kept (else the explorer calls the predictor directly)."""
        return self.min_changed_m2 > 0 or self.crop_margin_m is not None


def _is_number(value) -> bool:
    """A finite real number that is not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        and bool(np.isfinite(value))


def merge_with_map(prediction: Prediction, observed: np.ndarray) -> Prediction:
    """A prediction made on an older map, brought up to date: cells known in ``observed`` (int8 ``[H, W]``) take
    their observed value (wall probability 1 or 0, variance 0); unknown cells keep the prediction."""
    unknown = observed == UNKNOWN
    mean = np.where(unknown, prediction.mean, (observed == OCCUPIED).astype(np.float32)).astype(np.float32)
    variance = np.where(unknown, prediction.variance, np.float32(0.0)).astype(np.float32)
    return Prediction(mean=mean, variance=variance)


def changed_box(changed: np.ndarray) -> Optional[tuple[int, int, int, int]]:
    """``(top, left, bottom, right)`` (end-exclusive) of the True cells of bool ``[H, W]`` ``changed``; None if
    there are none."""
    rows = np.flatnonzero(changed.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(changed.any(axis=0))
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def _grow(box: tuple[int, int, int, int], margin: int, shape: tuple[int, int], multiple: int = 1
          ) -> tuple[int, int, int, int]:
    """``box`` grown by ``margin`` cells on every side, clipped to ``shape``, then widened (inside the map) to
    a multiple of ``multiple`` cells where the map allows: the network pads to that multiple anyway, so the
    extra cells are free context."""
    top, left = max(box[0] - margin, 0), max(box[1] - margin, 0)
    bottom, right = min(box[2] + margin, shape[0]), min(box[3] + margin, shape[1])
    if multiple > 1:
        rows = min(-(-(bottom - top) // multiple) * multiple, shape[0])
        cols = min(-(-(right - left) // multiple) * multiple, shape[1])
        extra_rows, extra_cols = rows - (bottom - top), cols - (right - left)
        top = max(top - extra_rows // 2, 0)
        bottom = min(top + rows, shape[0])
        top = bottom - rows
        left = max(left - extra_cols // 2, 0)
        right = min(left + cols, shape[1])
        left = right - cols
    return top, left, bottom, right


def feather_weights(outer: tuple[int, int, int, int], inner: tuple[int, int, int, int], feather_cells: int,
                    ramp: str = "linear") -> tuple[np.ndarray, np.ndarray]:
    """The blending weights of a crop: float32 ``[rows]`` and ``[cols]`` of the ``outer`` box (``(top, left,
    bottom, right)``, end-exclusive, map cells), whose outer product is a cell's weight (see the module docstring).

    A row (column) inside ``inner`` weighs 1; the ``d``-th one outside weighs the :data:`RAMPS` ``ramp`` of length
    ``L = min(feather_cells, cells between inner and outer on that side)`` at ``d``, 0 past ``L``.

    Raises:
        ValueError: ``inner`` not inside ``outer``, a negative ``feather_cells``, an unknown ramp.
    """
    if not (outer[0] <= inner[0] <= inner[2] <= outer[2] and outer[1] <= inner[1] <= inner[3] <= outer[3]):
        raise ValueError(f"inner box {inner} must lie inside the outer box {outer}")
    if isinstance(feather_cells, bool) or int(feather_cells) != feather_cells or feather_cells < 0:
        raise ValueError(f"feather_cells must be an integer >= 0, got {feather_cells!r}")
    if ramp not in RAMPS:
        raise ValueError(f"ramp must be one of {', '.join(RAMPS)}, got {ramp!r}")
    return tuple(_axis_weights(outer[axis], outer[axis + 2], inner[axis], inner[axis + 2], int(feather_cells), ramp)
                 for axis in (0, 1))


def _axis_weights(outer_lo: int, outer_hi: int, inner_lo: int, inner_hi: int, feather: int, ramp: str
                  ) -> np.ndarray:
    cells = np.arange(outer_lo, outer_hi)
    before = cells < inner_lo
    distance = np.where(before, inner_lo - cells, np.maximum(cells - (inner_hi - 1), 0))  # 0 inside
    length = np.where(before, min(feather, inner_lo - outer_lo), min(feather, outer_hi - inner_hi))
    x = distance / (length + 1.0)  # 0 inside, 1 one cell past the ramp's end
    weight = 1.0 - x if ramp == "linear" else 0.5 * (1.0 + np.cos(np.pi * x))
    return np.where(distance <= length, weight, 0.0).astype(np.float32)


class ReusingPredictor:
    """A :class:`~superex_deploy.onboard.types.MapPredictor` wrapper that keeps its last prediction (see the
    module docstring). Thread-safe: the asynchronous explorer calls it from its worker.

    Args:
        predictor: the wrapped predictor.
        cfg: what to keep.
        resolution_m: metres per cell (converts ``crop_margin_m``, ``feather_m`` and ``min_changed_m2``).

    Attributes:
        min_changed_cells: the changed cells that reach ``cfg.min_changed_m2`` on this grid.
        runs: predictor calls so far; ``reused``: requests answered from the last prediction alone;
        predicted_cells: cells of all the (cropped) maps the predictor ran on.
        last_crop: ``(outer, inner)`` boxes (``(top, left, bottom, right)``, end-exclusive) of the latest kept
            prediction: the crop the predictor ran on and the part written back in full; None when it ran on
            the whole map (or has not run).
    """

    def __init__(self, predictor: MapPredictor, cfg: PredictionReuse, resolution_m: float):
        if not callable(getattr(predictor, "predict", None)):
            raise ValueError(f"predictor must have a predict(observed, extra) method, got {type(predictor).__name__}")
        if not isinstance(cfg, PredictionReuse):
            raise ValueError(f"cfg must be a PredictionReuse, got {type(cfg).__name__}")
        if not (np.isfinite(resolution_m) and resolution_m > 0):
            raise ValueError(f"resolution_m must be positive, got {resolution_m!r}")
        self.predictor, self.cfg = predictor, cfg
        self.name = getattr(predictor, "name", type(predictor).__name__)
        self._crops = cfg.crop_margin_m is not None and bool(getattr(predictor, "accepts_crops", False))
        # Rounded up, but not by floating-point noise (1.1 m at 0.1 m is 11 cells, not 12).
        self._margin = 0 if cfg.crop_margin_m is None else int(np.ceil(cfg.crop_margin_m / resolution_m - 1e-9))
        self._multiple = int(getattr(predictor, "size_multiple", 1) or 1)
        self._feather = int(np.ceil(cfg.feather_m / resolution_m - 1e-9))
        self.min_changed_cells = cells_at_least(cfg.min_changed_m2, resolution_m ** 2)
        self._lock = threading.Lock()
        self._base: Optional[Prediction] = None
        self._base_observed: Optional[np.ndarray] = None
        self._base_evidence: Optional[np.ndarray] = None
        self.runs = self.reused = self.predicted_cells = 0
        self.last_crop: Optional[tuple[tuple[int, int, int, int], tuple[int, int, int, int]]] = None

    @property
    def crops(self) -> bool:
        """Whether this predictor predicts crops (a margin is set and the wrapped predictor accepts crops)."""
        return self._crops

    def reset(self) -> None:
        """Forget the last prediction (a new episode)."""
        with self._lock:
            self._base = self._base_observed = self._base_evidence = None
            self.runs = self.reused = self.predicted_cells = 0
            self.last_crop = None

    def regrid(self, regrid) -> None:
        """Move the last prediction to a larger grid (a :class:`~superex_deploy.onboard.mapping.growth.Regrid`;
        waits for a prediction in progress): new cells are unknown in its map and predicted free with no variance,
        as the observed-map predictor has them, until a prediction covers them."""
        with self._lock:
            if self._base is not None:
                self._base = Prediction(mean=regrid.embed(self._base.mean, 0.0),
                                        variance=regrid.embed(self._base.variance, 0.0))
                self._base_observed = regrid.embed(self._base_observed, UNKNOWN)
                if self._base_evidence is not None:
                    self._base_evidence = regrid.embed(self._base_evidence, 0.0)
            self.last_crop = None

    def _changed(self, observed: np.ndarray, evidence: Optional[np.ndarray]) -> np.ndarray:
        if self._base_observed is None:
            changed = observed != UNKNOWN
        else:
            changed = observed != self._base_observed
        if evidence is not None:
            before = 0.0 if self._base_evidence is None else self._base_evidence
            changed |= (evidence - before) > self.cfg.evidence_change
        return changed

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None, commit: bool = True) -> Prediction:
        """The prediction of ``observed`` (int8 ``[H, W]``) with evidence ``extra`` (float32 ``[H, W]`` or None).

        Args:
            commit: keep the result as the new last prediction (False: a look that leaves no trace, e.g. an
                evaluation between the planner's requests).
        """
        observed = np.asarray(observed)
        with self._lock:
            if self._base is not None and self._base.mean.shape != observed.shape:
                raise ValueError(f"observed has shape {observed.shape}, the last prediction {self._base.mean.shape}: "
                                 "reset() between maps")
            changed = self._changed(observed, extra)
            n_changed = int(changed.sum())
            # Too little changed; with crops, nothing changed also means the last prediction is exact for this map.
            if self._base is not None and (n_changed < self.min_changed_cells or (self._crops and not n_changed)):
                if commit:
                    self.reused += 1
                return merge_with_map(self._base, observed)
            box = changed_box(changed) if self._crops else None
            boxes = None
            if box is None:  # the whole map
                prediction = self.predictor.predict(observed, extra)
                cells = observed.size
            else:
                prediction, boxes = self._predict_crop(observed, extra, box)
                cells = (boxes[0][2] - boxes[0][0]) * (boxes[0][3] - boxes[0][1])
            if commit:
                self.last_crop = boxes
                self.runs += 1
                self.predicted_cells += cells
                self._base = prediction
                self._base_observed = observed.copy()
                self._base_evidence = None if extra is None else np.array(extra, np.float32, copy=True)
            return prediction

    def _predict_crop(self, observed: np.ndarray, extra: Optional[np.ndarray], box: tuple[int, int, int, int]
                      ) -> tuple[Prediction, tuple[tuple[int, int, int, int], tuple[int, int, int, int]]]:
        """The crop's prediction written into (a copy of) the last one, and the crop's ``(outer, inner)`` boxes."""
        shape = observed.shape
        outer = _grow(box, self._margin, shape, self._multiple)
        inner = _grow(box, self._margin // 2, shape)
        rows, cols = slice(outer[0], outer[2]), slice(outer[1], outer[3])
        crop = self.predictor.predict(np.ascontiguousarray(observed[rows, cols]),
                                      None if extra is None else np.ascontiguousarray(extra[rows, cols]))
        if self._base is None:
            mean = (observed == OCCUPIED).astype(np.float32)
            variance = np.zeros(shape, np.float32)
        else:
            merged = merge_with_map(self._base, observed)
            mean, variance = merged.mean, merged.variance
        if self._feather:
            _blend(mean[rows, cols], variance[rows, cols], crop, feather_weights(outer, inner, self._feather,
                                                                               self.cfg.feather_ramp))
        # The written part exactly as predicted (the blend's float rounding aside, its weight is 1 there).
        inside = slice(inner[0] - outer[0], inner[2] - outer[0]), slice(inner[1] - outer[1], inner[3] - outer[1])
        mean[inner[0]:inner[2], inner[1]:inner[3]] = crop.mean[inside]
        variance[inner[0]:inner[2], inner[1]:inner[3]] = crop.variance[inside]
        return Prediction(mean=mean, variance=variance), (outer, inner)


def _blend(mean: np.ndarray, variance: np.ndarray, crop: Prediction, weights: tuple[np.ndarray, np.ndarray]
           ) -> None:
    """Blend ``crop`` into the views ``mean`` / ``variance`` (float32 ``[h, w]``, the last prediction on the
    crop's box) in place with weight ``rows[:, None] * cols[None, :]``, as a mixture (module docstring). Written
    as ``last + w (crop - last)`` so that a cell where both agree (every known cell) or ``w == 0`` keeps its
    value bit for bit."""
    weight = weights[0][:, None] * weights[1][None, :]
    difference = crop.mean - mean
    variance += weight * (crop.variance - variance) + weight * (np.float32(1.0) - weight) * difference * difference
    mean += weight * difference
