"""Probability calibration of the LaMa ensembles (Platt scaling of the wall logits).

The LaMa members are trained with a wall-weighted loss (walls are ~10 % of the unknown cells; unweighted, the
net predicts no walls), and a weighted loss shifts the optimum upwards: measured on the held-out buildings, the
uncalibrated LaMa-LOS ensemble called 69 % of the unknown cells walls at probability 0.5 where 10 % are. MapEx
reads the mean as a probability (a ray stops at a cell whose wall probability reaches 0.8), so the bias turns
unknown space into predicted walls and hides the information gain behind them.

Platt scaling (Platt 1999) fixes this with two numbers per ensemble kind: calibrated logits
``logit_scale * z + logit_offset`` where ``z`` is a member's logit, fitted by maximum likelihood on cells that
were unknown when the prediction was made, in exploration episodes on the **training** buildings (the held-out
buildings stay untouched for evaluation). The export writes both numbers into the graph
(:class:`superex_train.export.WallProbabilityModel`) and into ``metadata_props``.

:func:`collect_calibration_samples` runs the episodes, :func:`fit_logit_calibration` fits the two numbers.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR, LamaEnsemble, ModelKind, Pix2PixFilter, SessionConfig
from superex_deploy.parallel import process_pool

__all__ = ["LogitCalibration", "CalibrationConfig", "fit_logit_calibration", "calibration_maps",
           "collect_calibration_samples", "calibrate", "read_calibration"]

PathLike = Union[str, Path]

_PROBABILITY_CLIP = 1e-6
"""Member outputs are sigmoid probabilities in float32; logits are recovered from them clipped to
[1e-6, 1 - 1e-6] (|z| <= 13.8), where a saturated cell's exact logit no longer matters."""


@dataclass(frozen=True)
class LogitCalibration:
    """Calibrated wall probability ``sigmoid(logit_scale * z + logit_offset)`` of a member logit ``z``.

    Attributes:
        logit_scale, logit_offset: the Platt parameters (identity: 1 and 0).
        cells: cells the fit used.
        wall_fraction: share of walls among them.
        nll_before, nll_after: mean negative log-likelihood (nats per cell) without and with the calibration.
        predicted_walls_before, predicted_walls_after: share of those cells with probability >= 0.5.
    """

    logit_scale: float = 1.0
    logit_offset: float = 0.0
    cells: int = 0
    wall_fraction: float = float("nan")
    nll_before: float = float("nan")
    nll_after: float = float("nan")
    predicted_walls_before: float = float("nan")
    predicted_walls_after: float = float("nan")

    def __post_init__(self) -> None:
        if not (np.isfinite(self.logit_scale) and self.logit_scale > 0 and np.isfinite(self.logit_offset)):
            raise ValueError(f"a calibration needs a finite logit_scale > 0 and a finite logit_offset, got "
                             f"{self.logit_scale}, {self.logit_offset}")

    def apply(self, probability: np.ndarray) -> np.ndarray:
        """Calibrated probabilities of uncalibrated ones (any shape, float32 out)."""
        z = _logit(np.asarray(probability, np.float64))
        return (1.0 / (1.0 + np.exp(-(self.logit_scale * z + self.logit_offset)))).astype(np.float32)


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, _PROBABILITY_CLIP, 1.0 - _PROBABILITY_CLIP)
    return np.log(p) - np.log1p(-p)


def _nll(z: np.ndarray, labels: np.ndarray) -> float:
    # log(1 + e^-z) for walls, log(1 + e^z) for free cells, computed stably.
    signed = np.where(labels, z, -z)
    return float(np.mean(np.logaddexp(0.0, -signed)))


