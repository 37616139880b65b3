"""NLOS labels from the simulator's ground truth (:func:`nlos_ground_truth`): the cells a three-bounce path with
photons reflected from.
"""

from __future__ import annotations

import numpy as np

from superex_deploy.spad_types import SpadScan

__all__ = ["nlos_ground_truth"]


def nlos_ground_truth(scan: SpadScan) -> np.ndarray:
    """Label image aligned with the BP map: bool ``[H, W]``, True at every cell a three-bounce path with
    non-zero photons reflected from (the ``h2`` cells). Reads the simulator's ground truth.

    Raises:
        ValueError: a scan without ground truth (a measured one).
    """
    if not isinstance(scan, SpadScan):
        raise ValueError(f"scan must be a SpadScan, got {type(scan).__name__}")
    if scan.truth is None:
        raise ValueError("nlos_ground_truth needs a simulated scan: this scan carries no ground truth")
    truth = np.zeros(scan.grid_shape, bool)
    cells = scan.truth.h2_rc[scan.truth.h2_counts > 0]
    truth[cells[:, 0], cells[:, 1]] = True
    return truth
