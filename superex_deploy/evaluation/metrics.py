"""Per-episode metrics: coverage of the valid area over the steps, the map IoU of a prediction, the errors of the
explorer's own map, and the paper suite's metrics of one episode (:func:`scenario_metrics`). Their summaries over
episodes, with bootstrap intervals and paired by scenario, are :mod:`superex_deploy.evaluation.summary`'s.

Coverage is measured on the map's valid mask (the area inside the building, see
``superex_deploy/data/kth/README.md``; :func:`superex_deploy.maps.coverage`, which the world reports while it runs).
The valid mask never contains walls, so the map IoU is measured on the valid area grown by :data:`IOU_MARGIN_CELLS`
cells, which takes in the walls that bound it (about 90 % of the wall cells of the eval maps; the rest are the inner
cells of thick walls and walls outside the building).

An episode here is a :meth:`~superex_deploy.evaluation.episodes.EpisodeResult.to_json` dict (plus ``start_index``),
as ``superex benchmark`` writes them. The suite's coverage is the known share of the valid area **with NLOS
carving** (``coverage_with_carving``; equal to the line-of-sight coverage for rows without SPAD sensing); the
line-of-sight share is reported beside it. An episode that ends early (nothing left to explore) keeps its final
coverage. Episodes on altered floors (``superex benchmark --suite altered``) carry ``dead_ends``
(:meth:`~superex_deploy.sim.dead_ends.DeadEndEntries.to_json`); their metrics gain the dead-end entries
(:data:`DEAD_END_METRICS`).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
from scipy import ndimage

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

__all__ = ["IOU_MARGIN_CELLS", "MAP_ERROR_KEYS", "CHECKPOINTS", "IOU_LEVELS", "IOU_BINS", "DEAD_END_METRICS",
           "evaluation_area", "map_iou", "wall_iou", "wall_iou_tolerant", "MapErrors", "explorer_map_errors",
           "coverage_at", "coverage_auc", "first_half_auc", "coverage_curve", "coverage_curves", "iou_at_coverage",
           "scenario_metrics"]

IOU_MARGIN_CELLS = 2
MAP_ERROR_KEYS = ("collisions", "true_walls_held_free", "true_walls_carved", "map_iou", "true_walls_seen",
                  "true_walls_missing", "map_iou_within_cell")
"""The episode-log keys of the explorer map's errors against the truth (see :func:`explorer_map_errors`)."""


CHECKPOINTS = (100, 250, 500, 1000)
IOU_LEVELS = (0.05, 0.10, 0.20, 0.30)
IOU_BINS = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.3))
DEAD_END_METRICS = {"dead_end_entries": "entries", "dead_end_metres_in": "metres_in",
                    "dead_end_metres_inside": "metres_inside", "dead_end_reached": "reached_end"}
"""Metric name -> field of :class:`~superex_deploy.sim.dead_ends.DeadEndEntries`: entries into dead ends (at least
1 m deep), metres driven from each entry to its deepest pose (into a region that then closes with no new frontier),
metres driven inside dead ends in all, entries that reached the obstruction."""


def evaluation_area(grid: OccupancyGrid) -> np.ndarray:
    """bool ``[H, W]``: the valid area grown by :data:`IOU_MARGIN_CELLS` cells (8-connected), so the walls that
    bound it are scored too."""
    return ndimage.binary_dilation(grid.valid, structure=np.ones((3, 3), bool), iterations=IOU_MARGIN_CELLS)


def map_iou(mean: np.ndarray, grid: OccupancyGrid, threshold: float = 0.5,
            area: np.ndarray | None = None) -> float:
    """Occupied-class IoU of a predicted map against the ground-truth walls.

    Args:
        mean: float ``[H, W]`` predicted wall probability; ``mean >= threshold`` counts as a wall.
        grid: the ground truth.
        threshold: probability from which a cell is predicted to be a wall.
        area: bool ``[H, W]`` where to score; default :func:`evaluation_area` (pass it in to avoid recomputing).

    Returns:
        ``|pred & truth| / |pred | truth|`` within the area, in [0, 1]; 1.0 when both are empty.
    """
    mean = np.asarray(mean)
    if mean.shape != grid.shape:
        raise ValueError(f"prediction has shape {mean.shape}, the map has {grid.shape}")
    area = evaluation_area(grid) if area is None else area
    predicted = (mean >= threshold) & area
    truth = grid.occupied & area
    union = np.count_nonzero(predicted | truth)
    return np.count_nonzero(predicted & truth) / union if union else 1.0


