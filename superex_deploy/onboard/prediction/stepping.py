"""The predictions an explorer's steps read (:class:`StepPredictions`, one per explorer).

The predictor runs at the resolution it was trained at (:func:`~.scale.at_resolution`), wrapped to reuse its last
answer where ``ExplorerConfig.reuse`` says (:class:`~.reuse.ReusingPredictor`), inline or in a worker thread on the
schedule ``ExplorerConfig.prediction`` (:class:`~.schedule.ScheduledPredictions`), on the explorer's share of the
cores (:class:`~.inference.sessions.ThreadBudget`). Each step gets the prediction it may read
(:meth:`StepPredictions.begin`: computed lazily inline, or the newest applied one merged with the step's map); the
newest prediction applied and the step of the map it was made of go into the step's command.
"""

from __future__ import annotations

import weakref
from typing import Optional

import numpy as np

from superex_deploy.onboard.prediction.inference.sessions import ThreadBudget
from superex_deploy.onboard.prediction.reuse import ReusingPredictor
from superex_deploy.onboard.prediction.scale import at_resolution
from superex_deploy.onboard.prediction.schedule import (LazyPrediction, ScheduledPredictions, StalePrediction,
                                                        weak_prediction_runner)
from superex_deploy.onboard.types import MapPredictor, Prediction

__all__ = ["StepPredictions"]


class StepPredictions:
    """What an explorer's steps predict with, and the newest prediction applied.

    Args:
        owner: the explorer (held weakly by the worker: ``owner.step_predictor`` is what it calls, and the worker
            stops when the owner is collected).
        predictor: the explorer's :class:`~superex_deploy.onboard.types.MapPredictor`.
        cfg: the explorer's :class:`~superex_deploy.onboard.config.ExplorerConfig` (``reuse``, ``prediction``).
        resolution_m: the map's cell size (metres).
        cores: the cores the explorer may use (None: the process's affinity).

    Raises:
        ValueError: a learned predictor that cannot serve the map's resolution (:func:`~.scale.at_resolution`).

    Attributes:
        reusing: the :class:`~.reuse.ReusingPredictor` when ``cfg.reuse`` keeps anything, else None.
        step_predictor: what the steps call: ``reusing``, else the predictor at the map's scale.
        budget: the :class:`~.inference.sessions.ThreadBudget` of ``cores``.
        scheduled: the :class:`~.schedule.ScheduledPredictions` when the schedule is not inline, else None.
        current: the latest step's prediction (lazy or stale), None before the first step.
        latest: the newest prediction applied (None: none yet); ``latest_step``: the step of its map (-1: none).
    """

    def __init__(self, owner, predictor: MapPredictor, cfg, resolution_m: float, cores: Optional[int]):
        native = at_resolution(predictor, resolution_m)
        self.reusing: Optional[ReusingPredictor] = (ReusingPredictor(native, cfg.reuse, resolution_m)
                                                    if cfg.reuse.reuses else None)
        self.step_predictor: MapPredictor = self.reusing if self.reusing is not None else native
        self.budget = ThreadBudget.for_cores(cores, worker=cfg.prediction.threaded)
        self.scheduled: Optional[ScheduledPredictions] = None
        self._stop_worker = None
        if cfg.prediction.asynchronous:
            # The worker holds the explorer weakly (weak_prediction_runner: dropped, it stops its worker at once).
            self.scheduled = ScheduledPredictions(cfg.prediction, weak_prediction_runner(owner),
                                                  self.budget.worker_threads)
            self._stop_worker = weakref.finalize(owner, self.scheduled.close)
        self.current: Optional[LazyPrediction] = None
        self.latest: Optional[Prediction] = None
        self.latest_step = -1
        self._no_evidence: Optional[np.ndarray] = None

    def evidence(self, spad_processing, shape: tuple[int, int]) -> Optional[np.ndarray]:
        """float32 ``[H, W]`` the NLOS evidence the predictor reads: None without ``spad_processing``, its evidence
        once it has processed a frame, read-only zeros of the map's ``shape`` until then (a predictor that reads
        evidence then sees none; made once per shape)."""
        if spad_processing is None:
            return None
        if spad_processing.evidence is not None:
            return spad_processing.evidence
        if self._no_evidence is None or self._no_evidence.shape != tuple(shape):
            self._no_evidence = np.zeros(shape, np.float32)
            self._no_evidence.flags.writeable = False
        return self._no_evidence

    @property
    def regrid_wait_s(self) -> float:
        """Seconds the latest regrid waited for a prediction in progress (0 inline)."""
        return 0.0 if self.scheduled is None else self.scheduled.last_regrid_wait_s

    def begin(self, step: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> tuple[LazyPrediction, float]:
        """The prediction step ``step`` reads on its map ``observed`` (int8) and ``evidence``: ``(prediction,
        seconds waited for the worker)``; the worker's newest applied prediction becomes :attr:`latest`."""
        waited = 0.0
        if self.scheduled is not None:
            waited = self.scheduled.advance(step, observed, evidence)
            self.latest, self.latest_step = self.scheduled.latest, self.scheduled.latest_step
            self.current = StalePrediction(self.latest, observed)
        else:
            self.current = LazyPrediction(self.step_predictor, observed, evidence)
        return self.current, waited

    def end(self, step: int) -> None:
        """After step ``step``: inline, its prediction (if anything computed it) becomes :attr:`latest`."""
        if self.scheduled is None and self.current is not None and self.current.value is not None:
            self.latest, self.latest_step = self.current.value, step

    def look(self) -> Prediction:
        """The latest step's prediction, computed now if nothing has (inline).

        Raises:
            RuntimeError: before the first step.
        """
        if self.current is None:
            raise RuntimeError("no observation yet: call step() first")
        return self.current.look()

    def follow(self, prediction_steps, steps_taken: int) -> None:
        """Replay a recording's prediction steps (:meth:`~.schedule.ScheduledPredictions.follow`).

        Raises:
            ValueError: an inline schedule; RuntimeError: ``steps_taken`` > 0.
        """
        if self.scheduled is None:
            raise ValueError("an inline schedule predicts each step's own map: there is nothing to follow")
        if steps_taken:
            raise RuntimeError("follow_recorded_predictions must be called before the first step")
        self.scheduled.follow(prediction_steps)

    def regrid(self, regrid) -> None:
        """Move the worker's and the wrapper's state, and :attr:`latest`, to the larger grid ``regrid`` (the
        worker first: it may wait for a prediction in progress)."""
        for part in (self.scheduled, self.reusing):
            if part is not None:
                part.regrid(regrid)
        if self.latest is not None:
            self.latest = Prediction(mean=regrid.embed(self.latest.mean, 0.0),
                                     variance=regrid.embed(self.latest.variance, 0.0))

    def close(self) -> None:
        """Stop the worker (idempotent)."""
        if self._stop_worker is not None:
            self._stop_worker()
