"""The ``superex`` commands end to end on a bundled map: scan, explore (its logs, figures and GIF, its
reproducibility, the learned ensembles) and benchmark, and their bad arguments. Finer checks of the arguments are in
test_cli_arguments.py, signals in test_cli_signals.py."""

import json

import imageio.v2 as imageio
import numpy as np
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
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--start", "2", "--planner", "mapex",
                 "--steps", "30", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 30 and len(metrics["coverage"]) == 30
    assert set(metrics["timings_s"]) == {"scan", "map_update", "frontiers", "prediction", "scoring", "path"}
    assert metrics["iou"]["steps"][0] == 0 and metrics["path_length_m"][-1] > 0
    assert (out / "final.png").stat().st_size > 5_000
    assert (out / "episode.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")


@pytest.mark.slow
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

    assert planner_options(["distance=euclidean", "min_distance_m=2", "weight=0.5", "flag=True"]) == {
        "distance": "euclidean", "min_distance_m": 2, "weight": 0.5, "flag": True}
    with pytest.raises(ValueError, match="FIELD=VALUE"):
        planner_options(["distance"])


@pytest.mark.slow
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


@pytest.mark.slow
def test_explore_with_spad_reports_carved_coverage(tmp_path):
    out = tmp_path / "spad"
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--start", "2", "--steps", "25", "--spad",
                 "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["coverage_with_carving"][-1] > metrics["coverage"][-1]


@pytest.mark.parametrize("argv, message", [
    (["explore", "--map", "50052750", "--planner", "frontier", "--steps", "5"], "unknown planner"),
    (["explore", "--map", "50052750", "--start", "7", "--steps", "5"], "--start must lie in 0..3"),
    (["scan", "--map", "no_such_map"], "no bundled map"),
    (["explore", "--map", "50052750", "--pose", "0", "1", "--steps", "5"], "inside a wall"),  # a wall cell
    (["explore", "--pipeline", "nearest", "--map", "50052750", "--predictor", "lama_bp", "--steps", "5"], "add --spad"),
    (["benchmark", "--maps", "50052750", "--predictor", "lama_bp", "--steps", "5"], "add --spad"),
    (["benchmark", "--maps", "50052750", "--planners", "mapex", "--planner-option", "distance=manhattan",
      "--steps", "5"], "distance must be"),
    (["explore", "--map", "50052750", "--planner", "nearest", "--planner-option", "weight=2", "--steps", "5"],
     "takes no configuration"),
])
def test_bad_arguments_fail_with_a_clear_message(tmp_path, capsys, argv, message):
    assert main(argv + ["--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err


def test_explore_with_the_oracle_logs_everything_the_benchmark_needs(tmp_path):
    out = tmp_path / "run"
    argv = ["explore", "--pipeline", "nearest", "--map", "50052750", "--start", "3", "--planner", "nearest",
            "--predictor", "oracle", "--seed", "4", "--steps", "30", "--gif-every", "7", "--out", str(out)]
    assert main(argv) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert (metrics["map"], metrics["planner"], metrics["seed"], metrics["steps"]) == ("50052750", "nearest", 4, 30)
    assert metrics["predictor"] == "oracle"
    coverage = np.array(metrics["coverage"])
    assert len(coverage) == 30 and np.all(np.diff(coverage) >= 0) and 0 < coverage[-1] < 1
    assert metrics["coverage_with_carving"] == metrics["coverage"]  # no NLOS hook: nothing carved
    path = np.array(metrics["path_length_m"])
    assert path[0] == 0 and np.all(np.diff(path) >= 0) and path[-1] > 3.0
    # The oracle's prediction is the ground truth itself: its map IoU is 1 whatever the coverage.
    assert metrics["iou"]["steps"] == [0, 25, 29] and metrics["iou"]["iou"] == [1.0, 1.0, 1.0]
    assert all(len(v) == 30 for v in metrics["timings_s"].values())
    explorer = metrics["config"]["explorer"]
    assert explorer["motion"]["robot_radius_m"] == 0.15 and explorer["frontier_min_m"] == 1.0
    frames = imageio.mimread(out / "episode.gif")
    assert len(frames) == 5  # steps 0, 7, 14, 21, 28
    assert max(frames[0].shape[:2]) <= 400
    assert (out / "final.png").stat().st_size > 5_000


@pytest.mark.slow
def test_explore_runs_are_reproducible_and_the_seed_matters(tmp_path):
    # UPEN on the LaMa-LOS ensemble grows its random tree from the episode's generator (on the observed map it
    # would fall back to the nearest frontier and never draw a number): the same seed must give the same episode,
    # another seed another one, or the test could not fail.
    logs = []
    for run, seed in (("a", "1"), ("b", "1"), ("c", "2")):
        assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--start", "1", "--planner", "upen",
                     "--predictor", "lama_los", "--steps", "40", "--seed", seed, "--gif-every", "100",
                     "--out", str(tmp_path / run)]) == 0
        logs.append(json.loads((tmp_path / run / "metrics.json").read_text()))
    assert logs[0]["poses"] == logs[1]["poses"] and logs[0]["goals"] == logs[1]["goals"]
    assert logs[0]["goals"] != logs[2]["goals"]


@pytest.mark.slow
def test_explore_with_the_learned_ensembles(tmp_path, capsys):
    out = tmp_path / "lama"
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--start", "1", "--planner", "mapex",
                 "--predictor", "lama_bp", "--spad", "--steps", "12", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["predictor"] == "lama_bp" and metrics["steps"] == 12
    # The learned prediction is neither the observation nor the truth: its IoU lies strictly between.
    assert all(0.0 < iou < 1.0 for iou in metrics["iou"]["iou"])
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--predictor", "lama_bp", "--steps", "5",
                 "--out", str(tmp_path / "x")]) == 2
    assert "add --spad" in capsys.readouterr().err
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--predictor", "lama_los", "--steps", "5",
                 "--models", str(tmp_path), "--out", str(tmp_path / "y")]) == 2
    assert "no model manifest" in capsys.readouterr().err
