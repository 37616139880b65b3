"""The oracle predictor: the ground truth as the prediction. It reads the truth, so it lives on the simulator's side:
an upper bound for testing planners, never a method (a recording made with it cannot be replayed)."""

from __future__ import annotations

from typing import Optional

import numpy as np

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.types import check_observed
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, Prediction

__all__ = ["OraclePredictor"]


class OraclePredictor:
    """Ground-truth walls as the prediction: an upper bound for testing planners, never reported as a method.

    Observed cells keep their observed value (they agree with the ground truth in simulation); unknown cells
    take the ground truth. Variance is zero.
    """

    name = "oracle"

    def __init__(self, grid: OccupancyGrid):
        self._walls = grid.occupied.astype(np.float32)

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        observed = check_observed(observed, self._walls.shape, codes=True)
        mean = np.where(observed == UNKNOWN, self._walls, (observed == OCCUPIED).astype(np.float32))
        return Prediction(mean=mean.astype(np.float32), variance=np.zeros_like(self._walls))
