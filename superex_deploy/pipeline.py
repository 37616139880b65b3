"""One place that assembles the pipeline from names: the map predictor, the simulated SPAD sensing and the
onboard SPAD processing (used by the CLI, the benchmarks, the replay, the Gymnasium environment and the scripts).

The onboard pieces it builds (:func:`make_predictor` for every predictor but ``oracle``, :func:`make_processing`) read
no ground truth; :func:`make_sensing` and the oracle belong to simulations.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Optional

__all__ = ["PREDICTORS", "EVIDENCE_PREDICTORS", "make_predictor", "make_sensing", "make_processing"]

PREDICTORS = ("observed", "oracle", "lama_los", "lama_bp", "evidence")
"""Predictor names: ``observed`` (unknown = free), ``oracle`` (the truth; simulation only), ``lama_los`` / ``lama_bp``
(the learned ensembles), ``evidence`` (the Pix2Pix evidence alone)."""
EVIDENCE_PREDICTORS = ("lama_bp", "evidence")
"""Predictors that read the SPAD evidence (they need SPAD sensing and the Pix2Pix filter)."""


@lru_cache(maxsize=8)
def _load_model(kind: str, directory: str):
    """A learned model, loaded once per process (its ONNX Runtime sessions hold no state between calls): the
    benchmark and data-generation workers run many episodes each."""
    from superex_deploy.onboard.inference import LamaEnsemble, ModelKind, Pix2PixFilter

    if kind == "pix2pix":
        return Pix2PixFilter.from_manifest(directory)
    return LamaEnsemble.from_manifest(ModelKind(kind), directory)


def _models_dir(models) -> str:
    from superex_deploy.onboard.inference import DEFAULT_MODEL_DIR

    return str(Path(models or DEFAULT_MODEL_DIR).resolve())


def _pix2pix_filter(models=None):
    return _load_model("pix2pix", _models_dir(models)).filter_map


def make_predictor(name: str, grid=None, models=None):
    """The map predictor called ``name`` (one of :data:`PREDICTORS`); ``grid`` is read by ``oracle`` only.

    Raises:
        ValueError: an unknown name, ``oracle`` without a grid, models that are missing or do not match.
    """
    from superex_deploy.onboard.prediction import EvidenceAsPrediction, ObservedAsPrediction

    if name == "observed":
        return ObservedAsPrediction()
    if name == "evidence":
        return EvidenceAsPrediction()
    if name == "oracle":
        if grid is None:
            raise ValueError("the oracle predictor reads the ground truth: it needs the grid (simulation only)")
        from superex_deploy.sim.oracle import OraclePredictor

        return OraclePredictor(grid)
    if name in ("lama_los", "lama_bp"):
        return _load_model(name, _models_dir(models))
    raise ValueError(f"unknown predictor {name!r}; choose one of {', '.join(PREDICTORS)}")


def make_sensing(predictor: str, spad: bool, seed: int, models=None):
    """The episode's SPAD sensing (``None`` without ``spad``); ``lama_bp`` and ``evidence`` get the Pix2Pix
    filter's evidence.

    Raises:
        ValueError: ``lama_bp`` or ``evidence`` without ``spad`` (they read the SPAD evidence).
    """
    if predictor in EVIDENCE_PREDICTORS and not spad:
        raise ValueError(f"--predictor {predictor} reads the SPAD evidence: add --spad")
    if not spad:
        return None
    from superex_deploy.sim.sensing import SpadSensing

    bp_filter = None
    if predictor in EVIDENCE_PREDICTORS:
        bp_filter = _pix2pix_filter(models)
    return SpadSensing(seed=seed, bp_filter=bp_filter)


def make_processing(predictor: str, sensor=None, nlos=None, models=None):
    """The onboard :class:`~superex_deploy.onboard.spad_processing.SpadProcessing` for ``predictor``: with the
    Pix2Pix filter for the evidence predictors, the Laplacian filter otherwise.

    Args:
        predictor: a name of :data:`PREDICTORS`.
        sensor: the sensor model (:class:`~superex_deploy.spad_types.SpadConfig`; default: the simulator's).
        nlos: the processing parameters (:class:`~superex_deploy.onboard.nlos.NlosConfig`; default).
        models: folder of exported models (default: the repository's ``exported/``).
    """
    from superex_deploy.onboard.nlos import NlosConfig
    from superex_deploy.onboard.spad_processing import SpadProcessing
    from superex_deploy.spad_types import SpadConfig

    bp_filter: Optional[object] = _pix2pix_filter(models) if predictor in EVIDENCE_PREDICTORS else None
    return SpadProcessing(sensor=sensor or SpadConfig(), nlos=nlos or NlosConfig(), bp_filter=bp_filter)
