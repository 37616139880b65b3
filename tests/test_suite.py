"""The paper benchmark's metrics, intervals and pairing, on hand-built episode logs; its command end to end."""

import json

import numpy as np
import pytest

from superex_deploy.cli import main
from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction
from superex_deploy.pipeline import PIPELINES
from superex_deploy.evaluation.metrics import scenario_metrics
from superex_deploy.evaluation.summary import (bootstrap_interval, paired_summary, row_intervals, row_summary,
                                              summary_markdown, summary_table)


def test_scenario_metrics_on_a_hand_built_log(episode_log):
    # Linear growth to 0.5 over 10 steps, then the episode ends (it keeps its final coverage).
    coverage = np.linspace(0.05, 0.5, 10)
    iou = [(0, 0.1, 0.04), (3, 0.2, 0.08), (5, 0.3, 0.12), (7, 0.4, 0.25), (9, 0.5, 0.5)]
    m = scenario_metrics(episode_log(coverage, iou=iou), steps=20)
    assert m["auc_first_half"] == pytest.approx(np.mean(coverage))
    assert m["auc"] == pytest.approx((coverage.sum() + 10 * 0.5) / 20)
    assert m["los_auc"] == m["auc"]
    assert m["iou@0.05"] == 0.2 and m["iou@0.10"] == 0.3 and m["iou@0.20"] == 0.4 and m["iou@0.30"] == 0.5
    assert m["iou_bin_0.0_0.1"] == pytest.approx(0.15) and m["iou_bin_0.1_0.2"] == 0.3
    assert m["iou_bin_0.2_0.3"] == 0.4 and m["final_iou"] == 0.5
    assert "coverage@100" not in m  # beyond the horizon
    never = scenario_metrics(episode_log([0.01, 0.02], iou=[(0, 0.1, 0.01)]), steps=4)
    assert np.isnan(never["iou@0.05"]) and np.isnan(never["iou_bin_0.1_0.2"])
    carved = scenario_metrics(episode_log([0.1, 0.2], carved=[0.2, 0.3]), steps=2)
    assert carved["auc"] == pytest.approx(0.25) and carved["los_auc"] == pytest.approx(0.15)


def test_bootstrap_interval_brackets_the_mean_and_narrows_with_more_data():
    rng = np.random.default_rng(0)
    small, large = rng.normal(1.0, 1.0, 20), rng.normal(1.0, 1.0, 2000)
    for values in (small, large):
        low, high = bootstrap_interval(values)
        assert low < values.mean() < high
    assert np.diff(bootstrap_interval(large)) < np.diff(bootstrap_interval(small))
    assert bootstrap_interval([2.0, 2.0, 2.0]) == (2.0, 2.0)
    assert all(np.isnan(bootstrap_interval([np.nan])))


def test_paired_summary_pairs_by_scenario_and_counts_better_and_worse(episode_log):
    reference = [episode_log([0.1] * 4, start=k) for k in range(3)]
    candidate = [episode_log([0.2] * 4, start=0), episode_log([0.1] * 4, start=1), episode_log([0.05] * 4, start=2)]
    paired = paired_summary(reference, candidate[::-1], steps=4)["auc"]  # order does not matter
    assert paired["mean"] == pytest.approx(0.05 / 3) and paired["n"] == 3
    assert (paired["better"], paired["worse"], paired["tied"]) == (1, 1, 1)
    assert paired["ratio"] == pytest.approx(0.35 / 0.3 - 1)
    with pytest.raises(ValueError, match="different scenarios"):
        paired_summary(reference, candidate[:2], steps=4)


