"""The benchmarks' evaluation library: scenario sets, one episode runner, the metrics and their paired bootstrap
intervals, and report writers. The scripts under ``scripts/`` each ask one question with it; the paper suite's
rows are the named pipelines (:data:`superex_deploy.pipeline.PIPELINES`), its metrics :mod:`superex_deploy.sim.suite`'s.

* :mod:`~superex_deploy.evaluation.scenarios`: the eval, held-out train and altered-floor scenario sets;
* :mod:`~superex_deploy.evaluation.episodes`: :func:`run_benchmark_episode`;
* :mod:`~superex_deploy.evaluation.tasks`: one benchmark episode by names, picklable for worker processes and Ray
  (:class:`~superex_deploy.evaluation.tasks.ScenarioTask`, what ``superex benchmark`` runs);
* :mod:`~superex_deploy.evaluation.metrics`: first-half AUC, IoU at coverage levels, bootstrap intervals;
* :mod:`~superex_deploy.evaluation.known_distance`: a predicted map's accuracy and calibration by distance from
  known space, and the strength of a periodic lattice in it;
* :mod:`~superex_deploy.evaluation.reports`: Markdown tables, atomic JSON / text / figure writers.
"""

from superex_deploy.evaluation.episodes import EpisodeRun, run_benchmark_episode
from superex_deploy.evaluation.metrics import (bootstrap_interval, coverage_at, coverage_auc, coverage_curve,
                                               first_half_auc, iou_at_coverage, mean_with_interval, scenario_key,
                                               scenario_metrics)
from superex_deploy.evaluation.reports import markdown_table, read_json, save_figure, write_json, write_text
from superex_deploy.evaluation.scenarios import (HELDOUT_BUILDINGS, Scenario, altered_scenarios, eval_scenarios,
                                                 heldout_scenarios, train_scenarios)

__all__ = ["EpisodeRun", "run_benchmark_episode", "bootstrap_interval", "coverage_at", "coverage_auc",
           "coverage_curve", "first_half_auc", "iou_at_coverage", "mean_with_interval", "scenario_key",
           "scenario_metrics", "markdown_table", "read_json", "save_figure", "write_json", "write_text",
           "HELDOUT_BUILDINGS", "Scenario", "altered_scenarios", "eval_scenarios", "heldout_scenarios",
           "train_scenarios"]
