"""Per-episode metrics and their paired statistics, one home each.

The coverage curve's integrals (:func:`first_half_auc`, :func:`coverage_auc`) live in
:mod:`superex_deploy.sim.metrics` and the percentile bootstrap (:func:`bootstrap_interval`) with the paper suite's
metrics in :mod:`superex_deploy.sim.suite`, below this package, because the simulator's summaries and the paper
figures (:mod:`superex_deploy.render`) read them too; they are re-exported here so a benchmark imports its
measures from one place.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from superex_deploy.sim.metrics import coverage_at, coverage_auc, difference_counts, first_half_auc
from superex_deploy.sim.suite import (IOU_LEVELS, bootstrap_interval, common_scenarios, paired_summary, row_summary,
                                      scenario_key, scenario_metrics)

__all__ = ["coverage_at", "coverage_auc", "first_half_auc", "coverage_curve", "iou_at_coverage",
           "bootstrap_interval", "mean_with_interval", "difference_counts", "scenario_key", "scenario_metrics",
           "row_summary", "paired_summary", "common_scenarios", "IOU_LEVELS"]


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


def mean_with_interval(values: Sequence[float], rng: np.random.Generator, resamples: int = 2000
                       ) -> tuple[float, float, float]:
    """``(mean, low, high)`` of the finite ``values``: their mean and its bootstrap 95 % interval
    (:func:`bootstrap_interval` at quantiles 0.025 / 0.975) drawn from ``rng``, a stream several rows' intervals
    share; ``nan`` three times if none is finite."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), float("nan"), float("nan")
    low, high = bootstrap_interval(values, resamples=resamples, rng=rng, levels=(0.025, 0.975))
    return float(values.mean()), low, high
