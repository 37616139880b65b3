"""Prediction: the map predictors and how the explorer runs them.

* :mod:`.registry`: the predictors a robot can run, by name (:func:`~.registry.make_onboard_predictor`).
* :mod:`.baselines`: the non-learned predictors (the observed map, the SPAD evidence alone).
* :mod:`.inference`: ONNX Runtime inference of the learned models (Pix2Pix, the LaMa ensembles).
* :mod:`.schedule`: when predictions run (inline, in a worker thread, on a simulated clock).
* :mod:`.reuse`: what of the last prediction is kept (crops around what changed).

The two baselines are re-exported here (``superex_deploy.onboard.prediction`` was their module).
"""

from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction, ObservedAsPrediction

__all__ = ["ObservedAsPrediction", "EvidenceAsPrediction"]
