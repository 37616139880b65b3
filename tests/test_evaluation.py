"""The evaluation library (superex_deploy.evaluation): AUC on hand-made curves, the bootstrap on known data and
against the committed benchmarks' numbers, the report writers, the scenario sets and the episode runner."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from superex_deploy import evaluation
from superex_deploy.evaluation import (HELDOUT_BUILDINGS, Scenario, bootstrap_interval, coverage_auc, coverage_curve,
                                       eval_scenarios, first_half_auc, heldout_scenarios, iou_at_coverage,
                                       markdown_table, mean_with_interval, write_json, write_text)
from superex_deploy.evaluation.reports import read_json, save_figure
from superex_deploy.files import TEMPORARY_SUFFIX
from superex_deploy.maps import list_maps, map_building, start_poses

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"


def _script(name: str):
    """A script under scripts/ as a module (its main() is guarded: nothing runs)."""
    spec = importlib.util.spec_from_file_location(f"script_{name}", ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --- metrics ---


def test_first_half_auc_of_hand_made_curves():
    assert first_half_auc([0.1, 0.2, 0.3, 0.4], 4) == pytest.approx(0.15)
    assert first_half_auc([0.1, 0.2, 0.3, 0.4, 0.5], 5) == pytest.approx(0.15)  # steps // 2 = 2
    # An episode that ended early keeps its last coverage for the steps it did not run.
    assert first_half_auc([0.2, 0.6], 8) == pytest.approx((0.2 + 0.6 + 0.6 + 0.6) / 4)
    assert first_half_auc([0.3], 1) == pytest.approx(0.3)  # at least step 1
    assert first_half_auc([], 10) == 0.0
    assert first_half_auc(np.array([0.5, 1.0]), 4) == pytest.approx(0.75)


def test_coverage_auc_and_curve():
    series = [0.0, 0.25, 0.5, 0.75, 1.0]
    assert coverage_auc(series, 1, 5) == pytest.approx(0.5)
    assert coverage_auc(series, 2, 3) == pytest.approx(0.375)
    assert coverage_curve([0.1, 0.4], 4) == [0.1, 0.4, 0.4, 0.4]


def test_the_paper_suite_reads_the_same_auc():
    episode = {"coverage": [0.1, 0.2, 0.3, 0.4], "coverage_with_carving": [0.2, 0.4, 0.6, 0.8],
               "iou": {"steps": [], "iou": [], "coverage": []}, "goals": {"steps": []}}
    metrics = evaluation.scenario_metrics(episode, 4)
    assert metrics["auc_first_half"] == first_half_auc([0.2, 0.4, 0.6, 0.8], 4) == pytest.approx(0.3)
    assert metrics["los_auc_first_half"] == pytest.approx(0.15)
    assert metrics["auc"] == pytest.approx(0.5)


def test_iou_at_coverage_interpolates_between_evaluations():
    episode = {"iou": {"coverage": [0.0, 0.1, 0.3], "iou": [0.2, 0.4, 0.8]}}
    assert iou_at_coverage(episode, 0.1) == pytest.approx(0.4)
    assert iou_at_coverage(episode, 0.2) == pytest.approx(0.6)
    assert math.isnan(iou_at_coverage(episode, 0.5))
    assert math.isnan(iou_at_coverage({"iou": {"coverage": [], "iou": []}}, 0.1))


# --- bootstrap ---


def test_bootstrap_of_a_constant_is_the_constant_and_nan_of_nothing():
    assert bootstrap_interval([0.3] * 7) == (pytest.approx(0.3), pytest.approx(0.3))
    assert all(math.isnan(v) for v in bootstrap_interval([np.nan, np.inf]))
    assert all(math.isnan(v) for v in mean_with_interval([], np.random.default_rng(0)))


def test_bootstrap_on_known_data():
    values = np.random.default_rng(1).normal(2.0, 1.0, 400)
    low, high = bootstrap_interval(values)
    # The interval of the mean of 400 draws of N(2, 1): about mean +- 1.96 / 20.
    assert low < values.mean() < high
    assert high - low == pytest.approx(2 * 1.96 / 20, rel=0.15)
    assert bootstrap_interval(values) == (low, high)  # seeded: the same numbers every time
    assert bootstrap_interval(values, seed=1) != (low, high)
    assert bootstrap_interval(list(values) + [np.nan]) == (low, high)  # non-finite values left out
    median_low, median_high = bootstrap_interval(values, statistic=np.median)
    assert median_low < np.median(values) < median_high and (median_low, median_high) != (low, high)
    wider = bootstrap_interval(values, confidence=0.99)
    assert wider[0] < low and wider[1] > high


def test_a_shared_stream_matches_the_robustness_benchmarks_draws():
    """bench_robustness drew ``rng.choice(values, (n, len))`` and took ``np.percentile(.., 2.5 / 97.5)``: the one
    implementation gives the same numbers bit for bit, from a stream shared by successive intervals."""
    values = np.random.default_rng(2).normal(size=37)
    values[5] = np.nan
    ours, theirs = np.random.default_rng(7), np.random.default_rng(7)
    for _ in range(3):  # the stream advances identically
        finite = values[np.isfinite(values)]
        means = theirs.choice(finite, size=(2000, finite.size), replace=True).mean(axis=1)
        expected = (float(finite.mean()), float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5)))
        assert mean_with_interval(values, ours) == expected


def test_the_committed_ceiling_study_intervals_regenerate():
    data = json.loads((BENCHMARKS / "ceiling_study" / "ceiling_study_500.json").read_text())
    base = {(e["map"], tuple(e["start"])): e for e in data["episodes"]
            if (e["idea"], e["predictor"]) == ("mapex", "observed")}
    for row in data["rows"]:
        mine = [e for e in data["episodes"] if (e["idea"], e["predictor"]) == (row["idea"], row["predictor"])]
        diff = np.array([e["auc_first_half"] - base[(e["map"], tuple(e["start"]))]["auc_first_half"] for e in mine])
        assert bootstrap_interval(diff) == (row["low"], row["high"]), row["idea"]


def test_the_committed_altered_ceiling_rows_regenerate():
    """ceiling_altered.py's mean and median intervals (quantiles spelled 0.025 / 0.975) from its episodes."""
    data = json.loads((BENCHMARKS / "altered_ceiling" / "ceiling.json").read_text())
    script = _script("ceiling_altered")
    runs = list(dict.fromkeys(row["run"] for row in data["rows"]))
    rows = json.loads(json.dumps(script.summarise(data["episodes"], runs)))
    gaps = json.loads(json.dumps(script.gap_changes(data["episodes"], runs)))
    assert rows == data["rows"]
    assert gaps == data["gap_changes"]


