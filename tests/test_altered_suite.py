"""``superex benchmark --suite altered``: the seed per scenario, the floors' cache, the dead-end columns on
hand-built logs, and the standard suite unchanged when the alteration is off."""

import json
import zlib

import numpy as np
import pytest

from superex_deploy.evaluation.tasks import ScenarioTask, run_scenario
from superex_deploy.cli import main
from superex_deploy.commands.paper_benchmark import _table
from superex_deploy.maps import start_poses
from superex_deploy.sim.altered_floors import alteration_seed, floor_path, load_floor, make_floor
from superex_deploy.sim.dead_ends import DeadEnd, dead_end_entries
from superex_deploy.evaluation.metrics import scenario_metrics
from superex_deploy.evaluation.summary import common_scenarios, paired_summary, row_summary

MAP = "50052750"


def test_the_seed_of_a_scenario_is_the_crc_of_its_map_and_start():
    assert alteration_seed(MAP, (13, 370)) == zlib.crc32(b"50052750:13:370")
    assert alteration_seed(MAP, np.array([13, 370])) == alteration_seed(MAP, (13, 370))
    seeds = {alteration_seed(m, p) for m in (MAP, "50052749") for p in start_poses(m)}
    assert len(seeds) == 8, "every eval scenario gets its own seed"
    with pytest.raises(ValueError, match="two integers"):
        alteration_seed(MAP, (1.5, 2))
    with pytest.raises(ValueError, match="non-empty"):
        alteration_seed("", (1, 2))


def test_a_task_with_an_alteration_seed_needs_a_floors_folder():
    with pytest.raises(ValueError, match="floors_dir"):
        ScenarioTask(map_name=MAP, start_index=0, start_rc=(15, 15), planner="nearest", predictor="observed",
                     spad=False, steps=5, seed=0, alteration_seed=1)


def _dead_end() -> DeadEnd:
    """A pocket along row 5, columns 10..19, 10 cells of 0.1 m: depth 0 at its mouth (column 10), 0.9 m at the
    obstruction (column 19)."""
    pocket = np.zeros((10, 30), bool)
    pocket[5, 10:20] = True
    depth = np.full(pocket.shape, np.nan, np.float32)
    depth[5, 10:20] = 2.0 * np.arange(10) / 9.0  # 0 .. 2 m
    return DeadEnd(pocket=pocket, depth_m=depth, mouth=np.array([[5, 10]]), face=np.array([[5, 20]]),
                   length_m=2.0, hidden_m=1.0, area_m2=0.1)


def test_dead_end_entries_on_a_hand_built_path():
    # In along the pocket to its end (column 19), back out, then a shallow visit that does not count.
    cols = list(range(5, 20)) + list(range(18, 5, -1)) + [10, 11, 10, 5]
    poses = np.array([[5, c] for c in cols])
    driven = np.r_[0.0, np.cumsum(0.1 * np.abs(np.diff(cols)))]
    entries = dead_end_entries([_dead_end()], poses, driven)
    assert entries.entries == 1 and entries.reached_end == 1
    assert entries.metres_in == pytest.approx(0.9)  # column 10 (entry) to column 19 (deepest), 0.1 m a cell
    # Inside the pocket: columns 10..19 and back to 10 (1.8 m), then 10 -> 11 -> 10 (0.2 m).
    assert entries.metres_inside == pytest.approx(2.0)
    assert entries.deepest_m == pytest.approx(2.0)


@pytest.fixture
def flat_log(episode_log):
    """``flat_log(start, auc, dead_ends=None)``: a four-step episode log at the constant coverage ``auc``."""
    return lambda start, auc, dead_ends=None: episode_log([auc] * 4, iou=((0, 0.1, 0.01),), start=start,
                                                          dead_ends=dead_ends)


def test_dead_end_columns_are_computed_and_paired(flat_log):
    reference = [flat_log(0, 0.2, (2, 10.0, 12.0, 1)), flat_log(1, 0.3, (0, 0.0, 0.0, 0))]
    candidate = [flat_log(0, 0.25, (1, 4.0, 5.0, 0)), flat_log(1, 0.3, (1, 2.0, 3.0, 0))]
    metrics = scenario_metrics(candidate[0], steps=4)
    assert metrics["dead_end_entries"] == 1 and metrics["dead_end_metres_in"] == 4.0
    assert metrics["dead_end_metres_inside"] == 5.0 and metrics["dead_end_reached"] == 0
    assert "dead_end_entries" not in scenario_metrics(flat_log(0, 0.2), steps=4), "standard episodes: no columns"
    summary = row_summary(reference, steps=4)
    assert summary["dead_end_metres_in"] == 5.0 and summary["dead_end_entries"] == 1.0
    paired = paired_summary(reference, candidate, steps=4)
    assert paired["dead_end_metres_in"]["mean"] == pytest.approx(((4 - 10) + (2 - 0)) / 2)
    assert paired["dead_end_metres_inside"]["worse"] == 1 and paired["dead_end_metres_inside"]["better"] == 1
    rows = {"mapex_lama_los": reference, "mapex_observed": reference, "superex_oracle": candidate}
    text, numbers = _table(rows, 4, ("mapex_lama_los", "mapex_observed"))
    assert "dead end metres in / scenario" in text and "| dead_end_metres_in |" in text
    assert set(numbers["paired"]) == {"mapex_lama_los", "mapex_observed"}
    assert numbers["paired"]["mapex_observed"]["superex_oracle"]["dead_end_metres_in"]["mean"] == pytest.approx(-2.0)
    standard, _ = _table({"mapex_lama_los": [flat_log(0, 0.2)], "nearest": [flat_log(0, 0.1)]}, 4)
    assert "dead end" not in standard


