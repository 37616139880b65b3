"""When and on what the explorer runs its map predictor: the schedule (inside the step that asks, in a worker
thread that is never waited for, or on a simulated clock) and the two views a planner reads through (:class:`LazyPrediction` computes on request;
:class:`StalePrediction` serves the newest finished one, merged with this step's map)."""

from __future__ import annotations

import time
import weakref
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.prediction.reuse import ReusingPredictor, merge_with_map
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, Prediction

__all__ = ["MODES", "PredictionSchedule", "LazyPrediction", "StalePrediction", "ScheduledPredictions",
           "set_numba_threads", "weak_prediction_runner"]


MODES = ("inline", "free", "simulated")
"""The schedule's modes (see :class:`PredictionSchedule`)."""


@dataclass(frozen=True)
class PredictionSchedule(JsonConfig):
    """When the explorer runs its map predictor, and on which step's map.

    Attributes:
        mode: ``"inline"`` (default): inside the step whose planner asks for it; the step waits for the whole
            ensemble (up to ~0.9 s on 2 cores on the largest eval map).
            ``"free"``: the robot's mode. A worker thread predicts the newest map whenever it is idle; a step takes
            the newest *finished* prediction and never waits for an unfinished one, whatever the CPU (the steps at
            which predictions land depend on the machine, so episodes are not reproducible; a recording keeps them,
            and ``superex replay`` follows them).
            ``"simulated"``: the benchmarks' mode, no thread. The map (and evidence) of every step ``k N`` is kept
            and its prediction is computed inside step ``k N + apply_after_steps`` and applied there: the worker's
            latency is a fixed number of steps, so episodes are reproducible on any machine. (A ``"thread"`` mode,
            this schedule in a worker thread, bit for bit the same results, measured the deterministic schedule's
            timing in docs/benchmarks/realtime.md, "History", and was retired.)
            In every mode but ``inline`` the planners read the newest applied prediction, with the cells known
            since overwritten by the current map (:func:`merge_with_map`).
        every_steps: ``N``, for ``simulated`` (ignored otherwise): the map of every step ``k N`` is predicted.
        apply_after_steps: ``L``, for ``simulated``: the delay in steps (``1 <= L <= N``).
        wait_first: in every mode but ``inline``: the first step applies the prediction of its own map (in
            ``free`` mode it waits for it: the one wait a never-waiting schedule allows, taken while the robot
            stands at its start). Without it the planners and the first evaluations see no prediction at
            all until one lands, which costs map IoU early in the episode (docs/benchmarks/realtime.md).
    """

    mode: str = "inline"
    every_steps: int = 10
    apply_after_steps: int = 1
    wait_first: bool = False

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for name in ("every_steps", "apply_after_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        if not isinstance(self.wait_first, bool):
            raise ValueError(f"wait_first must be True or False, got {self.wait_first!r}")
        if self.deterministic and self.every_steps < 1:
            raise ValueError(f"every_steps must be >= 1 in {self.mode} mode, got {self.every_steps} (the "
                             "never-waiting mode that predicts whenever the worker is idle is mode='free')")
        if self.deterministic and not 1 <= self.apply_after_steps <= self.every_steps:
            raise ValueError(f"apply_after_steps must lie in 1..every_steps = {self.every_steps}, got "
                             f"{self.apply_after_steps}")

    @property
    def asynchronous(self) -> bool:
        """Whether the planners read the prediction of an earlier map (every mode but ``inline``)."""
        return self.mode != "inline"

    @property
    def threaded(self) -> bool:
        """Whether the explorer runs a prediction worker thread (``free``)."""
        return self.mode == "free"

    @property
    def deterministic(self) -> bool:
        """Whether the steps at which predictions land are fixed (``simulated``)."""
        return self.mode == "simulated"


class LazyPrediction:
    """The predictor's output for one map: computed on the first call, then cached, with the seconds it took.

    A planner's request (``__call__``) lets a :class:`ReusingPredictor` keep the result as its new last
    prediction; :meth:`look` (an evaluation between requests) computes it without leaving a trace."""

    def __init__(self, predictor, observed: np.ndarray, evidence: Optional[np.ndarray]):
        self._predictor, self._observed, self._evidence = predictor, observed, evidence
        self.value: Optional[Prediction] = None
        self.seconds = 0.0

    def __call__(self) -> Prediction:
        return self._compute(commit=True)

    def look(self) -> Prediction:
        return self._compute(commit=False)

    def _compute(self, commit: bool) -> Prediction:
        if self.value is None:
            started = time.perf_counter()
            if isinstance(self._predictor, ReusingPredictor):
                self.value = self._predictor.predict(self._observed, self._evidence, commit=commit)
            else:
                self.value = self._predictor.predict(self._observed, self._evidence)
            self.seconds = time.perf_counter() - started
        return self.value


class StalePrediction:
    """What a planner reads in asynchronous mode: the newest finished prediction merged with this step's map
    (computed on the first call, then cached), or the map itself (unknown = free) before any prediction landed."""

    def __init__(self, newest: Optional[Prediction], observed: np.ndarray):
        self._newest, self._observed = newest, observed
        self.value: Optional[Prediction] = None
        self.seconds = 0.0

    def __call__(self) -> Prediction:
        if self.value is None:
            started = time.perf_counter()
            if self._newest is None:
                mean = (self._observed == OCCUPIED).astype(np.float32)
                self.value = Prediction(mean=mean, variance=np.zeros_like(mean))
            else:
                self.value = merge_with_map(self._newest, self._observed)
            self.seconds = time.perf_counter() - started
        return self.value

    look = __call__


def set_numba_threads(threads: int) -> int:
    """Set numba's thread count for the calling thread (numba keeps one per thread), capped at the threads numba
    launched (``NUMBA_NUM_THREADS``); returns the count set."""
    import numba

    threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(threads)
    return threads


class ScheduledPredictions:
    """Runs the predictor of an explorer whose schedule is not ``inline``, and holds the newest applied prediction.

    Args:
        schedule: the :class:`PredictionSchedule` (``free`` or ``simulated``).
        predict: ``predict(observed, evidence) -> Prediction``, called in the worker thread or inline.
        worker_threads: numba threads of the worker thread (set in it when it starts); unused without a worker.

    Attributes:
        latest: the newest applied prediction, or None.
        latest_step: the step whose map it was made from, or -1.
        blocking_waits: steps that waited for an unfinished prediction (``free`` mode: at most the first, with
            ``wait_first``, and a step whose grid grew while one was in progress).
        last_wait_s: seconds the latest step waited for the predictor: blocked on an unfinished prediction
            (``free``) or computing one inline (``simulated``, a followed recording); 0 otherwise.
        last_regrid_wait_s: the same for the latest move to a larger grid (:meth:`regrid`).
    """

    def __init__(self, schedule: PredictionSchedule, predict: Callable, worker_threads: int = 1):
        if not schedule.asynchronous:
            raise ValueError("ScheduledPredictions runs the free and simulated schedules, not inline")
        self.schedule, self._predict = schedule, predict
        self._worker: Optional[ThreadPoolExecutor] = None
        if schedule.threaded:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="superex-predict", initializer=set_numba_threads,
                                              initargs=(worker_threads,))
        self._pending: Optional[Future] = None
        self._pending_step = -1
        self._kept: dict[int, tuple[np.ndarray, Optional[np.ndarray]]] = {}  # inline: step -> its map, evidence
        self._recorded: Optional[tuple[int, ...]] = None
        self._next_step = 0  # the step the next advance() is for (a regrid comes before it)
        self.last_regrid_wait_s = 0.0
        self.latest: Optional[Prediction] = None
        self.latest_step = -1
        self.blocking_waits = 0
        self.last_wait_s = 0.0

    def follow(self, prediction_steps: Sequence[int]) -> None:
        """Replay a recording: at step ``t`` apply the prediction of the map of step ``prediction_steps[t]`` (the
        recorded commands' ``prediction_step``; -1: none yet), computed inline in the order the recorded run
        computed them, instead of this schedule's own timing. Call it before the first step."""
        steps = tuple(int(s) for s in prediction_steps)
        if any(not -1 <= s <= t for t, s in enumerate(steps)):
            raise ValueError("recorded prediction steps must lie in -1..step (a prediction of a later map)")
        self.close()
        self._recorded = steps
        self._needed = {s for s in steps if s >= 0}

    def close(self) -> None:
        """Stop the worker thread, if any (a running prediction finishes first)."""
        if self._worker is not None:
            self._worker.shutdown(wait=True, cancel_futures=True)
            self._worker = None

    def regrid(self, regrid) -> None:
        """Move to a larger grid (a :class:`~superex_deploy.onboard.mapping.growth.Regrid`) before the next step
        advances: a prediction in progress is waited for and becomes the newest (``simulated``: the kept map's is
        computed now; a followed recording: the one its next step applies), on the grid it was asked on; then the
        newest prediction and the maps kept for later predictions are embedded in the new grid (new cells unknown,
        predicted free with no variance). Predicting before the move keeps a replay exact: the recorded run's
        worker predicted the smaller map, and a prediction of the embedded map differs. The seconds spent waiting
        or predicting are :attr:`last_regrid_wait_s` (a wait for an unfinished prediction counts in
        :attr:`blocking_waits`)."""
        self.last_wait_s = 0.0
        if self._pending is not None:
            self._take()
        if self._recorded is not None:
            upcoming = self._next_step
            source = self._recorded[upcoming] if upcoming < len(self._recorded) else self.latest_step
            if source >= 0 and source != self.latest_step and source in self._kept:
                for step in [s for s in self._kept if s < source]:
                    del self._kept[step]
                self._apply_kept(source)
        elif self.schedule.mode == "simulated":
            for step in sorted(self._kept):
                self._apply_kept(step)
        self.last_regrid_wait_s = self.last_wait_s
        if self.latest is not None:
            self.latest = Prediction(mean=regrid.embed(self.latest.mean, 0.0),
                                     variance=regrid.embed(self.latest.variance, 0.0))
        self._kept = {step: (regrid.embed(observed, UNKNOWN),
                             None if evidence is None else regrid.embed(evidence, 0.0))
                      for step, (observed, evidence) in self._kept.items()}

    def advance(self, t: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> float:
        """Step ``t``'s share: apply what is due (or, in ``free`` mode, finished), start or keep what the schedule
        says on ``observed`` (int8 ``[H, W]``, copied when kept) and ``evidence`` (float32 ``[H, W]`` or None);
        returns the seconds spent waiting for the worker or computing inline."""
        clock = time.perf_counter()
        self.last_wait_s = 0.0
        self._next_step = t + 1
        if self._recorded is not None:
            self._advance_recorded(t, observed, evidence)
        elif self.schedule.mode == "free":
            self._advance_free(t, observed, evidence)
        else:
            self._advance_simulated(t, observed, evidence)
        return time.perf_counter() - clock

    @staticmethod
    def _copies(observed: np.ndarray, evidence: Optional[np.ndarray]):
        return observed.copy(), None if evidence is None else evidence.copy()

    def _take(self) -> None:
        pending, self._pending = self._pending, None  # a failed prediction is raised once, not every step
        clock = time.perf_counter()
        if not pending.done():
            self.blocking_waits += 1
        self.latest, self.latest_step = pending.result(), self._pending_step
        self.last_wait_s += time.perf_counter() - clock

    def _submit(self, t: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> None:
        self._pending = self._worker.submit(self._predict, *self._copies(observed, evidence))
        self._pending_step = t

    def _advance_free(self, t: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> None:
        # Never waits: only a finished prediction is taken (done() first), a new one starts when the worker is idle.
        if self._pending is not None and self._pending.done():
            self._take()
        if self._pending is None:
            self._submit(t, observed, evidence)
            if t == 0 and self.schedule.wait_first:  # the start-up exception: the robot stands at its start
                self._take()

    def _advance_simulated(self, t: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> None:
        # A worker's schedule with its latency as apply_after_steps steps: the map of step k N is kept and its
        # prediction computed inline at step k N + apply_after_steps, where it is applied.
        schedule = self.schedule
        due = [s for s in self._kept if t >= s + schedule.apply_after_steps]
        for step in due:
            self._apply_kept(step)
        if not self._kept and t % schedule.every_steps == 0:
            self._kept[t] = self._copies(observed, evidence)
            if t == 0 and schedule.wait_first:
                self._apply_kept(0)

    def _advance_recorded(self, t: int, observed: np.ndarray, evidence: Optional[np.ndarray]) -> None:
        if t in self._needed:
            self._kept[t] = self._copies(observed, evidence)
        source = self._recorded[t] if t < len(self._recorded) else self.latest_step
        if source >= 0 and source != self.latest_step:
            if source not in self._kept:
                raise RuntimeError(f"the recording applies the prediction of step {source} at step {t}, after one "
                                   f"of step {self.latest_step}: not a schedule this explorer ran")
            for step in [s for s in self._kept if s < source]:
                del self._kept[step]
            self._apply_kept(source)

    def _apply_kept(self, step: int) -> None:
        observed, evidence = self._kept.pop(step)
        clock = time.perf_counter()
        self.latest, self.latest_step = self._predict(observed, evidence), step
        self.last_wait_s += time.perf_counter() - clock


def weak_prediction_runner(owner):
    """The prediction function of a worker thread, holding ``owner`` (an explorer) weakly: it calls
    ``owner.step_predictor.predict(observed, evidence)``. An explorer dropped without ``close()`` is then collected at
    once and its worker stopped (a bound method would make a cycle only the garbage collector breaks).

    The function raises ``RuntimeError`` once the owner is gone."""
    ref = weakref.ref(owner)

    def run(observed: np.ndarray, evidence: Optional[np.ndarray]) -> Prediction:
        target = ref()
        if target is None:
            raise RuntimeError("the explorer this prediction was for no longer exists")
        # Not the owner itself while the prediction runs: dropped meanwhile, it is freed (and its worker stopped) by
        # the thread that dropped it, never by this worker thread (which cannot join itself).
        predictor = target.step_predictor
        del target
        return predictor.predict(observed, evidence)

    return run
