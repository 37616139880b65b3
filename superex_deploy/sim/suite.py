"""The paper's exploration benchmark: per-scenario metrics, and comparisons paired by scenario against a reference
row with bootstrap intervals. Its rows are the named pipelines (:data:`superex_deploy.pipeline.PIPELINES`: planner x
predictor x sensing).

A row's episodes are :meth:`~superex_deploy.sim.episode.EpisodeResult.to_json` dicts (plus ``start_index``),
as ``superex benchmark`` writes them. Coverage is the known share of the valid area **with NLOS carving**
(``coverage_with_carving``; equal to the line-of-sight coverage for rows without SPAD sensing); the line-of-sight
share is reported beside it. An episode that ends early (nothing left to explore) keeps its final coverage.

Episodes on altered floors (``superex benchmark --suite altered``) carry ``dead_ends``
(:meth:`~superex_deploy.sim.dead_ends.DeadEndEntries.to_json`); their metrics gain the dead-end entries
(:data:`DEAD_END_METRICS`), paired like every other metric.
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import numpy as np

from superex_deploy.sim.metrics import (coverage_at, coverage_auc, difference_counts, first_half_auc,
                                        pair_by_scenario)

__all__ = ["REFERENCE_ROW", "CHECKPOINTS", "IOU_LEVELS", "IOU_BINS",
           "DEAD_END_METRICS", "scenario_metrics", "bootstrap_interval", "paired_summary", "row_summary",
           "coverage_curves", "common_scenarios", "scenario_key"]


REFERENCE_ROW = "mapex_lama_los"
"""Every row is paired against this one (MapEx as published: its planner on the line-of-sight ensemble)."""

CHECKPOINTS = (100, 250, 500, 1000)
IOU_LEVELS = (0.05, 0.10, 0.20, 0.30)
IOU_BINS = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.3))
DEAD_END_METRICS = {"dead_end_entries": "entries", "dead_end_metres_in": "metres_in",
                    "dead_end_metres_inside": "metres_inside", "dead_end_reached": "reached_end"}
"""Metric name -> field of :class:`~superex_deploy.sim.dead_ends.DeadEndEntries`: entries into dead ends (at least
1 m deep), metres driven from each entry to its deepest pose (into a region that then closes with no new frontier),
metres driven inside dead ends in all, entries that reached the obstruction."""


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


def bootstrap_interval(values: Sequence[float], confidence: float = 0.95, resamples: int = 10000,
                       seed: int = 0, *, rng: Optional[np.random.Generator] = None,
                       statistic: Callable[..., np.ndarray] = np.mean,
                       levels: Optional[tuple[float, float]] = None) -> tuple[float, float]:
    """Percentile bootstrap interval of ``statistic`` (the mean by default) over ``values`` (finite ones;
    ``(nan, nan)`` if none): the one implementation every benchmark's interval comes from.

    Args:
        values: the sample, float (paired differences, for a paired interval).
        confidence: the interval's coverage; its quantiles are ``(1 - confidence) / 2`` and ``1 - that``.
        resamples: bootstrap resamples, each of ``len(values)`` draws with replacement.
        seed: seeds a fresh generator, unless ``rng`` is given.
        rng: draw from this generator instead (a stream shared by several intervals, advanced by each).
        statistic: ``statistic(draws, axis=1)`` of the ``[resamples, n]`` resampled values (``np.median``...).
        levels: the two quantile levels instead of those of ``confidence`` (``(0.025, 0.975)``: the spelling
            some benchmarks were committed with, which differs from 0.95's in the last bits).
    """
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed) if rng is None else rng
    draws = statistic(values[rng.integers(0, values.size, (resamples, values.size))], axis=1)
    if levels is None:
        tail = (1.0 - confidence) / 2.0
        levels = (tail, 1.0 - tail)
    return float(np.quantile(draws, levels[0])), float(np.quantile(draws, levels[1]))


def scenario_key(episode: dict) -> tuple:
    """``(map, start index)``: what pairs two rows' episodes."""
    return episode["map"], int(episode["start_index"])


def row_summary(episodes: list[dict], steps: int) -> dict[str, float]:
    """Mean of each :func:`scenario_metrics` entry over a row's episodes (``nan`` entries skipped); the
    per-goal times are medians over episodes (a loaded machine makes a few episodes slow)."""
    per = [scenario_metrics(e, steps) for e in episodes]
    out = {}
    for key in (per[0] if per else ()):
        values = np.array([p.get(key, np.nan) for p in per], float)
        if not np.isfinite(values).any():
            out[key] = float("nan")
        elif key.endswith("_ms_per_goal"):
            out[key] = float(np.nanmedian(values))
        else:
            out[key] = float(np.nanmean(values))
    return out


def paired_summary(reference: list[dict], candidate: list[dict], steps: int, tie_tolerance: float = 1e-6
                   ) -> dict[str, dict]:
    """Each metric of ``candidate`` minus ``reference``, paired by (map, start index).

    Returns:
        metric -> ``{"n", "mean", "low", "high" (bootstrap 95 % interval of the mean difference), "ratio"
        (candidate mean / reference mean - 1), "better", "worse", "tied"}``.

    Raises:
        ValueError: the two rows do not hold the same scenarios, or a row holds one twice
            (:func:`~superex_deploy.sim.metrics.pair_by_scenario`).
    """
    per_scenario = [(scenario_metrics(ref, steps), scenario_metrics(cand, steps))
                    for ref, cand in pair_by_scenario(reference, candidate, scenario_key, what="rows")]
    out = {}
    for metric in per_scenario[0][0] if per_scenario else ():
        if metric.endswith("_ms_per_goal") or any(metric not in cand for _, cand in per_scenario):
            continue
        pairs = np.array([(ref[metric], cand[metric]) for ref, cand in per_scenario], float)
        pairs = pairs[np.isfinite(pairs).all(axis=1)]
        if len(pairs) == 0:
            continue
        diff = pairs[:, 1] - pairs[:, 0]
        low, high = bootstrap_interval(diff)
        base = pairs[:, 0].mean()
        out[metric] = {"n": int(len(diff)), "mean": float(diff.mean()), "low": low, "high": high,
                       "ratio": float(pairs[:, 1].mean() / base - 1.0) if base else float("nan"),
                       **difference_counts(diff, tie_tolerance)}
    return out


def common_scenarios(reference: list[dict], candidate: list[dict]) -> tuple[list[dict], list[dict]]:
    """The episodes of two rows on the scenarios (map, start index) both hold, each row's in its own order: a row
    run on fewer scenarios (an expensive one) is paired on those."""
    shared = {scenario_key(e) for e in reference} & {scenario_key(e) for e in candidate}
    return [e for e in reference if scenario_key(e) in shared], [e for e in candidate if scenario_key(e) in shared]


def coverage_curves(episodes: list[dict], steps: int) -> np.ndarray:
    """float64 ``[n_episodes, steps]`` coverage with carving at steps 1..steps (early ends keep their value)."""
    return np.array([[coverage_at(_series(e, "coverage_with_carving"), s) for s in range(1, steps + 1)]
                     for e in episodes])
