"""Removal of the period-``P`` lattice a LaMa member draws over featureless unknown space.

A LaMa generator (:mod:`superex_train.models.lama`) works at ``1 / P`` of the map's resolution (``P = 2 **
n_downsample``, the ``size_multiple`` of its metadata, 8 for the committed models) and goes back up through
stride-2 3x3 transposed convolutions. Such a convolution gives even and odd output cells different numbers of
kernel taps, so a feature map that is constant, which is what the FFC blocks make of a large unknown region,
comes out as a pattern repeating every 2, 4, then ``P`` cells (the checkerboard of transposed convolutions).
What the committed members draw far from known space is that pattern: faint lines every ``P`` cells in both
directions, locked to the network's input grid (the padded map's origin, which is the map's origin since
:class:`~superex_deploy.onboard.prediction.inference.lama.LamaEnsemble` pads at the bottom and right), whatever
the map or its size. The cure of the cause is in training (an up-sampling that treats all output cells alike);
:func:`remove_lattice` removes the pattern from a member's output.

It splits the output into a smooth part, a ``P``-wide box filter applied twice along each axis (a triangle 2 P - 1
cells wide that reproduces any linear ramp and whose response is zero at every multiple of ``1 / P``
cycles per cell, so it holds nothing of the lattice), and the rest. Around every ``P x P`` block, the rest's
mean per phase (``P ** 2`` phases: the cell's row and column modulo ``P``) over ``window_blocks x
window_blocks`` blocks is the local lattice, which is subtracted, less its mean over the phases: a narrow notch at
the lattice's frequencies that keeps every block's mean (so the mean probability, and with it the calibration, of
any region of whole blocks is unchanged) and leaves smooth gradients alone. Cells whose rest stands out of a first
estimate by more than ``outlier`` (a predicted wall, a known wall), and every cell within ``P - 1`` cells of one
(whose smooth part the wall lifts), are left out of the second estimate, so a wall neither leaves ghost lines
``P`` cells apart around it nor lowers itself.

Where a window holds few cells clear of walls, the estimate comes from the few it has: in a narrow corridor between
predicted walls it is the lattice of the open unknown beside it, which can be stronger than the corridor's own,
and the filter then overshoots there (measured in ``docs/benchmarks/models.md``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["LATTICE_WINDOW_BLOCKS", "LATTICE_MAX_DEVIATION", "LATTICE_OUTLIER", "remove_lattice"]

LATTICE_WINDOW_BLOCKS = 9
"""Side of the window the phase template is estimated over, in blocks (9 blocks = 72 cells = 7.2 m at 0.1 m per
cell for ``P = 8``): wide enough that a wall crosses a small share of it, narrow enough to follow the lattice's
amplitude, which changes over metres with the distance from known space."""

LATTICE_MAX_DEVIATION = 0.15
"""The first estimate reads each cell's deviation from the smooth part clipped to +-this (probability): the
committed members' lattices span at most 0.17 peak to peak far from known space (LaMa-LOS member 0 on a small
held-out floor), about +-0.1, so a lattice cell counts in full and a wall, however strong, moves the estimate by at
most this over ``window_blocks`` blocks."""

LATTICE_OUTLIER = 0.05
"""Deviation from the first estimate (wall probability) from which a cell is left out of the second estimate: on
two held-out floors 97-99 % of the committed members' cells more than 5 m from known space lie within it on the
large one (85-94 % on the small one, whose far region predicted wall continuations cross), while 98-100 % of
the cells called walls (>= 0.5) stand out of it, by 0.23-0.44 (median)."""


def _blocks(array: np.ndarray, period: int) -> np.ndarray:
    """``[H, W]`` -> ``[H / P, W / P, P * P]``: each block's cells in row-major phase order."""
    h, w = array.shape[0] // period, array.shape[1] // period
    return array.reshape(h, period, w, period).transpose(0, 2, 1, 3).reshape(h, w, period * period)


def _unblocks(blocks: np.ndarray, period: int) -> np.ndarray:
    h, w = blocks.shape[:2]
    return blocks.reshape(h, w, period, period).transpose(0, 2, 1, 3).reshape(h * period, w * period)


def _window_mean(values: np.ndarray, window_blocks: int) -> np.ndarray:
    """Mean over ``window_blocks x window_blocks`` blocks of ``[h, w, phases]``, each phase on its own."""
    return ndimage.uniform_filter(values, size=(window_blocks, window_blocks, 1), mode="reflect")


def remove_lattice(probability: np.ndarray, period: int, window_blocks: int = LATTICE_WINDOW_BLOCKS,
                   outlier: float = LATTICE_OUTLIER, max_deviation: float = LATTICE_MAX_DEVIATION) -> np.ndarray:
    """``probability`` with its period-``period`` lattice removed (see the module docstring).

    Args:
        probability: float ``[H, W]`` one member's wall probability on the network's input grid; ``H`` and ``W``
            multiples of ``period`` (the padded map, before cropping).
        period: lattice period in cells (the member's ``size_multiple``), >= 2.
        window_blocks: see :data:`LATTICE_WINDOW_BLOCKS` (odd, >= 1).
        outlier: see :data:`LATTICE_OUTLIER` (probability, > 0).
        max_deviation: see :data:`LATTICE_MAX_DEVIATION` (probability, > 0).

    Returns:
        float32 ``[H, W]`` in [0, 1]; every ``period x period`` block keeps its mean (up to the final clip).
    """
    probability = np.asarray(probability, np.float32)
    if int(period) < 2:
        raise ValueError(f"period must be >= 2 cells, got {period}")
    period = int(period)
    if probability.ndim != 2 or probability.shape[0] % period or probability.shape[1] % period:
        raise ValueError(f"probability must be 2-D with sides that are multiples of {period}, got "
                         f"{probability.shape}")
    if int(window_blocks) < 1 or int(window_blocks) % 2 == 0:
        raise ValueError(f"window_blocks must be an odd number >= 1, got {window_blocks}")
    if not (outlier > 0.0 and max_deviation > 0.0):
        raise ValueError(f"outlier and max_deviation must be positive, got {outlier} and {max_deviation}")
    smooth = probability
    for axis in (0, 1):  # two centred P-wide boxes per axis: a triangle, zero response at multiples of 1 / P
        smooth = ndimage.uniform_filter1d(smooth, period, axis=axis, mode="reflect")
        smooth = ndimage.uniform_filter1d(smooth, period, axis=axis, mode="reflect", origin=-1)
    rest = probability - smooth
    # First estimate from the rest clipped to +-max_deviation (a wall moves it by at most that over the window);
    # the cells that stand out of it, and every cell within reach of the smoothing of one, are left out.
    clipped = np.clip(rest, -max_deviation, max_deviation)
    first = _unblocks(_window_mean(_blocks(clipped, period), window_blocks), period)
    standing_out = np.abs(rest - first) > outlier
    reach = 2 * period - 1
    inlier = ~ndimage.maximum_filter(standing_out, size=reach, mode="constant", cval=False)
    rest_blocks, inlier_blocks = _blocks(rest * inlier, period), _blocks(inlier.astype(np.float32), period)
    weight = _window_mean(inlier_blocks, window_blocks)
    template = np.where(weight > 0.0, _window_mean(rest_blocks, window_blocks) / np.maximum(weight, 1e-12), 0.0)
    template -= template.mean(axis=-1, keepdims=True)  # zero over each block: block means are kept
    return np.clip(probability - _unblocks(template, period), 0.0, 1.0).astype(np.float32)