def test_the_committed_reports_regenerate_from_their_json():
    """The Markdown written by ceiling_altered.py (through markdown_table), from the committed JSON: the same
    text."""
    folder = BENCHMARKS / "altered_ceiling"
    data = json.loads((folder / "ceiling.json").read_text())
    text = _script("ceiling_altered").markdown(data["rows"], data["scenarios"], data["steps"], data["gap_changes"])
    assert text == (folder / "ceiling.md").read_text()


@pytest.mark.parametrize("split", ["eval", "train"])
def test_the_committed_carving_benchmark_regenerates(split):
    """bench_carving.py's rows (paired intervals) and tables from its committed per-scenario results, and its
    scenario list from the evaluation's scenario sets (eval: start order; train: seeded train floors)."""
    data = json.loads((BENCHMARKS / "carving" / f"{split}.json").read_text())
    script = _script("bench_carving")
    rows, text = script.summarise(data["scenarios"], [row["variant"] for row in data["rows"]])
    assert rows == data["rows"]
    assert text in (BENCHMARKS / "carving" / f"{split}.md").read_text()
    places = script.scenarios(data["split"], len(data["scenarios"]))
    assert [[name, list(start)] for name, start in places] == [[s["map"], s["start"]] for s in data["scenarios"]]


def test_the_committed_suite_comparison_regenerates():
    """compare_suites.py pairs the committed paper and altered rows (scenario_metrics' first-half AUC, the bootstrap)
    into the committed side_by_side.json and .md."""
    folder = BENCHMARKS / "eval_altered"
    data = json.loads((folder / "side_by_side.json").read_text())
    script = _script("compare_suites")
    # The altered suite ran with the previous defaults: its standard rows are the paper rows of those defaults
    # (the rows the 0.2 defaults changed are kept in history/eval_paper_previous_defaults/).
    standard = {**script._rows(BENCHMARKS / "eval_paper"),
                **script._rows(BENCHMARKS / "history" / "eval_paper_previous_defaults")}
    entries = script.compare(standard, script._rows(folder), data["steps"])
    assert json.dumps(entries) == json.dumps(data["entries"])
    assert script.markdown(data["entries"], data["steps"]) == (folder / "side_by_side.md").read_text()