def test_the_one_summary_gives_each_rows_means_with_their_bootstrap_intervals(episode_log):
    """summary_table: one row per planner, the means of row_summary, the intervals of row_intervals (the bootstrap
    of bootstrap_interval over the episodes' values, seed 0 per metric), extra episode fields summarised too."""
    episodes = []
    for k, level in enumerate((0.1, 0.2, 0.4, 0.3)):
        for planner, scale in (("b", 1.0), ("a", 0.5)):
            episode = dict(episode_log([level * scale] * 4, start=k), planner=planner, collisions=k,
                           path_length_m=[0.0, 1.0, 2.0 + k])
            episodes.append(episode)
    extra = ("collisions", "path_length_m")
    table = summary_table(episodes, steps=4, extra=extra)
    assert [row["planner"] for row in table] == ["a", "b"] and table[1]["episodes"] == 4
    row_b = [e for e in episodes if e["planner"] == "b"]
    means, intervals = row_summary(row_b, 4, extra), row_intervals(row_b, 4, extra)
    assert table[1]["auc"] == {"mean": means["auc"], "low": intervals["auc"][0], "high": intervals["auc"][1]}
    assert table[1]["auc"]["mean"] == pytest.approx(0.25) and table[1]["path_length_m"]["mean"] == pytest.approx(3.5)
    assert intervals["auc"] == bootstrap_interval([0.1, 0.2, 0.4, 0.3])
    assert 0.1 <= intervals["auc"][0] < 0.25 < intervals["auc"][1] <= 0.4
    assert table[1]["collisions"]["mean"] == 1.5 and "collisions" not in row_summary(row_b, 4)
    # Without extra fields the summary is row_summary's: the paper suite's committed numbers.
    assert set(summary_table(row_b, 4)[0]) == {"planner", "episodes", *row_summary(row_b, 4)}
    text = summary_markdown(table, ["auc", "final_iou", "collisions"])
    assert text.splitlines()[0] == "| planner | episodes | auc | final_iou | collisions |"
    assert text.splitlines()[3].startswith("| b | 4 | 25.0 [") and summary_markdown([]) == "(no results)\n"


def test_the_evidence_predictor_reads_the_evidence_only_on_unknown_cells():
    observed = np.array([[-1, 0], [1, -1]], np.int8)
    evidence = np.array([[0.7, 0.9], [0.1, np.nan]], np.float32)
    mean = EvidenceAsPrediction().predict(observed, evidence).mean
    np.testing.assert_array_equal(mean, np.array([[0.7, 0.0], [1.0, 0.0]], np.float32))
    assert np.array_equal(EvidenceAsPrediction().predict(observed).mean, np.array([[0, 0], [1, 0]], np.float32))
    with pytest.raises(ValueError, match="evidence must be a float"):
        EvidenceAsPrediction().predict(observed, np.zeros((3, 3), np.float32))


@pytest.mark.slow
def test_paper_suite_runs_rows_resumes_and_refuses_other_settings(tmp_path, capsys):
    out = tmp_path / "paper"
    argv = ["benchmark", "--suite", "paper", "--rows", "nearest,superex_oracle", "--maps", "50052750",
            "--steps", "40", "--jobs", "1", "--out", str(out)]
    assert main(argv) == 0
    rows = json.loads((out / "rows" / "superex_oracle.json").read_text())
    assert rows["row"] == "superex_oracle" and len(rows["episodes"]) == 4
    assert all(e["planner"] == "superex" and e["predictor"] == "oracle" for e in rows["episodes"])
    assert (out / "results.md").is_file() and (out / "coverage.png").is_file()
    assert (out / "iou_vs_coverage.png").is_file()
    summary = json.loads((out / "results.json").read_text())["summary"]
    assert set(summary) == {"nearest", "superex_oracle"}
    capsys.readouterr()
    assert main(argv) == 0  # resumes: both rows are there already
    assert capsys.readouterr().out.count("done already") == 2
    assert main(argv[:8] + ["30"] + argv[9:]) == 2  # the same folder with other settings
    assert "other settings" in capsys.readouterr().err
    assert main(argv[:4] + ["nearest,frontier"] + argv[5:]) == 2
    assert "--rows: unknown row(s) frontier;" in capsys.readouterr().err
    assert set(PIPELINES) >= {"mapex_lama_los", "superex", "no_lama", "no_pix2pix", "superex_oracle"}
