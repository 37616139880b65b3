"""Exploration metrics (coverage, map IoU) and the benchmark's aggregation into a results table.

Coverage is measured on the map's valid mask (the area inside the building, see
``superex_deploy/data/kth/README.md``). The valid mask never contains walls, so the map IoU is measured on the
valid area grown by :data:`IOU_MARGIN_CELLS` cells, which takes in the walls that bound it (about 90 % of the
wall cells of the eval maps; the rest are the inner cells of thick walls and walls outside the building).
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np
from scipy import ndimage

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

__all__ = ["IOU_MARGIN_CELLS", "coverage", "evaluation_area", "map_iou", "coverage_at", "coverage_auc",
           "first_half_auc", "summarise",
           "results_markdown", "pair_by_scenario", "difference_counts", "paired_differences"]

IOU_MARGIN_CELLS = 2
MAP_ERROR_KEYS = ("collisions", "true_walls_held_free", "true_walls_carved", "map_iou", "true_walls_seen",
                  "true_walls_missing", "map_iou_within_cell")
"""The episode-log keys of the explorer map's errors against the truth (see :func:`explorer_map_errors`)."""


def coverage(known: np.ndarray, valid: np.ndarray) -> float:
    """Fraction of the valid area that is known.

    Args:
        known: bool ``[H, W]`` cells known (seen free, seen wall or carved).
        valid: bool ``[H, W]`` the area coverage is measured on.

    Returns:
        ``|known & valid| / |valid|`` in [0, 1]; 1.0 for an empty valid area.
    """
    known, valid = np.asarray(known), np.asarray(valid)
    if known.shape != valid.shape:
        raise ValueError(f"known has shape {known.shape}, valid has {valid.shape}")
    total = np.count_nonzero(valid)
    return np.count_nonzero(known & valid) / total if total else 1.0


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


def _mean_std(values: list[float]) -> tuple[float, float]:
    values = [v for v in values if np.isfinite(v)]
    return (float(np.mean(values)), float(np.std(values))) if values else (float("nan"), float("nan"))


def summarise(results: list[dict], checkpoints: Sequence[int] = (250, 500, 1000), map_errors: bool = False
              ) -> list[dict]:
    """Per-planner results table from :meth:`~superex_deploy.sim.episode.EpisodeResult.to_json` dicts.

    Each row holds ``planner``, ``episodes`` and ``(mean, std)`` pairs over episodes of: line-of-sight coverage
    ``coverage@N`` and carving-inclusive ``coverage_carved@N`` at each checkpoint, the area under the coverage
    curve per step ``coverage_auc``, the final ``path_length_m`` and the ``final_iou``; with ``map_errors`` (runs
    with noise) also :data:`MAP_ERROR_KEYS` (collisions, true walls held free and carved, the explorer map's IoU).
    Rows are sorted by planner name.
    """
    by_planner: dict[str, list[dict]] = {}
    for result in results:
        by_planner.setdefault(result["planner"], []).append(result)
    rows = []
    for planner, runs in sorted(by_planner.items()):
        row: dict = {"planner": planner, "episodes": len(runs)}
        for step in checkpoints:
            row[f"coverage@{step}"] = _mean_std([coverage_at(r["coverage"], step) for r in runs])
        for step in checkpoints:
            row[f"coverage_carved@{step}"] = _mean_std(
                [coverage_at(r["coverage_with_carving"], step) for r in runs])
        horizon = max(checkpoints) if checkpoints else 1
        row["coverage_auc"] = _mean_std([coverage_auc(r["coverage"], 1, horizon) for r in runs if r["coverage"]])
        row["path_length_m"] = _mean_std([r["path_length_m"][-1] for r in runs if r["path_length_m"]])
        row["final_iou"] = _mean_std([r["iou"]["iou"][-1] for r in runs if r["iou"]["iou"]])
        for key in MAP_ERROR_KEYS if map_errors else ():
            row[key] = _mean_std([float(r[key]) for r in runs if key in r])
        rows.append(row)
    return rows


def _scenario_key(result: dict) -> tuple:
    return result["map"], int(result["start_index"]), result["planner"]


