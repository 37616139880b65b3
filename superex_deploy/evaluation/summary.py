"""Summaries of episodes: one row's means with percentile bootstrap intervals, and two rows compared scenario by
scenario (paired differences with their intervals). The one summary stack of the benchmarks: ``superex benchmark``
(:func:`summary_table`), its paper suite (:func:`row_summary`, :func:`paired_summary`) and the scripts under
``scripts/``. The per-episode metrics it summarises are :mod:`superex_deploy.evaluation.metrics`'.

A scenario is a floor and a start (:func:`scenario_key`): two rows' episodes pair on it.
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import numpy as np

from superex_deploy.evaluation.metrics import MAP_ERROR_KEYS, coverage_at, scenario_metrics

__all__ = ["REFERENCE_ROW", "bootstrap_interval", "mean_with_interval", "scenario_key", "pair_by_scenario",
           "common_scenarios", "difference_counts", "row_summary", "row_intervals", "summary_table",
           "summary_markdown", "paired_summary", "paired_differences"]


REFERENCE_ROW = "mapex_lama_los"
"""Every row of the paper suite is paired against this one (MapEx as published: its planner on the line-of-sight
ensemble)."""


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


def scenario_key(episode: dict) -> tuple:
    """``(map, start index)``: the scenario an episode ran, what pairs two rows' episodes."""
    return episode["map"], int(episode["start_index"])


def pair_by_scenario(baseline: list[dict], candidate: list[dict], key: Callable[[dict], tuple] = scenario_key,
                     what: str = "runs") -> list[tuple[dict, dict]]:
    """The episodes of two runs paired by scenario: ``(baseline episode, candidate episode)`` in the order of
    their sorted ``key`` (default: :func:`scenario_key`); ``what`` names the runs in error messages.

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


def common_scenarios(reference: list[dict], candidate: list[dict]) -> tuple[list[dict], list[dict]]:
    """The episodes of two rows on the scenarios (map, start index) both hold, each row's in its own order: a row
    run on fewer scenarios (an expensive one) is paired on those."""
    shared = {scenario_key(e) for e in reference} & {scenario_key(e) for e in candidate}
    return [e for e in reference if scenario_key(e) in shared], [e for e in candidate if scenario_key(e) in shared]


def _episode_values(episode: dict, steps: int, extra: Sequence[str]) -> dict[str, float]:
    values = scenario_metrics(episode, steps)
    for key in extra:
        if key in episode:
            value = episode[key]
            values[key] = float(value[-1] if len(value) else np.nan) if isinstance(value, list) else float(value)
    return values


def _by_metric(episodes: list[dict], steps: int, extra: Sequence[str]) -> dict[str, np.ndarray]:
    """Metric -> float64 ``[n_episodes]`` (``nan`` where an episode lacks it), the metrics of the first episode."""
    per = [_episode_values(e, steps, extra) for e in episodes]
    return {key: np.array([p.get(key, np.nan) for p in per], float) for key in (per[0] if per else ())}


def _is_median(metric: str) -> bool:
    # The per-goal times are medians over episodes: a loaded machine makes a few episodes slow.
    return metric.endswith("_ms_per_goal")


def row_summary(episodes: list[dict], steps: int, extra: Sequence[str] = ()) -> dict[str, float]:
    """Mean of each :func:`~superex_deploy.evaluation.metrics.scenario_metrics` entry over a row's episodes (``nan``
    entries skipped); the per-goal times are medians over episodes (a loaded machine makes a few episodes slow).
    ``extra`` names episode fields summarised too: a number, or a per-step series read at its last step
    (``"path_length_m"``, the :data:`~superex_deploy.evaluation.metrics.MAP_ERROR_KEYS`)."""
    out = {}
    for key, values in _by_metric(episodes, steps, extra).items():
        if not np.isfinite(values).any():
            out[key] = float("nan")
        elif _is_median(key):
            out[key] = float(np.nanmedian(values))
        else:
            out[key] = float(np.nanmean(values))
    return out


def row_intervals(episodes: list[dict], steps: int, extra: Sequence[str] = (), confidence: float = 0.95,
                  resamples: int = 10000, seed: int = 0) -> dict[str, tuple[float, float]]:
    """The bootstrap interval (:func:`bootstrap_interval`, a fresh generator of ``seed`` per metric) of each
    :func:`row_summary` entry: of the mean, of the median for the per-goal times; ``(nan, nan)`` where no episode
    has a finite value."""
    return {key: bootstrap_interval(values, confidence, resamples, seed,
                                    statistic=np.median if _is_median(key) else np.mean)
            for key, values in _by_metric(episodes, steps, extra).items()}


def summary_table(episodes: list[dict], steps: int, by: str = "planner", extra: Sequence[str] = (),
                  confidence: float = 0.95, seed: int = 0) -> list[dict]:
    """One row per value of ``episode[by]`` (sorted): ``{by: value, "episodes": n, metric: {"mean", "low",
    "high"}}`` for each :func:`row_summary` metric (with ``extra``), the interval of :func:`row_intervals`.
    ``superex benchmark``'s summary (``by="planner"``)."""
    rows: dict[str, list[dict]] = {}
    for episode in episodes:
        rows.setdefault(episode[by], []).append(episode)
    table = []
    for name, row in sorted(rows.items()):
        means, intervals = row_summary(row, steps, extra), row_intervals(row, steps, extra, confidence, seed=seed)
        table.append({by: name, "episodes": len(row),
                      **{key: {"mean": means[key], "low": intervals[key][0], "high": intervals[key][1]}
                         for key in means}})
    return table


def _cell(metric: str, value: dict) -> str:
    percent = metric.split("@")[0] in ("coverage", "los_coverage") or metric.split("_first")[0] in ("auc", "los_auc")
    scale = 100.0 if percent else 1.0
    counts = metric in MAP_ERROR_KEYS and not metric.startswith("map_iou")
    digits = 1 if percent or counts or metric == "path_length_m" or metric.endswith("_ms_per_goal") else 3
    return f"{value['mean'] * scale:.{digits}f} [{value['low'] * scale:.{digits}f}, {value['high'] * scale:.{digits}f}]"


def summary_markdown(rows: list[dict], metrics: Optional[Sequence[str]] = None) -> str:
    """A Markdown table of :func:`summary_table` rows, ``mean [low, high]`` per cell (coverage and its AUCs in
    percent); ``metrics``: the columns, in this order (default: every metric of the first row)."""
    if not rows:
        return "(no results)\n"
    name = next(iter(rows[0]))
    columns = list(metrics) if metrics is not None else [k for k in rows[0] if k not in (name, "episodes")]
    lines = [f"| {name} | episodes | " + " | ".join(columns) + " |", "|" + "---|" * (len(columns) + 2)]
    for row in rows:
        cells = [_cell(key, row[key]) if key in row else "" for key in columns]
        lines.append(f"| {row[name]} | {row['episodes']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def paired_summary(reference: list[dict], candidate: list[dict], steps: int, tie_tolerance: float = 1e-6
                   ) -> dict[str, dict]:
    """Each metric of ``candidate`` minus ``reference``, paired by (map, start index).

    Returns:
        metric -> ``{"n", "mean", "low", "high" (bootstrap 95 % interval of the mean difference), "ratio"
        (candidate mean / reference mean - 1), "better", "worse", "tied"}``.

    Raises:
        ValueError: the two rows do not hold the same scenarios, or a row holds one twice
            (:func:`pair_by_scenario`).
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
    pairs = pair_by_scenario(baseline, candidate, key=lambda episode: (*scenario_key(episode), episode["planner"]))
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
