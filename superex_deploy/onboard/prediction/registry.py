"""The map predictors the robot can run, by name; none of them reads the ground truth.

:func:`superex_deploy.pipeline.make_predictor` builds the same predictors (with a real-time profile's ensemble
settings) plus the simulation's ``oracle``, which needs the ground-truth grid; the Gymnasium environment, which never
shows the agent the truth, builds its predictor here.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Optional

from superex_deploy.onboard.prediction.inference import SessionConfig

__all__ = ["PREDICTORS", "EVIDENCE_PREDICTORS", "load_model", "models_dir", "make_onboard_predictor"]

PREDICTORS = ("observed", "oracle", "lama_los", "lama_bp", "evidence")
"""Predictor names: ``observed`` (unknown = free), ``oracle`` (the truth; simulation only), ``lama_los`` / ``lama_bp``
(the learned ensembles), ``evidence`` (the Pix2Pix evidence alone)."""
EVIDENCE_PREDICTORS = ("lama_bp", "evidence")
"""Predictors that read the SPAD evidence (they need SPAD sensing and the Pix2Pix filter)."""


@lru_cache(maxsize=8)
def load_model(kind: str, directory: str, session: SessionConfig = SessionConfig()):
    """A learned model (``"pix2pix"``, ``"lama_los"`` or ``"lama_bp"``) from the exported folder ``directory``,
    loaded once per process (its ONNX Runtime sessions hold no state between calls): the benchmark and
    data-generation workers run many episodes each."""
    from superex_deploy.onboard.prediction.inference import LamaEnsemble, ModelKind, Pix2PixFilter

    if kind == "pix2pix":
        return Pix2PixFilter.from_manifest(directory, session)
    return LamaEnsemble.from_manifest(ModelKind(kind), directory, session)


def models_dir(models) -> str:
    """The absolute folder of exported models: ``models``, or when None the default one
    (:data:`~superex_deploy.onboard.prediction.inference.DEFAULT_MODEL_DIR`: ``$SUPEREX_MODELS``, else the installed models)."""
    from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR

    return str(Path(models or DEFAULT_MODEL_DIR).resolve())


def make_onboard_predictor(name: str, models=None, session: SessionConfig = SessionConfig(),
                           max_members: Optional[int] = None, agreement_stop: Optional[float] = None):
    """The map predictor called ``name`` (one of :data:`PREDICTORS` but ``oracle``).

    Args:
        name: the predictor.
        models: folder of exported models (default: :func:`models_dir`'s).
        session: ONNX Runtime settings of a LaMa ensemble.
        max_members, agreement_stop: a LaMa ensemble's member limits (``LamaEnsemble.with_members``).

    Raises:
        ValueError: an unknown name, ``oracle`` (it reads the ground truth), models that are missing or do not
            match.
    """
    from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction, ObservedAsPrediction

    if name == "observed":
        return ObservedAsPrediction()
    if name == "evidence":
        return EvidenceAsPrediction()
    if name == "oracle":
        raise ValueError("the oracle predictor reads the ground truth: it needs the grid (simulation only)")
    if name in ("lama_los", "lama_bp"):
        return load_model(name, models_dir(models), session).with_members(max_members, agreement_stop)
    raise ValueError(f"unknown predictor {name!r}; choose one of {', '.join(PREDICTORS)}")
