"""Non-learned map predictors: honest baselines for the planners until the learned ensembles exist.

Both satisfy :class:`~superex_deploy.onboard.types.MapPredictor`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, Prediction, check_observed

__all__ = ["ObservedAsPrediction", "EvidenceAsPrediction"]


class ObservedAsPrediction:
    """The observed map taken as the prediction: unknown cells are assumed free, walls are certain.

    Variance is zero everywhere (no uncertainty model), so variance-driven planners fall back to counting
    unknown cells (see :class:`~superex_deploy.onboard.planning.planners.MapexPlanner`).
    """

    name = "observed"
    accepts_crops = True  # each cell's output depends on that cell alone

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        observed = check_observed(observed, codes=True)
        mean = (observed == OCCUPIED).astype(np.float32)
        return Prediction(mean=mean, variance=np.zeros_like(mean))


class EvidenceAsPrediction:
    """The NLOS evidence taken as the prediction, with no learned map predictor (the *no LaMa* ablation).

    Observed cells keep their observed value; an unknown cell's wall probability is the evidence there (the
    running maximum of the Pix2Pix-filtered back-projection, in [0, 1]), or 0 where there is none. Variance is
    zero.
    """

    name = "evidence"
    accepts_crops = True

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        observed = check_observed(observed, codes=True)
        mean = (observed == OCCUPIED).astype(np.float32)
        if extra is not None:
            extra = np.asarray(extra)
            if extra.shape != observed.shape or not np.issubdtype(extra.dtype, np.floating):
                raise ValueError(f"evidence must be a float {observed.shape} array, got {extra.dtype} "
                                 f"{extra.shape}")
            unknown = observed == UNKNOWN
            mean[unknown] = np.clip(np.nan_to_num(extra[unknown], nan=0.0), 0.0, 1.0)
        return Prediction(mean=mean, variance=np.zeros_like(mean))
