"""How the learned models' inputs are encoded (shared with :mod:`superex_train`, which imports them from here).

* **Pix2Pix** (:attr:`~superex_deploy.onboard.prediction.inference.manifest.ModelKind.PIX2PIX`): one square window of
  ``window_cells`` cells of the raw back-projection (``superex_deploy.onboard.nlos.back_project``, in [0, 1])
  centred on the robot, whose cell is the window's ``(S // 2, S // 2)`` (:func:`crop_window`, undone by
  :func:`paste_window`); fed through a :class:`BpEncoding` (by default ``2 x - 1``); the output is the probability,
  per cell, of a hidden wall.
* **LaMa** (``ModelKind.LAMA_BP``, ``ModelKind.LAMA_LOS``): the whole observed map, channels in {0, 1} except the
  evidence: ``observed_wall`` (1 where observed OCCUPIED), ``evidence`` (the filtered back-projection in [0, 1],
  map frame; LAMA_BP only) and ``unknown`` (1 where UNKNOWN) (:func:`encode_map`). The output is the wall
  probability of every cell.

The models are trained at :data:`RESOLUTION_M` metres per cell (each file declares its own in its
``resolution_m`` metadata; maps on other grids are brought to it by :mod:`superex_deploy.onboard.prediction.scale`);
:data:`NORMALISATION` is the encoding each kind declares in its metadata.
"""

from __future__ import annotations

import enum
from typing import Optional

import numpy as np

from superex_deploy.onboard.prediction.inference.manifest import ModelKind
from superex_deploy.onboard.types import check_observed
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN

__all__ = ["BpEncoding", "NORMALISATION", "RESOLUTION_M", "encode_bp_windows", "encode_map", "crop_window",
           "paste_window"]


class BpEncoding(enum.Enum):
    """How a back-projection window in [0, 1] is mapped to the Pix2Pix input range [-1, 1]."""

    LINEAR = "linear"
    """``2 x - 1`` (the committed model's)."""
    LOG = "log"
    """``2 log1p(100 x) / log(101) - 1``: a normalised back-projection is dominated by the brightest votes near
    the robot; the logarithm lifts the faint arcs of distant hidden walls."""

    @property
    def description(self) -> str:
        """The ``normalisation`` metadata string of a model that reads this encoding."""
        return _BP_DESCRIPTIONS[self]

    @classmethod
    def from_description(cls, text: str) -> "BpEncoding":
        """The encoding whose :attr:`description` is ``text`` (ValueError if none)."""
        for encoding, description in _BP_DESCRIPTIONS.items():
            if description == text:
                return encoding
        raise ValueError(f"unknown back-projection normalisation {text!r}; this package knows "
                         f"{[d for d in _BP_DESCRIPTIONS.values()]}")

    def apply(self, windows: np.ndarray) -> np.ndarray:
        """Encode float ``windows`` in [0, 1] (any shape); float32."""
        windows = np.asarray(windows, np.float32)
        if self is BpEncoding.LOG:
            return (2.0 * np.log1p(100.0 * windows) / np.log(101.0) - 1.0).astype(np.float32)
        return (2.0 * windows - 1.0).astype(np.float32)


_BP_DESCRIPTIONS = {
    BpEncoding.LINEAR: "bp: 2 * x - 1, x = back-projection in [0, 1] (normalised by its maximum)",
    BpEncoding.LOG: ("bp: 2 * log1p(100 x) / log(101) - 1, x = back-projection in [0, 1] (normalised by its "
                     "maximum)"),
}

NORMALISATION: dict[ModelKind, str] = {
    ModelKind.PIX2PIX: BpEncoding.LINEAR.description,
    ModelKind.LAMA_BP: "observed_wall, unknown: {0, 1}; evidence: filtered back-projection in [0, 1]",
    ModelKind.LAMA_LOS: "observed_wall, unknown: {0, 1}",
}
"""How each kind's inputs are encoded (written into the metadata and compared at load). A Pix2Pix model may
declare any :class:`BpEncoding`'s description; this is the default one (datasets store windows in it)."""