def wall_iou(pred: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two bool wall masks of equal shape; 1.0 when both are empty."""
    pred, truth = np.asarray(pred), np.asarray(truth)
    if pred.dtype != np.bool_ or truth.dtype != np.bool_ or pred.shape != truth.shape:
        raise ValueError(f"pred and truth must be bool arrays of one shape, got {pred.dtype} {pred.shape} and "
                         f"{truth.dtype} {truth.shape}")
    union = np.count_nonzero(pred | truth)
    return 1.0 if union == 0 else np.count_nonzero(pred & truth) / union


def wall_iou_tolerant(pred: np.ndarray, truth: np.ndarray, tolerance_cells: float) -> float:
    """IoU that forgives misplacement by up to ``tolerance_cells`` (Euclidean, cell centres): a predicted cell
    counts as correct within that distance of a true one, a true cell as missed only beyond that distance of
    every prediction. ``|P & dilate(T)| / (|P| + |T - dilate(P)|)``; equals :func:`wall_iou` at tolerance 0
    and 1.0 when both masks are empty."""
    pred, truth = np.asarray(pred), np.asarray(truth)
    if pred.dtype != np.bool_ or truth.dtype != np.bool_ or pred.shape != truth.shape or pred.ndim != 2:
        raise ValueError(f"pred and truth must be 2-D bool arrays of one shape, got {pred.dtype} {pred.shape} "
                         f"and {truth.dtype} {truth.shape}")
    if not (np.isfinite(tolerance_cells) and tolerance_cells >= 0.0):
        raise ValueError(f"tolerance_cells must be finite and >= 0, got {tolerance_cells}")
    reach = int(np.floor(tolerance_cells))
    offsets = np.arange(-reach, reach + 1)
    disc = offsets[:, None] ** 2 + offsets[None, :] ** 2 <= tolerance_cells ** 2
    near_truth = ndimage.binary_dilation(truth, structure=disc)
    near_pred = ndimage.binary_dilation(pred, structure=disc)
    denominator = np.count_nonzero(pred) + np.count_nonzero(truth & ~near_pred)
    return 1.0 if denominator == 0 else np.count_nonzero(pred & near_truth) / denominator


class MapErrors(NamedTuple):
    """How the explorer's own final map errs against the truth (:func:`explorer_map_errors`).

    Attributes:
        held_free: true wall cells the map holds FREE, anywhere.
        map_iou: wall-class IoU of the map's OCCUPIED cells against the true walls within the area.
        seen: true wall cells the map holds known (FREE or OCCUPIED): the walls "seen", the denominator of a
            held-free rate.
        missing: the held-free true wall cells with no OCCUPIED map cell among their 8 neighbours: walls the map
            lacks, not walls it holds one cell off (a pose error of half a cell or more moves a whole wall face by
            a cell in a 0.1 m grid; both count in ``held_free``).
        map_iou_within_cell: :func:`wall_iou_tolerant` within one cell, diagonals included (tolerance 1.5 cells:
            a wall held one cell off counts as found; phantom walls farther than a cell from every true wall still
            count against it).
    """

    held_free: int
    map_iou: float
    seen: int
    missing: int
    map_iou_within_cell: float


def explorer_map_errors(observed: np.ndarray, grid: OccupancyGrid, area: np.ndarray | None = None) -> MapErrors:
    """How the explorer's own map (not a prediction) errs against the truth.

    Args:
        observed: int8 ``[H, W]`` the explorer's map (FREE, OCCUPIED, UNKNOWN; carved cells FREE).
        grid: the ground truth.
        area: bool ``[H, W]`` where the IoUs are scored; default :func:`evaluation_area`.

    Returns:
        The :class:`MapErrors`.
    """
    observed = np.asarray(observed)
    if observed.shape != grid.shape:
        raise ValueError(f"observed has shape {observed.shape}, the map has {grid.shape}")
    area = evaluation_area(grid) if area is None else area
    held = (observed == FREE) & grid.occupied
    walls = observed == OCCUPIED
    near_wall = ndimage.binary_dilation(walls, structure=np.ones((3, 3), bool))
    seen = int(np.count_nonzero((observed != UNKNOWN) & grid.occupied))
    return MapErrors(held_free=int(np.count_nonzero(held)), map_iou=wall_iou(walls & area, grid.occupied & area),
                     seen=seen, missing=int(np.count_nonzero(held & ~near_wall)),
                     map_iou_within_cell=wall_iou_tolerant(walls & area, grid.occupied & area, 1.5))


def coverage_at(series: Sequence[float], step: int) -> float:
    """Coverage after ``step`` steps (1-based) of a per-step series; an episode that ended earlier (nothing left
    to explore) keeps its last value. ``nan`` for an empty series."""
    if len(series) == 0:
        return float("nan")
    return float(series[min(int(step), len(series)) - 1])


def coverage_auc(series: Sequence[float], first: int, last: int) -> float:
    """Mean coverage over steps ``first..last`` (1-based, both included) of a per-step series, read by
    :func:`coverage_at` (an early end keeps its last value): the area under the coverage curve per step."""
    return float(np.mean([coverage_at(series, s) for s in range(first, last + 1)]))


def first_half_auc(series: Sequence[float], steps: int) -> float:
    """The benchmarks' headline: mean coverage over steps ``1..steps // 2`` (at least step 1) of an episode run
    for ``steps`` steps; an empty series counts as coverage 0. The first half rewards exploring fast, where the
    whole run's mean mostly measures where coverage saturates."""
    return coverage_auc(list(series) or [0.0], 1, max(steps // 2, 1))


def coverage_curve(series: Sequence[float], steps: int) -> list[float]:
    """Coverage after each of steps ``1..steps`` (:func:`coverage_at`: an early end keeps its last value)."""
    return [coverage_at(series, s) for s in range(1, steps + 1)]


def iou_at_coverage(episode: dict, level: float) -> float:
    """The prediction's map IoU when the episode's coverage first reached ``level``, linear between the logged
    evaluations (``episode["iou"]``: ``coverage`` and ``iou`` lists); ``nan`` if it never did."""
    coverage, iou = np.asarray(episode["iou"]["coverage"], float), np.asarray(episode["iou"]["iou"], float)
    if coverage.size == 0 or coverage.max() < level:
        return float("nan")
    return float(np.interp(level, np.maximum.accumulate(coverage), iou))


def coverage_curves(episodes: list[dict], steps: int) -> np.ndarray:
    """float64 ``[n_episodes, steps]`` coverage with carving at steps 1..steps (early ends keep their value)."""
    return np.array([[coverage_at(_series(e, "coverage_with_carving"), s) for s in range(1, steps + 1)]
                     for e in episodes])


def _series(episode: dict, key: str) -> list[float]:
    return episode[key] if episode[key] else [0.0]


def scenario_metrics(episode: dict, steps: int = 1000) -> dict[str, float]:
    """Metrics of one episode (fractions, not percent).

    Returns:
        ``coverage@N`` (with carving) and ``los_coverage@N`` for N in :data:`CHECKPOINTS` up to ``steps``;
        ``auc_first_half``: mean coverage over steps 1..steps/2, ``auc``: over 1..steps (and ``los_auc_*``);
        ``iou@L``: the map IoU at the first evaluation whose coverage reached L (:data:`IOU_LEVELS`; ``nan``
        if never reached); ``iou_bin_A_B``: mean IoU of the evaluations with coverage in ``[A, B)``
        (:data:`IOU_BINS`; ``nan`` if none); ``final_iou``; and, when the log has its stage times,
        ``scoring_ms_per_goal`` and ``prediction_ms_per_goal`` (the mean time per goal choice).
    """
    carved, los = _series(episode, "coverage_with_carving"), _series(episode, "coverage")
    out = {}
    for n in CHECKPOINTS:
        if n <= steps:
            out[f"coverage@{n}"] = coverage_at(carved, n)
            out[f"los_coverage@{n}"] = coverage_at(los, n)
    out["auc_first_half"] = first_half_auc(carved, steps)
    out["auc"] = coverage_auc(carved, 1, steps)
    out["los_auc_first_half"] = first_half_auc(los, steps)
    out["los_auc"] = coverage_auc(los, 1, steps)
    iou_cov = np.asarray(episode["iou"]["coverage"], float)
    iou = np.asarray(episode["iou"]["iou"], float)
    for level in IOU_LEVELS:
        reached = np.flatnonzero(iou_cov >= level)
        out[f"iou@{level:.2f}"] = float(iou[reached[0]]) if len(reached) else float("nan")
    for low, high in IOU_BINS:
        inside = (iou_cov >= low) & (iou_cov < high)
        out[f"iou_bin_{low:.1f}_{high:.1f}"] = float(iou[inside].mean()) if inside.any() else float("nan")
    out["final_iou"] = float(iou[-1]) if len(iou) else float("nan")
    if "mean_step_s" in episode and episode["goals"]["steps"]:
        # Per goal choice: the planner's own work and the predictor's (metric evaluation excluded).
        choices = len(episode["goals"]["steps"])
        for stage in ("scoring", "prediction"):
            out[f"{stage}_ms_per_goal"] = 1000 * episode["mean_step_s"][stage] * episode["steps"] / choices
    if "dead_ends" in episode:
        for metric, field in DEAD_END_METRICS.items():
            out[metric] = float(episode["dead_ends"][field])
    return out
