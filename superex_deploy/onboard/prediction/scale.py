"""Learned models at their native scale: a map on another grid is brought to the resolution a model was trained at,
and its answer back.

The learned models (the LaMa ensembles, the Pix2Pix filter) read their training resolution from their files
(``resolution_m``: 0.1 m for the committed ones); run unchanged on a 0.05 m grid they would see every wall and room
twice the size they learned. :func:`at_resolution` wraps a model for a grid of ``resolution_m`` metres per cell:

* the same resolution: the model itself, unwrapped (the same arrays reach the same sessions);
* a grid ``k`` times finer (``k`` an integer up to :data:`MAX_POOL`: 0.05, 0.0333.., 0.025 m for a 0.1 m model):
  blocks of ``k x k`` cells are pooled into one model cell (:func:`pool_observed`: a wall where any cell of the
  block is a wall, unknown only where the whole block is unknown, free otherwise; :func:`pool_mean`: the evidence
  and the back-projection averaged), and the model's answer comes back by bilinear interpolation between the model
  cells' centres (:func:`upsample_linear`); observed cells then keep their observed value, as the model keeps them
  on its own grid;
* a grid ``u`` times coarser (``u`` an integer up to :data:`MAX_UPSAMPLE`: 0.2 m for a 0.1 m model): every cell is
  repeated ``u x u`` times (:func:`repeat_cells`) and the answer of a block is its cells' mean (the variance that of
  the block's cells taken as one mixture, :func:`pool_prediction`);
* any other ratio (not an integer either way, or beyond those limits): one ValueError when the wrapper is made,
  naming the nearest resolution served (:func:`servable_resolution`): an explorer for a SLAM map of 0.0504 m runs
  at 0.05 m and resamples the map onto its cells, which costs the map nothing the models would see.

Maps whose sides are not multiples of ``k`` are padded at the bottom and right (unknown, no evidence) and the
answer cropped back. :class:`NativeScalePredictor` wraps a map predictor, :class:`NativeScaleFilter` a
back-projection filter; the explorer wraps its predictor for its frame, the SPAD processing its filter for each
scan's grid.

:func:`pool_observed` and :func:`pool_prediction` are ``skimage.measure.block_reduce`` (each block's maximum; mean
and variance), equal to the bit to the numpy they replaced, whose reductions they are, at 0.86x and 1.03x its time on
the largest eval floor at 0.05 m. :func:`pool_mean` stays a compiled kernel: ``block_reduce`` (sums over counts,
the same bits) measured 8.7x slower there (18x at 0.1 m); :func:`upsample_linear` stays numpy:
``skimage.transform.rescale`` (order 1, edge mode) measured 2.7x slower (4.1x at 0.1 m) and differs in the last bit
with 3-cell blocks (``benchmarks/skimage``).
"""

from __future__ import annotations

from typing import Callable, Optional

import numba
import numpy as np

from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, MapPredictor, Prediction, check_observed

__all__ = ["MAX_POOL", "MAX_UPSAMPLE", "scale_factors", "servable_resolution", "model_resolution", "pool_observed", "pool_mean",
           "repeat_cells", "upsample_linear", "pool_prediction", "NativeScalePredictor", "NativeScaleFilter",
           "at_resolution", "model_window_cells", "filter_area"]

MAX_POOL = 4
"""Finest grid served: the model's resolution divided by this (0.025 m for a 0.1 m model). Finer, a model cell
pools more than 16 cells and thin walls would blur into blocks the models never saw."""
MAX_UPSAMPLE = 2
"""Coarsest grid served: the model's resolution times this (0.2 m for a 0.1 m model). Coarser, a wall cell is
wider than the walls the models learned."""

_RATIO_TOLERANCE = 1e-6  # relative: 0.1 / (0.1 / 3) is 3.0000000000000004, not 3