def fit_logit_calibration(probability: np.ndarray, is_wall: np.ndarray, iterations: int = 50) -> LogitCalibration:
    """Maximum-likelihood Platt parameters for uncalibrated wall probabilities.

    Args:
        probability: float ``[N]`` uncalibrated probabilities in [0, 1] (sigmoid of the member logits).
        is_wall: bool ``[N]`` ground truth of the same cells.
        iterations: Newton steps (the log-likelihood is concave in the two parameters; a handful suffice).

    Returns:
        The :class:`LogitCalibration` with its fit statistics.

    Raises:
        ValueError: mismatched or empty inputs, probabilities outside [0, 1], or labels of one class only (the
            likelihood then has no finite maximum).
    """
    p = np.asarray(probability, np.float64).ravel()
    y = np.asarray(is_wall).ravel()
    if y.dtype != bool:
        raise ValueError(f"is_wall must be bool, got {y.dtype}")
    if p.shape != y.shape or p.size == 0:
        raise ValueError(f"probability and is_wall must be non-empty and of one size, got {p.size} and {y.size}")
    if not np.all((p >= 0.0) & (p <= 1.0)):
        raise ValueError("probabilities must lie in [0, 1]")
    if y.all() or not y.any():
        raise ValueError("calibration needs cells of both classes (walls and free cells)")
    z = _logit(p)
    target = y.astype(np.float64)
    params = np.array([1.0, 0.0])
    design = np.stack([z, np.ones_like(z)], axis=1)
    loss = _nll(design @ params, y)
    for _ in range(iterations):
        q = 0.5 * (1.0 + np.tanh(0.5 * (design @ params)))  # sigmoid without overflow
        gradient = design.T @ (q - target) / len(z)
        hessian = (design * (q * (1 - q))[:, None]).T @ design / len(z) + 1e-9 * np.eye(2)
        step = np.linalg.solve(hessian, gradient)
        # Damped Newton: far from the optimum a full step can overshoot (the Hessian vanishes where the
        # current fit saturates), so halve it until the likelihood does not fall.
        fraction = 1.0
        while fraction > 1e-6:
            candidate = params - fraction * step
            candidate_loss = _nll(design @ candidate, y)
            if candidate_loss <= loss:
                break
            fraction *= 0.5
        else:
            break
        params, loss = candidate, candidate_loss
        if np.abs(fraction * step).max() < 1e-10:
            break
    scale, offset = float(params[0]), float(params[1])
    calibrated = scale * z + offset
    return LogitCalibration(logit_scale=scale, logit_offset=offset, cells=int(len(z)),
                            wall_fraction=float(target.mean()), nll_before=_nll(z, y), nll_after=_nll(calibrated, y),
                            predicted_walls_before=float((z >= 0).mean()),
                            predicted_walls_after=float((calibrated >= 0).mean()))


@dataclass(frozen=True)
class CalibrationConfig:
    """Where the calibration samples come from.

    Attributes:
        maps: ``train`` maps to run episodes on (default: every map of a building not in
            ``heldout_buildings()``; held-out and eval maps are refused).
        coverages: line-of-sight coverages at which the ensemble predicts (the first step at or past each).
        steps: step budget of an episode.
        cells_per_prediction: unknown cells drawn (uniformly, seeded) from each prediction.
        seed: seed of the start cells and the cell draws.
    """

    maps: tuple[str, ...] = ()
    coverages: tuple[float, ...] = (0.05, 0.15, 0.25, 0.4)
    steps: int = 400
    cells_per_prediction: int = 4000
    seed: int = 0

    def __post_init__(self) -> None:
        if self.steps < 1 or self.cells_per_prediction < 1 or not self.coverages:
            raise ValueError("CalibrationConfig: steps and cells_per_prediction must be >= 1, coverages non-empty")
        if not all(0.0 < c < 1.0 for c in self.coverages) or list(self.coverages) != sorted(self.coverages):
            raise ValueError(f"coverages must increase within (0, 1), got {self.coverages}")


def calibration_maps(cfg: CalibrationConfig) -> list[str]:
    """``cfg.maps`` checked against, or by default all of, the ``train`` maps outside the held-out buildings.

    Raises:
        ValueError: a map outside that set (an eval map, a held-out building's map, an unknown name).
    """
    from superex_deploy.maps import list_maps, map_building
    from superex_train.generate import heldout_buildings

    heldout = set(heldout_buildings())
    allowed = [m for m in list_maps("train") if map_building(m) not in heldout]
    if not cfg.maps:
        return allowed
    refused = sorted(set(cfg.maps) - set(allowed))
    if refused:
        raise ValueError(f"calibration maps must be train maps outside the held-out buildings; refused {refused}")
    return list(cfg.maps)


