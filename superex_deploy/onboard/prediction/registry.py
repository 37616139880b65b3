"""The map predictors, by name: :data:`PREDICTORS`, one :class:`PredictorKind` per name, each saying what it needs
(the SPAD evidence, an ensemble's members, which exported models, the ground truth) and how the robot builds it.
Every list of predictor names and every check of what a predictor needs reads it: the CLI's choices and help, the
pipelines' checks (:mod:`superex_deploy.pipeline`), ``superex warmup``, the replay, the ROS 2 node and the Gymnasium
environment.

:func:`superex_deploy.pipeline.make_predictor` builds the same predictors (with a real-time profile's ensemble
settings) plus the simulation's ``oracle``, which needs the ground-truth grid; the Gymnasium environment, which never
shows the agent the truth, builds its predictor here.

A new kind of predictor is a :class:`PredictorKind` subclass (its name, one line of help, what it needs, and
:meth:`~PredictorKind.build`) added to :data:`PREDICTORS`, like a planner to ``planners.PLANNERS``.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import ClassVar, Optional

from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction, ObservedAsPrediction
from superex_deploy.onboard.prediction.inference import ModelKind, SessionConfig

__all__ = ["PredictorKind", "PREDICTORS", "EVIDENCE_PREDICTORS", "ENSEMBLE_PREDICTORS", "TRUTH_PREDICTORS",
           "EVIDENCE_MODEL", "predictor_kind", "kind_of", "exported_model", "models_dir", "make_onboard_predictor"]


class PredictorKind:
    """One kind of map predictor: its name, what it needs and how the robot builds it (:meth:`build`). One subclass
    per kind, listed in :data:`PREDICTORS`; the class itself is the entry (never instantiated), as a planner class
    is in ``planners.PLANNERS``."""

    name: ClassVar[str]
    """Its name: ``--predictor NAME``, ``Pipeline.predictor``, the name in episode logs and recordings."""
    summary: ClassVar[str]
    """What it is, in a few words (the CLI's help)."""
    reads_evidence: ClassVar[bool] = False
    """Whether it reads the SPAD evidence (``predict``'s ``extra``): it needs SPAD sensing, whose processing then
    runs the Pix2Pix filter (:data:`EVIDENCE_MODEL`)."""
    ensemble: ClassVar[bool] = False
    """Whether its variance is the spread of an ensemble's members: with one member (a profile's ``max_members=1``)
    it is zero, which a planner that reads the variance refuses (``pipeline.check_profile``)."""
    models: ClassVar[tuple[ModelKind, ...]] = ()
    """The exported models it loads from the models folder (``superex warmup`` loads them)."""
    reads_truth: ClassVar[bool] = False
    """Whether it reads the ground truth: simulations only (``pipeline.make_predictor`` builds it from the grid);
    never on the robot, in the Gymnasium environment or in a recording."""

    @classmethod
    def build(cls, models=None, session: SessionConfig = SessionConfig(), max_members: Optional[int] = None):
        """The predictor (a :class:`~superex_deploy.onboard.types.MapPredictor`), with the arguments of
        :func:`make_onboard_predictor`.

        Raises:
            ValueError: it cannot be built on the robot, models that are missing or do not match.
        """
        raise NotImplementedError


class ObservedKind(PredictorKind):
    """:class:`~superex_deploy.onboard.prediction.baselines.ObservedAsPrediction`."""

    name, summary = ObservedAsPrediction.name, "unknown = free (honest baseline)"

    @classmethod
    def build(cls, models=None, session=SessionConfig(), max_members=None):
        return ObservedAsPrediction()


class OracleKind(PredictorKind):
    """``superex_deploy.sim.oracle.OraclePredictor``: the truth, built by ``pipeline.make_predictor`` from the
    grid."""

    name, summary = "oracle", "ground truth (upper bound only)"
    reads_truth = True

    @classmethod
    def build(cls, models=None, session=SessionConfig(), max_members=None):
        raise ValueError(f"the {cls.name} predictor reads the ground truth: it needs the grid (simulation only)")


class LamaKind(PredictorKind):
    """A LaMa ensemble (:class:`~superex_deploy.onboard.prediction.inference.LamaEnsemble`) of the one model kind
    of :attr:`models`, with the profile's member limits."""

    ensemble = True

    @classmethod
    def build(cls, models=None, session=SessionConfig(), max_members=None):
        (model,) = cls.models
        return exported_model(model.value, models_dir(models), session).with_members(max_members)


class LamaLosKind(LamaKind):
    name, summary = ModelKind.LAMA_LOS.value, "the line-of-sight LaMa ensemble"
    models = (ModelKind.LAMA_LOS,)


class LamaBpKind(LamaKind):
    name, summary = ModelKind.LAMA_BP.value, "the LaMa ensemble that also reads the Pix2Pix-filtered back-projection"
    reads_evidence = True
    models = (ModelKind.LAMA_BP,)


class EvidenceKind(PredictorKind):
    """:class:`~superex_deploy.onboard.prediction.baselines.EvidenceAsPrediction`."""

    name, summary = EvidenceAsPrediction.name, "the Pix2Pix evidence alone, no LaMa"
    reads_evidence = True

    @classmethod
    def build(cls, models=None, session=SessionConfig(), max_members=None):
        return EvidenceAsPrediction()


PREDICTORS: dict[str, type[PredictorKind]] = {kind.name: kind for kind in (
    ObservedKind, OracleKind, LamaLosKind, LamaBpKind, EvidenceKind,
)}
"""The predictor kinds by name, the one list of them: ``observed`` (unknown = free), ``oracle`` (the truth;
simulation only), ``lama_los`` / ``lama_bp`` (the learned ensembles), ``evidence`` (the Pix2Pix evidence alone)."""
EVIDENCE_PREDICTORS = tuple(name for name, kind in PREDICTORS.items() if kind.reads_evidence)
"""The shipped predictors that read the SPAD evidence (they need SPAD sensing and the Pix2Pix filter). The checks
ask :func:`kind_of`, which also knows a kind registered later (``PREDICTORS[kind.name] = kind``)."""
ENSEMBLE_PREDICTORS = tuple(name for name, kind in PREDICTORS.items() if kind.ensemble)
"""The shipped predictors whose variance is an ensemble's spread (zero with one member)."""
TRUTH_PREDICTORS = tuple(name for name, kind in PREDICTORS.items() if kind.reads_truth)
"""The shipped predictors that read the ground truth (simulation only)."""
EVIDENCE_MODEL = ModelKind.PIX2PIX
"""The exported model the SPAD processing runs for the :data:`EVIDENCE_PREDICTORS` (the Pix2Pix filter)."""


def predictor_kind(name: str) -> type[PredictorKind]:
    """The :class:`PredictorKind` called ``name``.

    Raises:
        ValueError: an unknown name (the message lists the valid ones).
    """
    if not isinstance(name, str) or name not in PREDICTORS:
        raise ValueError(f"unknown predictor {name!r}; choose one of {', '.join(PREDICTORS)}")
    return PREDICTORS[name]


def kind_of(name) -> type[PredictorKind]:
    """What the predictor called ``name`` needs: its :class:`PredictorKind`, or :class:`PredictorKind` itself (it
    needs nothing) for a name no kind has, such as a predictor object's own name."""
    return PREDICTORS.get(name, PredictorKind) if isinstance(name, str) else PredictorKind


@lru_cache(maxsize=8)
def exported_model(kind: str, directory: str, session: SessionConfig = SessionConfig()):
    """A learned model (``"pix2pix"``, ``"lama_los"`` or ``"lama_bp"``: a ``Pix2PixFilter`` or ``LamaEnsemble``)
    from the exported folder ``directory``, built once per process (its ONNX Runtime sessions hold no state between
    calls): the benchmark and data-generation workers run many episodes each. Each of its files is opened and
    checked by :func:`~superex_deploy.onboard.prediction.inference.sessions.load_model`."""
    from superex_deploy.onboard.prediction.inference import LamaEnsemble, Pix2PixFilter

    if kind == ModelKind.PIX2PIX.value:
        return Pix2PixFilter.from_manifest(directory, session)
    return LamaEnsemble.from_manifest(ModelKind(kind), directory, session)


def models_dir(models) -> str:
    """The absolute folder of exported models: ``models``, or when None the default one
    (:data:`~superex_deploy.onboard.prediction.inference.DEFAULT_MODEL_DIR`: ``$SUPEREX_MODELS``, else the installed models)."""
    from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR

    return str(Path(models or DEFAULT_MODEL_DIR).resolve())


def make_onboard_predictor(name: str, models=None, session: SessionConfig = SessionConfig(),
                           max_members: Optional[int] = None):
    """The map predictor called ``name`` (one of :data:`PREDICTORS` but those of :data:`TRUTH_PREDICTORS`):
    its kind's :meth:`PredictorKind.build`.

    Args:
        name: the predictor.
        models: folder of exported models (default: :func:`models_dir`'s).
        session: ONNX Runtime settings of a LaMa ensemble.
        max_members: a LaMa ensemble's member limit (``LamaEnsemble.with_members``).

    Raises:
        ValueError: an unknown name, ``oracle`` (it reads the ground truth), models that are missing or do not
            match.
    """
    return predictor_kind(name).build(models, session, max_members)