def test_the_committed_seams_report_and_scenarios_regenerate():
    """bench_seams.py's Markdown from its committed JSON, and its episodes' scenarios from the evaluation's sets
    (train: the held-out scenarios; eval: start 0 of its maps)."""
    folder = BENCHMARKS / "seams"
    script = _script("bench_seams")
    assert script.markdown(folder) == (folder / "seams.md").read_text()
    for split in ("train", "eval"):
        episodes = json.loads((folder / f"seams_{split}.json").read_text())["episodes"]
        assert [tuple(s) for s in script.scenarios(split, len(episodes))] == [
            (e["map"], e["start_index"], tuple(e["start"])) for e in episodes]


CARVE_CEILING_VARIANTS = ["", "path", "weight3", "path_weight3", "confirm", "estimate"]


@pytest.mark.parametrize("variant", CARVE_CEILING_VARIANTS)
def test_the_committed_carve_gain_ceiling_regenerates(variant):
    """ceiling_carve_gain.py's report from its committed episodes (the held-out scenarios it names, each arm's
    first-half AUC, the paired bootstrap) is the committed ceiling.json and ceiling.md, in each variant's folder."""
    folder = BENCHMARKS / "carve_gain_ceiling" / variant
    data = json.loads((folder / "ceiling.json").read_text())
    script = _script("ceiling_carve_gain")
    starts = data.get("starts", 1)
    scenarios = heldout_scenarios(data["scenarios_planned"] // starts, starts)
    result, text = script.summarise(folder, scenarios, data["steps"], data["weight"], data["top_k"],
                                    data["viewpoints"], starts, "steps_run" in data,
                                    data.get("second_arm", "ceiling"))
    assert json.loads(json.dumps(result)) == data
    assert text == (folder / "ceiling.md").read_text()
    assert [(p["map"], p["start_index"], tuple(p["start_rc"])) for p in data["per_scenario"]] == [
        (s.map_name, s.start_index, s.start_rc) for s in scenarios[:data["scenarios_finished"]]]


def test_the_true_carve_gain_counts_the_unknown_cells_the_carving_would_carve():
    """The ceiling's carve gain of a cell: the cells the onboard carving carves from a scan simulated there on the
    true grid, counted where the map is unknown (carved cells, FREE in the map, count no more); one scan per cell."""
    from superex_deploy.maps import load_map, random_start
    from superex_deploy.onboard.nlos import NlosConfig, carve, estimate_los
    from superex_deploy.onboard.types import FREE, UNKNOWN
    from superex_deploy.sim.spad import simulate_scan
    from superex_deploy.spad_types import SpadConfig

    script = _script("ceiling_carve_gain")
    grid = load_map(heldout_scenarios(1)[0].map_name)
    start = random_start(grid, np.random.default_rng(3), 0.5)
    scan = simulate_scan(grid, start, SpadConfig())
    carved = carve(scan, estimate_los(scan, NlosConfig()), NlosConfig())
    assert carved.sum() > 100
    gain = script.TrueCarveGain(grid, SpadConfig(), NlosConfig())
    observed = np.full(grid.shape, UNKNOWN, np.int8)
    assert gain.gains(observed, [start]).tolist() == [float(carved.sum())]
    rows, cols = np.nonzero(carved)
    observed[rows[::2], cols[::2]] = FREE  # half of them carved (or seen) already
    wall = tuple(int(v) for v in np.argwhere(grid.occupied)[0])
    assert gain.gains(observed, [start, wall]).tolist() == [float(len(rows) - len(rows[::2])), 0.0]
    assert gain.scans == 2  # the start's carved set computed once (it reads neither the map nor the step)
    with pytest.raises(ValueError, match="true grid"):
        gain.gains(observed[1:], [start])


def test_the_ceiling_planner_adds_the_weighted_carve_gain_to_the_k_best_frontiers(monkeypatch):
    """The ceiling planner's gain is today's plus ``weight`` x the carve gain, for the ``top_k`` frontiers of
    largest line-of-sight gain only."""
    from types import SimpleNamespace

    from superex_deploy.onboard.planning.planners import SuperexPlanner
    from superex_deploy.onboard.types import frontiers_at

    script = _script("ceiling_carve_gain")
    monkeypatch.setattr(SuperexPlanner, "gains", lambda self, ctx, prediction, frontiers: np.array([5.0, 9.0, 1.0]))
    carve_gain = SimpleNamespace(gains=lambda observed, cells: np.array([10.0 * r for r, _ in cells]))
    frontiers = frontiers_at([[1, 0], [2, 0], [3, 0]])
    ctx = SimpleNamespace(observed=np.zeros((4, 4), np.int8))
    every = script.ceiling_planner(carve_gain, weight=0.5)
    assert every.gains(ctx, None, frontiers).tolist() == [10.0, 19.0, 16.0]
    best_two = script.ceiling_planner(carve_gain, weight=2.0, top_k=2)
    assert best_two.gains(ctx, None, frontiers).tolist() == [25.0, 49.0, 1.0]
    assert best_two.stats == {"calls": 1, "frontiers": 3, "scored": 2, "los_gain": 14.0, "carve_gain": 30.0}


# --- reports ---


def test_markdown_table():
    lines = markdown_table(["row", "AUC"], [["a", "1.0"], ["b", 2]], ["-", "---:"])
    assert lines == ["| row | AUC |", "|---|---:|", "| a | 1.0 |", "| b | 2 |"]
    assert markdown_table(["x"], [], "-") == ["| x |", "|---|"]
    with pytest.raises(ValueError):
        markdown_table(["a", "b"], [["only one"]])
    with pytest.raises(ValueError):
        markdown_table(["a", "b"], [], ["-"])


def test_json_and_text_round_trip_atomically(tmp_path):
    data = {"rows": [{"auc": 0.25, "low": float("nan")}], "steps": 500}
    path = write_json(tmp_path / "deep" / "out.json", data)
    back = read_json(path)
    assert back["steps"] == 500 and back["rows"][0]["auc"] == 0.25 and math.isnan(back["rows"][0]["low"])
    assert path.read_text() == json.dumps(data, indent=1)
    assert write_json(tmp_path / "n.json", [1], indent=None, newline=True).read_text() == "[1]\n"
    text = write_text(tmp_path / "t" / "table.md", "| a |\n")
    assert text.read_text() == "| a |\n"
    assert not list(tmp_path.rglob(f"*{TEMPORARY_SUFFIX}"))


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = write_json(tmp_path / "out.json", {"old": True})
    with pytest.raises(TypeError):
        write_json(path, {"new": object()})
    assert read_json(path) == {"old": True} and not list(tmp_path.glob(f"*{TEMPORARY_SUFFIX}"))


def test_save_figure_writes_a_png(tmp_path):
    fig, ax = evaluation.reports.pyplot().subplots()
    ax.plot([0, 1], [0, 1])
    path = save_figure(fig, tmp_path / "plots" / "curve.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.rglob(f"*{TEMPORARY_SUFFIX}"))


# --- scenario sets ---


def test_the_forty_eval_scenarios():
    by_map = eval_scenarios()
    assert len(by_map) == 40 and len({s.map_name for s in by_map}) == 10
    assert by_map == [Scenario(m, k, tuple(int(v) for v in pose)) for m in list_maps("eval")
                      for k, pose in enumerate(start_poses(m))]
    by_start = eval_scenarios("start")
    assert sorted(by_start) == sorted(by_map)
    assert [s.start_index for s in by_start[:10]] == [0] * 10 and len({s.map_name for s in by_start[:10]}) == 10
    first = eval_scenarios(starts=1, maps=["50052750", "50010539"])
    assert [(s.map_name, s.start_index) for s in first] == [("50052750", 0), ("50010539", 0)]
    with pytest.raises(ValueError):
        eval_scenarios("sideways")


def test_the_held_out_train_scenarios():
    held = heldout_scenarios()
    assert len(held) == 12 and len({s.map_name for s in held}) == 12
    assert all(map_building(s.map_name) in HELDOUT_BUILDINGS and s.start_index == 0 for s in held)
    assert set(list_maps("eval")).isdisjoint(s.map_name for s in held)
    assert held == heldout_scenarios()  # seeded by the map's name
    assert [(s.map_name, s.start_rc) for s in held] == evaluation.train_scenarios(12, 1, 40000, heldout=True)
    committed = json.loads((BENCHMARKS / "ceiling_study" / "ceiling_study_lama_heldout.json").read_text())["scenarios"]
    assert [[s.map_name, list(s.start_rc)] for s in heldout_scenarios(len(committed))][:len(committed)] == committed
    two = heldout_scenarios(12, starts=2)  # a floor's first start is the one-start set's, its second another cell
    assert two[::2] == held and [s.start_index for s in two[:4]] == [0, 1, 0, 1]
    assert all(a.map_name == b.map_name and a.start_rc != b.start_rc for a, b in zip(two[::2], two[1::2]))
    with pytest.raises(ValueError, match="starts"):
        heldout_scenarios(12, starts=0)


def test_the_held_out_buildings_are_the_training_splits():
    generate = pytest.importorskip("superex_train.generate")
    assert HELDOUT_BUILDINGS == generate.heldout_buildings()


def test_the_altered_scenarios_carry_their_floors_seed():
    from superex_deploy.sim.altered_floors import alteration_seed

    altered = evaluation.altered_scenarios()
    assert [s for s, _ in altered] == eval_scenarios()
    assert all(seed == alteration_seed(s.map_name, s.start_rc) for s, seed in altered)
    assert len({seed for _, seed in altered}) == 40


# --- the episode runner ---


def test_the_runner_is_run_episode_with_the_pieces_made_by_name():
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.sim.exploration import ExplorationConfig

    name, _, start = eval_scenarios()[0]
    cfg = ExplorationConfig(iou_every=0)
    run = evaluation.run_benchmark_episode(name, start, "nearest", "observed", steps=6, cfg=cfg)
    direct = run_episode(load_map(name), start, make_planner("nearest"), ObservedAsPrediction(), steps=6, cfg=cfg)
    assert run.grid.name == name and run.seconds > 0
    np.testing.assert_array_equal(run.result.coverage, direct.coverage)
    np.testing.assert_array_equal(run.result.poses, direct.poses)
    with pytest.raises(ValueError):
        evaluation.run_benchmark_episode(name, start, "nearest", ObservedAsPrediction(), steps=2, spad=True)


@pytest.mark.parametrize("folder", ["eval_paper", "eval_paper/ablations"])
def test_the_committed_paper_rows_are_those_of_this_version(folder):
    """Every committed row of the paper suite (and its ablations) is what a rerun of its command with this version's
    defaults would find done: its setting is the row's setting today (a row made with other defaults would be
    refused or left out of the regenerated table)."""
    from superex_deploy.commands.paper_benchmark import _row_setting

    paths = sorted((BENCHMARKS / folder / "rows").glob("*.json"))
    assert paths
    for path in paths:
        done = json.loads(path.read_text())
        base = {key: done["setting"][key] for key in ("maps", "steps", "seed", "iou")}
        assert done["setting"] == _row_setting(base, done["row"]), path.name