def _episode_samples(task: tuple[str, int, str, str, CalibrationConfig]) -> tuple[np.ndarray, np.ndarray]:
    """Member probabilities and truth on unknown cells of one episode (see :func:`collect_calibration_samples`)."""
    from superex_deploy.evaluation.episodes import EpisodeState, run_episode
    from superex_deploy.evaluation.metrics import evaluation_area
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
    from superex_deploy.sim.sensing import SpadSensing
    from superex_deploy.onboard.types import UNKNOWN
    from superex_deploy.maps import load_map
    from superex_train.generate import random_start

    name, index, model_dir, kind_value, cfg = task
    kind = ModelKind(kind_value)
    session = SessionConfig(intra_op_threads=1)
    ensemble = LamaEnsemble.from_manifest(kind, model_dir, session)
    p2p = Pix2PixFilter.from_manifest(model_dir, session) if kind is ModelKind.LAMA_BP else None
    sensing = SpadSensing(bp_filter=p2p.filter_map) if p2p is not None else None
    grid = load_map(name)
    rng = np.random.default_rng([cfg.seed, index])
    area = evaluation_area(grid)
    pending = list(cfg.coverages)
    probabilities, labels = [], []

    class _Done(Exception):
        """Every coverage is behind."""

    def on_step(state: EpisodeState) -> None:
        if not pending:
            raise _Done
        if state.coverage < pending[0]:
            return
        while pending and state.coverage >= pending[0]:
            pending.pop(0)
        if kind is ModelKind.LAMA_BP:
            observed, evidence = state.observed, sensing.evidence
        else:
            observed, evidence = state.mapper.observed(include_carved=False), None
        unknown = np.flatnonzero((observed == UNKNOWN) & area)
        if len(unknown) == 0:
            return
        cells = rng.choice(unknown, size=min(cfg.cells_per_prediction, len(unknown)), replace=False)
        members = ensemble.predict_members(observed, evidence).reshape(ensemble.members, -1)
        probabilities.append(members[:, cells].ravel())
        labels.append(np.tile(grid.occupied.ravel()[cells], ensemble.members))

    planners = ("nearest", "hector", "mapex")
    try:
        run_episode(grid, random_start(grid, rng, 0.4), make_planner(planners[index % len(planners)]),
                    ObservedAsPrediction(), steps=cfg.steps, seed=index, sensing=sensing, on_step=on_step)
    except _Done:
        pass
    if not probabilities:
        return np.zeros(0, np.float32), np.zeros(0, bool)
    return np.concatenate(probabilities), np.concatenate(labels)


def collect_calibration_samples(kind: ModelKind, model_dir: PathLike = DEFAULT_MODEL_DIR,
                                cfg: CalibrationConfig = CalibrationConfig(), jobs: int = 1
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Uncalibrated member probabilities and ground truth on cells unknown at prediction time.

    One exploration episode per map (planner cycled over nearest / hector / mapex with the observed map as
    predictor, so the trajectory does not depend on the models; SuperEx sensing with the folder's Pix2Pix filter
    for LAMA_BP), predicting with the folder's ``kind`` ensemble when the line-of-sight coverage first reaches
    each of ``cfg.coverages``; every member's probability at ``cfg.cells_per_prediction`` random unknown cells of
    the evaluation area is kept.

    Returns:
        ``(probability float32 [N], is_wall bool [N])``.

    Raises:
        ValueError: a non-LaMa kind, maps outside the calibration set, or no sample at all.
    """
    if kind not in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS):
        raise ValueError(f"only LaMa ensembles are calibrated, got {kind.value}")
    maps = calibration_maps(cfg)
    tasks = [(name, i, str(model_dir), kind.value, cfg) for i, name in enumerate(maps)]
    if jobs > 1:
        with process_pool(jobs) as pool:
            parts = list(pool.map(_episode_samples, tasks))
    else:
        parts = [_episode_samples(task) for task in tasks]
    probability = np.concatenate([p for p, _ in parts])
    is_wall = np.concatenate([y for _, y in parts])
    if probability.size == 0:
        raise ValueError("the calibration episodes produced no sample")
    return probability, is_wall


def calibrate(kinds: Sequence[ModelKind], model_dir: PathLike = DEFAULT_MODEL_DIR,
              cfg: CalibrationConfig = CalibrationConfig(), jobs: int = 1,
              out: Optional[PathLike] = None, keep: Optional[dict[ModelKind, LogitCalibration]] = None
              ) -> dict[ModelKind, LogitCalibration]:
    """Collect samples and fit one calibration per ensemble kind; optionally write them as JSON to ``out``
    (the file :func:`read_calibration` and ``superex export --calibration`` read). ``keep``: fits of other kinds
    written beside the new ones as they are (an ensemble that was not retrained keeps its calibration); a kind
    both fitted and kept is fitted."""
    result = dict(keep or {})
    for kind in kinds:
        probability, is_wall = collect_calibration_samples(kind, model_dir, cfg, jobs)
        result[kind] = fit_logit_calibration(probability, is_wall)
    if out is not None:
        Path(out).write_text(json.dumps({"format": "superex-calibration/1", "config": asdict(cfg),
                                         "ensembles": {k.value: asdict(v) for k, v in result.items()}}, indent=1))
    return result


def read_calibration(path: PathLike) -> dict[ModelKind, LogitCalibration]:
    """The calibrations in a file written by :func:`calibrate`.

    Raises:
        ValueError: a missing or malformed file.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"calibration file {path} is missing")
    try:
        data = json.loads(path.read_text())
        if data.get("format") != "superex-calibration/1":
            raise ValueError(f"format {data.get('format')!r}")
        return {ModelKind(kind): LogitCalibration(**values) for kind, values in data["ensembles"].items()}
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise ValueError(f"calibration file {path} is malformed: {error}") from error
