"""The benchmarks' evaluation, whole: scenario sets, the episode runner, the per-episode metrics, one summary with
bootstrap intervals, and report writers. The simulator (:mod:`superex_deploy.sim`) is the world the runner steps;
the scripts under ``scripts/`` each ask one question with this package; the paper suite's rows are the named
pipelines (:data:`superex_deploy.pipeline.PIPELINES`).

* :mod:`~superex_deploy.evaluation.scenarios`: the eval, held-out train and altered-floor scenario sets;
* :mod:`~superex_deploy.evaluation.episodes`: the episode runner
  (:func:`~superex_deploy.evaluation.episodes.run_episode`, every explorer by
  :func:`superex_deploy.pipeline.build_explorer`) and :func:`run_benchmark_episode` (by names);
* :mod:`~superex_deploy.evaluation.tasks`: one benchmark episode by names, picklable for worker processes and Ray
  (:class:`~superex_deploy.evaluation.tasks.ScenarioTask`, what ``superex benchmark`` runs);
* :mod:`~superex_deploy.evaluation.metrics`: per-episode metrics: coverage curves and their AUCs, map IoU, the
  explorer map's errors, the paper suite's metrics of an episode;
* :mod:`~superex_deploy.evaluation.summary`: a row's means with bootstrap intervals, rows paired by scenario;
* :mod:`~superex_deploy.evaluation.known_distance`: a predicted map's accuracy and calibration by distance from
  known space, and the strength of a periodic lattice in it;
* :mod:`~superex_deploy.evaluation.reports`: Markdown tables, atomic JSON / text / figure writers.
"""

from superex_deploy.evaluation.episodes import EpisodeRun, run_benchmark_episode
from superex_deploy.evaluation.metrics import (coverage_at, coverage_auc, coverage_curve, first_half_auc,
                                               iou_at_coverage, scenario_metrics)
from superex_deploy.evaluation.summary import bootstrap_interval, mean_with_interval, scenario_key
from superex_deploy.evaluation.reports import markdown_table, read_json, save_figure, write_json, write_text
from superex_deploy.evaluation.scenarios import (HELDOUT_BUILDINGS, Scenario, altered_scenarios, eval_scenarios,
                                                 heldout_scenarios, train_scenarios)

__all__ = ["EpisodeRun", "run_benchmark_episode", "bootstrap_interval", "coverage_at", "coverage_auc",
           "coverage_curve", "first_half_auc", "iou_at_coverage", "mean_with_interval", "scenario_key",
           "scenario_metrics", "markdown_table", "read_json", "save_figure", "write_json", "write_text",
           "HELDOUT_BUILDINGS", "Scenario", "altered_scenarios", "eval_scenarios", "heldout_scenarios",
           "train_scenarios"]