def scale_factors(resolution_m: float, model_resolution_m: float) -> tuple[int, int]:
    """``(pool, repeat)``: the grid is ``pool`` times finer than the model's (``repeat == 1``) or ``repeat`` times
    coarser (``pool == 1``); ``(1, 1)`` at the model's own resolution.

    Raises:
        ValueError: a resolution that is not a positive number of metres, or a ratio the models cannot serve (not
            an integer either way, finer than ``MAX_POOL`` or coarser than ``MAX_UPSAMPLE`` times).
    """
    for name, value in (("resolution_m", resolution_m), ("model_resolution_m", model_resolution_m)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number of metres, got {value!r}")
    ratio = float(model_resolution_m) / float(resolution_m)
    finer = ratio >= 1.0
    factor = ratio if finer else 1.0 / ratio
    whole = int(round(factor))
    limit = MAX_POOL if finer else MAX_UPSAMPLE
    if abs(factor - whole) > _RATIO_TOLERANCE * factor or whole > limit:
        low, high = model_resolution_m / MAX_POOL, model_resolution_m * MAX_UPSAMPLE
        raise ValueError(f"a {resolution_m:g} m grid cannot be served by a model trained at {model_resolution_m:g} "
                         f"m/cell: the grid must be an integer fraction (1/2, 1/3, 1/4) of the model's resolution or "
                         f"twice it, within [{low:g}, {high:g}] m; give the explorer "
                         f"{servable_resolution(resolution_m, model_resolution_m):g} m (a SLAM map of any resolution "
                         f"is resampled onto its cells)")
    return (whole, 1) if finer else (1, whole)


def servable_resolution(resolution_m: float, model_resolution_m: float = 0.1) -> float:
    """The grid resolution (metres per cell) a model trained at ``model_resolution_m`` serves that lies nearest to
    ``resolution_m`` (in ratio): ``model / k`` for ``k`` up to :data:`MAX_POOL`, or ``model * u`` for ``u`` up to
    :data:`MAX_UPSAMPLE`. A SLAM map of 0.0504 m (a real one) gets an explorer at 0.05 m, onto whose cells it is
    resampled (:meth:`~superex_deploy.messages.OccupancyGridMessage.in_frame`); one the models serve gets itself.

    Raises:
        ValueError: a resolution that is not a positive number of metres.
    """
    for name, value in (("resolution_m", resolution_m), ("model_resolution_m", model_resolution_m)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number of metres, got {value!r}")
    options = [model_resolution_m / k for k in range(1, MAX_POOL + 1)]
    options += [model_resolution_m * u for u in range(2, MAX_UPSAMPLE + 1)]
    best = min(options, key=lambda option: abs(np.log(option / resolution_m)))
    return float(resolution_m) if abs(best - resolution_m) <= _RATIO_TOLERANCE * best else float(best)


def model_resolution(model) -> Optional[float]:
    """The training resolution (metres per cell) of a model, of a predictor, or of a bound method of one (the
    SPAD processing is given ``Pix2PixFilter.filter_map``): its ``resolution_m`` attribute; None for anything
    without one (the baselines, the oracle, a plain function), which works at any resolution."""
    value = getattr(model, "resolution_m", None)
    if value is None:
        value = getattr(getattr(model, "__self__", None), "resolution_m", None)
    return None if value is None else float(value)


def model_window_cells(model) -> Optional[int]:
    """The side (model cells) of the window a windowed model (the Pix2Pix filter) reads around the robot, of the
    model or of a bound method of one: its ``window_cells`` attribute; None where it gives none (a filter that may
    read and write the whole map)."""
    value = getattr(model, "window_cells", None)
    if value is None:
        value = getattr(getattr(model, "__self__", None), "window_cells", None)
    return None if value is None else int(value)


def filter_area(bp_filter, resolution_m: float, pose_rc, shape: tuple[int, int],
                include: Optional[tuple[slice, slice]] = None) -> tuple[slice, slice]:
    """The rectangle of a ``shape`` grid of ``resolution_m`` metres per cell that a windowed back-projection filter,
    run at its model's scale (:func:`at_resolution`), can write around robot cell ``pose_rc``, grown to hold
    ``include`` (the back-projection's own patch, whose maximum normalises it) and cut at the model's block
    boundaries, with one model cell of margin.

    Running the filter on this rectangle alone (the back-projection zero elsewhere, the robot cell moved into it)
    gives its answer on the whole grid there (bit for bit where a model cell is a power-of-two number of cells; else
    the interpolation weights, computed from the rectangle's first cell, may differ in the last bit), and zero is its
    answer everywhere else: the model reads and
    writes only its window; the blocks pooled are the whole grid's blocks; the interpolation back onto the grid
    meets the same zeros past the window. The whole grid where the filter gives no window size
    (:func:`model_window_cells`).

    Raises:
        ValueError: a ratio :func:`scale_factors` refuses.
    """
    rows, cols = int(shape[0]), int(shape[1])
    window, model_m = model_window_cells(bp_filter), model_resolution(bp_filter)
    if window is None or model_m is None:
        return slice(0, rows), slice(0, cols)
    pool, _ = scale_factors(resolution_m, model_m)
    half = int(np.ceil(window * model_m / resolution_m / 2.0)) + 2 * pool + 1
    bounds = []
    for axis, (centre, size) in enumerate(zip((int(pose_rc[0]), int(pose_rc[1])), (rows, cols))):
        low, high = centre - half, centre + half + 1
        if include is not None:
            low, high = min(low, include[axis].start), max(high, include[axis].stop)
        low = max(low // pool * pool, 0)
        high = min(-(-high // pool) * pool, size)
        bounds.append(slice(low, high))
    return bounds[0], bounds[1]


def pool_observed(observed: np.ndarray, k: int) -> np.ndarray:
    """An observed map on a ``k`` times coarser grid: int8 ``[ceil(H/k), ceil(W/k)]``; a cell is OCCUPIED where any
    cell of its ``k x k`` block is, UNKNOWN only where all of them are (cells past the map's edge count as unknown),
    FREE otherwise. Walls are kept whole (a one-cell wall stays a wall) and a block seen at all is not unknown.

    Raises:
        ValueError: not an observed map, ``k`` not an integer >= 1.
    """
    from skimage.measure import block_reduce  # here, not at import: only a finer grid pools (~10 ms to load)

    observed = check_observed(observed, codes=True)
    k = _check_factor(k)
    # OCCUPIED > FREE > UNKNOWN, so the rule is each block's maximum, the edge padded with UNKNOWN.
    assert (OCCUPIED, FREE, UNKNOWN) == (1, 0, -1)
    return block_reduce(observed, (k, k), np.max, cval=UNKNOWN).astype(np.int8, copy=False)


def pool_mean(values: np.ndarray, k: int) -> np.ndarray:
    """float32 ``[ceil(H/k), ceil(W/k)]``: the mean of each ``k x k`` block of a float ``[H, W]`` map (probabilities,
    evidence, a back-projection); a block cut by the map's edge averages the cells it has."""
    values = _check_map(values, "values")
    k = _check_factor(k)
    out = np.empty((-(-values.shape[0] // k), -(-values.shape[1] // k)), np.float32)
    if values.dtype not in (np.float32, np.float64):  # float16, longdouble: summed in float64 as the rest
        values = values.astype(np.float64)
    _block_means(np.ascontiguousarray(values), k, out)
    return out


@numba.njit(cache=True)
def _block_means(values, k, out):
    """``out[R, C]``: the mean (summed in float64) of the cells of block ``(R, C)`` that lie inside ``values``."""
    rows, cols = values.shape
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            total = 0.0
            r1, c1 = min(r * k + k, rows), min(c * k + k, cols)
            for i in range(r * k, r1):
                for j in range(c * k, c1):
                    total += values[i, j]
            out[r, c] = total / ((r1 - r * k) * (c1 - c * k))


def repeat_cells(values: np.ndarray, u: int) -> np.ndarray:
    """``values`` ``[H, W]`` on a ``u`` times finer grid: every cell repeated ``u x u`` times, ``[u H, u W]``, same
    dtype (exact for observed maps and evidence: nothing is invented between cells)."""
    values = np.asarray(values)
    if values.ndim != 2:
        raise ValueError(f"values must be a 2-D map, got shape {values.shape}")
    u = _check_factor(u)
    return np.repeat(np.repeat(values, u, axis=0), u, axis=1)


def upsample_linear(values: np.ndarray, k: int, shape: tuple[int, int]) -> np.ndarray:
    """float32 ``shape``: a map of ``k`` times coarser cells ``[h, w]`` (with ``h = ceil(shape[0] / k)``, likewise
    ``w``) interpolated bilinearly between the coarse cells' centres onto the fine cells' centres; beyond the
    outermost centres the edge value holds. A constant block stays constant."""
    values = _check_map(values, "values")
    k = _check_factor(k)
    rows, cols = int(shape[0]), int(shape[1])
    if values.shape != (-(-rows // k), -(-cols // k)):
        raise ValueError(f"a {values.shape} map of {k} x {k} blocks cannot cover a {(rows, cols)} map")
    out = values.astype(np.float64)
    for axis, size in ((0, rows), (1, cols)):
        coarse = out.shape[axis]
        # Fine cell j's centre (j + 0.5) in coarse cells, where coarse cell i's centre lies at i + 0.5.
        position = np.clip((np.arange(size) + 0.5) / k - 0.5, 0.0, coarse - 1.0)
        low = np.floor(position).astype(np.int64)
        high = np.minimum(low + 1, coarse - 1)
        weight = position - low
        shape_w = (-1, 1) if axis == 0 else (1, -1)
        out = (np.take(out, low, axis=axis) * (1.0 - weight).reshape(shape_w)
               + np.take(out, high, axis=axis) * weight.reshape(shape_w))
    return out.astype(np.float32)


def pool_prediction(prediction: Prediction, u: int, shape: tuple[int, int]) -> Prediction:
    """A prediction made on a ``u`` times finer grid, ``[u H, u W]``, brought back to ``shape`` ``(H, W)``: each
    cell's mean is its block's mean, its variance the block's as one mixture (the mean of the variances plus the
    variance of the means, the ensemble's rule for pooled members)."""
    u = _check_factor(u)
    rows, cols = int(shape[0]), int(shape[1])
    if prediction.mean.shape != (rows * u, cols * u):
        raise ValueError(f"a {prediction.mean.shape} prediction is not a {(rows, cols)} map of {u} x {u} blocks")
    from skimage.measure import block_reduce  # here, not at import: only a coarser grid pools back (~10 ms to load)

    mean, variance = prediction.mean.astype(np.float64), prediction.variance.astype(np.float64)
    pooled = block_reduce(mean, (u, u), np.mean)
    spread = block_reduce(variance, (u, u), np.mean) + block_reduce(mean, (u, u), np.var)
    return Prediction(mean=pooled.astype(np.float32), variance=spread.astype(np.float32))


def _check_factor(k) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"the scale factor must be an integer >= 1, got {k!r}")
    return int(k)


def _check_map(values, name: str) -> np.ndarray:
    values = np.asarray(values)
    if values.ndim != 2 or not np.issubdtype(values.dtype, np.floating):
        raise ValueError(f"{name} must be a float [H, W] map, got {values.dtype} with shape {values.shape}")
    return values


class NativeScalePredictor:
    """A :class:`~superex_deploy.onboard.types.MapPredictor` on a grid of ``resolution_m`` that runs ``predictor``
    (trained at ``predictor.resolution_m``) at its own scale (see the module docstring).

    Args:
        predictor: the wrapped predictor; its ``resolution_m`` is its training resolution.
        resolution_m: metres per cell of the maps :meth:`predict` is given.

    Attributes:
        predictor, resolution_m: as given; ``model_resolution_m``: the predictor's.
        pool, repeat: :func:`scale_factors` of the two.
        name, accepts_crops, keep_observed: the wrapped predictor's.
        size_multiple: the multiple (grid cells) a crop of this grid is best cut to, so that its model-scale
            input needs no padding.

    Raises:
        ValueError: a predictor without a predict method or a training resolution; a ratio
            :func:`scale_factors` refuses.
    """

    def __init__(self, predictor: MapPredictor, resolution_m: float):
        if not callable(getattr(predictor, "predict", None)):
            raise ValueError(f"predictor must have a predict(observed, extra) method, got {type(predictor).__name__}")
        model_resolution_m = model_resolution(predictor)
        if model_resolution_m is None:
            raise ValueError(f"{type(predictor).__name__} gives no training resolution (resolution_m)")
        self.pool, self.repeat = scale_factors(resolution_m, model_resolution_m)
        self.predictor = predictor
        self.resolution_m, self.model_resolution_m = float(resolution_m), model_resolution_m
        self.name = getattr(predictor, "name", type(predictor).__name__)
        self.accepts_crops = bool(getattr(predictor, "accepts_crops", False))
        self.keep_observed = bool(getattr(predictor, "keep_observed", True))
        multiple = int(getattr(predictor, "size_multiple", 1) or 1)
        self.size_multiple = multiple * self.pool if self.repeat == 1 else (
            multiple // self.repeat if multiple % self.repeat == 0 else 1)

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        """The wrapped predictor's answer for ``observed`` (int8 ``[H, W]`` on this grid) and the evidence
        ``extra`` (float32 ``[H, W]`` in [0, 1], or None), on this grid: float32 ``[H, W]`` mean and variance."""
        observed = check_observed(observed, codes=True)
        if extra is not None:
            extra = np.asarray(extra)
            if extra.shape != observed.shape or not np.issubdtype(extra.dtype, np.floating):
                raise ValueError(f"evidence must be a float {observed.shape} array, got {extra.dtype} {extra.shape}")
        if self.repeat > 1:
            coarse = self.predictor.predict(repeat_cells(observed, self.repeat),
                                            None if extra is None else repeat_cells(extra, self.repeat))
            return pool_prediction(coarse, self.repeat, observed.shape)
        k = self.pool
        pooled = self.predictor.predict(pool_observed(observed, k), None if extra is None else pool_mean(extra, k))
        mean = upsample_linear(pooled.mean, k, observed.shape)
        variance = upsample_linear(pooled.variance, k, observed.shape)
        if self.keep_observed:
            known = observed != UNKNOWN
            mean[known] = observed[known] == OCCUPIED
            variance[known] = 0.0
        return Prediction(mean=mean, variance=variance)


class NativeScaleFilter:
    """A back-projection filter (``bp_filter(bp, pose_rc)``, e.g. ``Pix2PixFilter.filter_map``) on a grid of
    ``resolution_m``, run at its model's scale: the raw back-projection is averaged over blocks (and brought back to
    [0, 1] by its maximum, as the back-projection is normalised on the model's own grid) or its cells repeated, the
    robot cell moved to the block that holds it, and the filtered map brought back as a prediction is (see the
    module docstring).

    Raises:
        ValueError: a filter without a training resolution, a ratio :func:`scale_factors` refuses.
    """

    def __init__(self, bp_filter: Callable[[np.ndarray, tuple[int, int]], np.ndarray], resolution_m: float):
        model_resolution_m = model_resolution(bp_filter)
        if model_resolution_m is None or not callable(bp_filter):
            raise ValueError("bp_filter must be a callable filter that gives its training resolution (resolution_m)")
        self.pool, self.repeat = scale_factors(resolution_m, model_resolution_m)
        self.bp_filter = bp_filter
        self.resolution_m, self.model_resolution_m = float(resolution_m), model_resolution_m

    def __call__(self, bp: np.ndarray, pose_rc) -> np.ndarray:
        """float32 ``[H, W]`` wall probability from the raw back-projection float32 ``[H, W]`` in [0, 1] taken at
        robot cell ``pose_rc`` (row, col) of this grid."""
        bp = _check_map(bp, "bp")
        row, col = int(pose_rc[0]), int(pose_rc[1])
        if self.repeat > 1:
            u = self.repeat
            fine = self.bp_filter(repeat_cells(bp, u), (row * u + u // 2, col * u + u // 2))
            blank = np.zeros((u * bp.shape[0], u * bp.shape[1]), np.float32)
            return pool_prediction(Prediction(mean=np.asarray(fine, np.float32), variance=blank), u, bp.shape).mean
        k = self.pool
        pooled = pool_mean(bp, k)
        top = float(pooled.max(initial=0.0))
        if top > 0:
            pooled = (pooled / top).astype(np.float32)
        return upsample_linear(np.asarray(self.bp_filter(pooled, (row // k, col // k)), np.float32), k, bp.shape)


def at_resolution(model, resolution_m: float):
    """``model`` serving a grid of ``resolution_m`` metres per cell: the model itself where it gives no training
    resolution (it works at any: the baselines, the oracle) or was trained at this one (nothing changes), else a
    :class:`NativeScalePredictor` (a predictor) or :class:`NativeScaleFilter` (a back-projection filter).

    Raises:
        ValueError: a resolution the model cannot serve (:func:`scale_factors`).
    """
    model_resolution_m = model_resolution(model)
    if model_resolution_m is None or scale_factors(resolution_m, model_resolution_m) == (1, 1):
        return model
    if callable(getattr(model, "predict", None)):
        return NativeScalePredictor(model, resolution_m)
    return NativeScaleFilter(model, resolution_m)
