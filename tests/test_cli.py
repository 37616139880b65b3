import json

import pytest

from superex_deploy.cli import main
from superex_deploy.pipeline import DEFAULT_PROFILE


def test_scan_writes_figure_and_summary(tmp_path, capsys):
    assert main(["scan", "--map", "50052749", "--start", "1", "--secondary", "16", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "scan.json").read_text())
    assert summary["carved_walls"] == 0 and summary["carved_cells"] > 0
    assert (tmp_path / "scan.png").stat().st_size > 10_000


def test_explore_writes_metrics_plot_and_gif(tmp_path):
    out = tmp_path / "run"
    assert main(["explore", "--map", "50052750", "--start", "2", "--planner", "mapex", "--steps", "30",
                 "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 30 and len(metrics["coverage"]) == 30
    assert set(metrics["timings_s"]) == {"scan", "map_update", "frontiers", "prediction", "scoring", "path"}
    assert metrics["iou"]["steps"][0] == 0 and metrics["path_length_m"][-1] > 0
    assert (out / "final.png").stat().st_size > 5_000
    assert (out / "episode.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")


def test_benchmark_runs_scenarios_and_writes_the_table(tmp_path):
    out = tmp_path / "bench"
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest,mapex", "--steps", "20", "--jobs", "2",
                 "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert len(results["episodes"]) == 8  # 4 start poses x 2 planners
    assert {e["profile"] for e in results["episodes"]} == {DEFAULT_PROFILE}
    assert "| mapex | 4 |" in (out / "results.md").read_text()
    assert (out / "coverage.png").exists() and (out / "iou_vs_coverage.png").exists()
    # A planner option reaches every episode: MapEx's straight-line divisor changes its goals.
    straight = tmp_path / "straight"
    assert main(["benchmark", "--maps", "50052750", "--planners", "mapex", "--planner-option", "distance=euclidean",
                 "--steps", "20", "--jobs", "2", "--out", str(straight)]) == 0
    other = json.loads((straight / "results.json").read_text())
    assert other["planner_options"] == {"distance": "euclidean"}
    assert f", distance=euclidean, profile {DEFAULT_PROFILE};" in (straight / "results.md").read_text()
    goals = lambda run: [e["goals"] for e in run["episodes"] if e["planner"] == "mapex"]  # noqa: E731
    assert goals(other) != goals(results)


def test_planner_options_are_parsed_and_checked():
    from superex_deploy.commands.explore import planner_options

    assert planner_options(["distance=euclidean", "min_distance_cells=2", "weight=0.5", "flag=True"]) == {
        "distance": "euclidean", "min_distance_cells": 2, "weight": 0.5, "flag": True}
    with pytest.raises(ValueError, match="FIELD=VALUE"):
        planner_options(["distance"])


def test_benchmark_with_spad_and_the_evidence_ensemble(tmp_path):
    out = tmp_path / "bench"
    assert main(["benchmark", "--maps", "50052750", "--planners", "mapex", "--predictor", "lama_bp", "--spad",
                 "--steps", "15", "--jobs", "2", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert len(results["episodes"]) == 4
    assert all(e["predictor"] == "lama_bp" for e in results["episodes"])
    # SPAD carving proves cells free beyond line of sight in at least one scenario.
    assert any(e["final_coverage_with_carving"] > e["final_coverage"] for e in results["episodes"])
    # MapEx reads the ensemble's variance: the one-member default does not apply to it.
    assert (out / "results.md").read_text().startswith("Predictor: lama_bp, SPAD sensing, profile full;")


def test_explore_with_spad_reports_carved_coverage(tmp_path):
    out = tmp_path / "spad"
    assert main(["explore", "--map", "50052750", "--start", "2", "--steps", "25", "--spad", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["coverage_with_carving"][-1] > metrics["coverage"][-1]


@pytest.mark.parametrize("argv, message", [
    (["explore", "--map", "50052750", "--planner", "frontier", "--steps", "5"], "unknown planner"),
    (["explore", "--map", "50052750", "--start", "7", "--steps", "5"], "--start must lie in 0..3"),
    (["scan", "--map", "no_such_map"], "no bundled map"),
    (["explore", "--map", "50052750", "--pose", "0", "1", "--steps", "5"], "inside a wall"),  # a wall cell
    (["explore", "--map", "50052750", "--predictor", "lama_bp", "--steps", "5"], "add --spad"),
    (["benchmark", "--maps", "50052750", "--predictor", "lama_bp", "--steps", "5"], "add --spad"),
    (["benchmark", "--maps", "50052750", "--planners", "mapex", "--planner-option", "distance=manhattan",
      "--steps", "5"], "distance must be"),
    (["explore", "--map", "50052750", "--planner", "nearest", "--planner-option", "weight=2", "--steps", "5"],
     "takes no configuration"),
])
def test_bad_arguments_fail_with_a_clear_message(tmp_path, capsys, argv, message):
    assert main(argv + ["--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