def pair_by_scenario(baseline: list[dict], candidate: list[dict], key: Callable[[dict], tuple] = _scenario_key,
                     what: str = "runs") -> list[tuple[dict, dict]]:
    """The episodes of two runs paired by scenario: ``(baseline episode, candidate episode)`` in the order of
    their sorted ``key`` (default: map, start index, planner); ``what`` names the runs in error messages.

    Raises:
        ValueError: a run holds a scenario twice, or the runs do not hold the same scenarios.
    """
    runs = []
    for name, episodes in (("baseline", baseline), ("candidate", candidate)):
        keyed = {}
        for episode in episodes:
            scenario = key(episode)
            if scenario in keyed:
                raise ValueError(f"the {name} run holds scenario {scenario} twice")
            keyed[scenario] = episode
        runs.append(keyed)
    if set(runs[0]) != set(runs[1]):
        missing = sorted(set(runs[0]) ^ set(runs[1]))
        raise ValueError(f"the {what} hold different scenarios (e.g. {missing[:3]}); pair {what} of the same "
                         f"scenarios")
    return [(runs[0][scenario], runs[1][scenario]) for scenario in sorted(runs[0])]


def difference_counts(differences: np.ndarray, tie_tolerance: float = 1e-6) -> dict[str, int]:
    """How many paired differences (candidate - baseline, float ``[n]``) are ``better`` (above
    ``tie_tolerance``), ``worse`` (below ``-tie_tolerance``) or ``tied``."""
    return {"better": int(np.sum(differences > tie_tolerance)), "worse": int(np.sum(differences < -tie_tolerance)),
            "tied": int(np.sum(np.abs(differences) <= tie_tolerance))}


def paired_differences(baseline: list[dict], candidate: list[dict], checkpoints: Sequence[int],
                       series: str = "coverage", baseline_series: str = "coverage",
                       tie_tolerance: float = 1e-6) -> dict:
    """Scenario-by-scenario comparison of two benchmark runs (``results.json`` episode dicts of ``superex
    benchmark``), paired by (map, start index, planner).

    For each checkpoint ``N`` (steps) the difference is ``candidate[series]@N - baseline[baseline_series]@N``
    (coverage fractions); ``final_iou`` compares each episode's last logged map IoU. Each entry holds ``n``,
    each run's mean (``baseline_mean``, ``candidate_mean``), the ``median`` and ``mean`` difference, and how
    many scenarios are ``better`` / ``worse`` / ``tied`` (within ``tie_tolerance``).

    Raises:
        ValueError: the runs do not cover the same scenarios, a scenario appears twice, or an unknown series.
    """
    pairs = pair_by_scenario(baseline, candidate)
    for name, key in (("series", series), ("baseline_series", baseline_series)):
        if key not in ("coverage", "coverage_with_carving"):
            raise ValueError(f"{name} must be 'coverage' or 'coverage_with_carving', got {key!r}")

    def describe(baseline_values: list[float], candidate_values: list[float]) -> dict:
        base, cand = np.asarray(baseline_values, float), np.asarray(candidate_values, float)
        values = cand - base
        return {"n": int(values.size), "baseline_mean": float(base.mean()), "candidate_mean": float(cand.mean()),
                "median": float(np.median(values)), "mean": float(np.mean(values)),
                **difference_counts(values, tie_tolerance)}

    out = {}
    for step in checkpoints:
        out[f"coverage@{step}"] = describe([coverage_at(b[baseline_series], step) for b, _ in pairs],
                                           [coverage_at(c[series], step) for _, c in pairs])
    ious = [(b["iou"]["iou"], c["iou"]["iou"]) for b, c in pairs]
    if all(b and c for b, c in ious):
        out["final_iou"] = describe([b[-1] for b, _ in ious], [c[-1] for _, c in ious])
    return out


def results_markdown(rows: list[dict]) -> str:
    """A markdown table of :func:`summarise` rows, ``mean ± std`` per cell (coverage in percent)."""
    if not rows:
        return "(no results)\n"
    columns = [key for key in rows[0] if key not in ("planner", "episodes")]
    header = "| planner | episodes | " + " | ".join(columns) + " |"
    lines = [header, "|" + "---|" * (len(columns) + 2)]
    for row in rows:
        cells = []
        for key in columns:
            mean, std = row[key]
            scale = 100.0 if key.startswith("coverage") else 1.0
            counts = key in MAP_ERROR_KEYS and not key.startswith("map_iou")
            digits = 1 if key.startswith("coverage") or key == "path_length_m" or counts else 3
            cells.append(f"{mean * scale:.{digits}f} ± {std * scale:.{digits}f}")
        lines.append(f"| {row['planner']} | {row['episodes']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


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


__all__ += ["wall_iou", "wall_iou_tolerant", "MapErrors", "explorer_map_errors", "MAP_ERROR_KEYS"]