RESOLUTION_M = 0.1
"""Grid resolution the models are trained and exported at (metres per cell): the training datasets' grid."""


def encode_bp_windows(windows: np.ndarray, encoding: BpEncoding = BpEncoding.LINEAR) -> np.ndarray:
    """Pix2Pix input: float32 ``[N, 1, S, S]``, back-projection windows ``[N, S, S]`` in [0, 1] encoded by
    ``encoding`` (default ``2 x - 1``)."""
    windows = np.asarray(windows)
    if windows.ndim != 3 or windows.dtype != np.float32:
        raise ValueError(f"windows must be float32 [N, S, S], got {windows.dtype} with shape {windows.shape}")
    if not np.isfinite(windows).all() or windows.min(initial=0.0) < 0.0 or windows.max(initial=0.0) > 1.0:
        raise ValueError("back-projection windows must be finite and lie in [0, 1]")
    return encoding.apply(windows)[:, None]


def encode_map(observed: np.ndarray, evidence: Optional[np.ndarray], kind: ModelKind) -> np.ndarray:
    """LaMa input: float32 ``[1, C, H, W]`` with the channels of ``MODEL_CHANNELS[kind]``.

    Args:
        observed: int8 ``[H, W]`` observed map (UNKNOWN / FREE / OCCUPIED).
        evidence: float32 ``[H, W]`` filtered back-projection in [0, 1] (required for LAMA_BP; ignored for
            LAMA_LOS, whose baselines do not use NLOS evidence).
        kind: LAMA_BP or LAMA_LOS.
    """
    observed = check_observed(observed, codes=True)
    wall = (observed == OCCUPIED).astype(np.float32)
    unknown = (observed == UNKNOWN).astype(np.float32)
    if kind is ModelKind.LAMA_LOS:
        return np.stack([wall, unknown])[None]
    if kind is not ModelKind.LAMA_BP:
        raise ValueError(f"encode_map encodes LaMa inputs, got {kind}")
    if evidence is None:
        raise ValueError("a lama_bp model needs the filtered back-projection as evidence (extra), got None")
    evidence = np.asarray(evidence)
    if evidence.dtype != np.float32 or evidence.shape != observed.shape:
        raise ValueError(f"evidence must be float32 of the observed map's shape {observed.shape}, got "
                         f"{evidence.dtype} {evidence.shape}")
    if not np.isfinite(evidence).all() or evidence.min(initial=0.0) < 0.0 or evidence.max(initial=0.0) > 1.0:
        raise ValueError("evidence must be finite and lie in [0, 1]")
    return np.stack([wall, evidence, unknown])[None]


def crop_window(array: np.ndarray, pose_rc, size: int, fill: float = 0.0) -> np.ndarray:
    """The ``size x size`` window of a 2-D ``array`` whose cell ``(size // 2, size // 2)`` is ``pose_rc``.

    Cells beyond the array's edges take ``fill``. Window cell ``(i, j)`` is array cell
    ``(r - size // 2 + i, c - size // 2 + j)``. Same dtype as ``array``.
    """
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"array must be 2-D, got shape {array.shape}")
    if int(size) < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    r0, c0 = int(pose_rc[0]) - size // 2, int(pose_rc[1]) - size // 2
    out = np.full((size, size), fill, dtype=array.dtype)
    rows = slice(max(r0, 0), min(r0 + size, array.shape[0]))
    cols = slice(max(c0, 0), min(c0 + size, array.shape[1]))
    if rows.start < rows.stop and cols.start < cols.stop:
        out[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = array[rows, cols]
    return out


def paste_window(window: np.ndarray, pose_rc, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`crop_window`: a zero float32 ``shape`` map holding ``window`` where it came from."""
    size = window.shape[0]
    r0, c0 = int(pose_rc[0]) - size // 2, int(pose_rc[1]) - size // 2
    out = np.zeros(shape, np.float32)
    rows = slice(max(r0, 0), min(r0 + size, shape[0]))
    cols = slice(max(c0, 0), min(c0 + size, shape[1]))
    if rows.start < rows.stop and cols.start < cols.stop:
        out[rows, cols] = window[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0]
    return out