def test_a_row_on_fewer_scenarios_is_paired_on_the_ones_it_shares(flat_log):
    reference = [flat_log(k, 0.2) for k in range(4)]
    candidate = [flat_log(k, 0.3) for k in (1, 3)]
    ref, cand = common_scenarios(reference, candidate)
    assert [e["start_index"] for e in ref] == [1, 3] and cand == candidate
    text, numbers = _table({"mapex_lama_los": reference, "superex": candidate}, 4)
    assert numbers["scenarios"] == {"mapex_lama_los": 4, "superex": 2}
    assert numbers["paired_vs_reference"]["superex"]["auc"]["n"] == 2
    assert "| scenarios |" in text


@pytest.mark.slow
def test_the_floors_are_cached_and_the_same_seed_gives_the_same_floor(tmp_path):
    start = start_poses(MAP)[1]
    summary = make_floor(MAP, start, tmp_path)
    assert summary["seed"] == alteration_seed(MAP, start) and summary["start_rc"] == list(start)
    path = floor_path(tmp_path, MAP, start)
    stamp = path.stat().st_mtime_ns
    assert make_floor(MAP, start, tmp_path) == summary and path.stat().st_mtime_ns == stamp, "read from the cache"
    grid, dead_ends, meta = load_floor(MAP, start, tmp_path)
    again, _, _ = load_floor(MAP, start, tmp_path / "again")
    np.testing.assert_array_equal(grid.occupied, again.occupied)
    np.testing.assert_array_equal(grid.valid, again.valid)
    assert len(dead_ends) == len(meta["alterations"]) and grid.name == MAP
    other = make_floor(MAP, start, tmp_path, seed=summary["seed"] + 1)  # another seed: made again, not read
    assert other["seed"] == summary["seed"] + 1


@pytest.mark.slow
def test_alteration_off_is_the_standard_suite(tmp_path):
    """The standard suite's episodes stay bit-identical: a short run reproduces the committed paper rows' first
    steps, and carries no alteration."""
    committed = json.loads(open("benchmarks/eval_paper/rows/superex_observed.json").read())["episodes"]
    start = start_poses(MAP)[0]
    task = ScenarioTask(map_name=MAP, start_index=0, start_rc=start, planner="superex", predictor="observed",
                        spad=False, steps=30, seed=0, iou_every=10, iou_dense_until=0.35, profile="full")
    summary = run_scenario(task)
    reference = next(e for e in committed if e["map"] == MAP and e["start_index"] == 0)
    assert summary["coverage"] == reference["coverage"][:30]
    assert summary["path_length_m"] == reference["path_length_m"][:30]
    assert "dead_ends" not in summary and "alteration" not in summary


@pytest.mark.slow
def test_altered_suite_end_to_end(tmp_path, capsys):
    out = tmp_path / "altered"
    argv = ["benchmark", "--suite", "altered", "--rows", "superex_oracle", "--maps", MAP, "--steps", "20",
            "--jobs", "1", "--out", str(out)]
    assert main(argv) == 0
    floors = json.loads((out / "floors.json").read_text())
    assert [f["seed"] for f in floors] == [alteration_seed(MAP, p) for p in start_poses(MAP)]
    episodes = json.loads((out / "rows" / "superex_oracle.json").read_text())["episodes"]
    assert [e["alteration"]["seed"] for e in episodes] == [f["seed"] for f in floors]
    assert all(set(e["dead_ends"]) >= {"entries", "metres_in", "metres_inside"} for e in episodes)
    assert "dead end entries / scenario" in (out / "results.md").read_text()
    setting = json.loads((out / "results.json").read_text())["setting"]
    assert setting["alteration"]["seed"] == 'zlib.crc32(f"{map}:{row}:{col}")'
    capsys.readouterr()
    assert main(argv) == 0 and "done already" in capsys.readouterr().out
    assert main(argv + ["--pose-noise", "0.05,1"]) == 2
    assert "noise-free protocol" in capsys.readouterr().err
