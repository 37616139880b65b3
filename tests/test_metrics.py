"""The evaluation's metrics and summaries (superex_deploy.evaluation.metrics and .summary): the map IoU and the
pairing of two runs' scenarios, on hand-built maps and logs."""

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid
from superex_deploy.evaluation.metrics import map_iou
from superex_deploy.evaluation.summary import paired_differences


def test_map_iou_definition():
    walls = np.zeros((10, 10), bool)
    walls[5, :] = True
    grid = OccupancyGrid(walls, ~walls, 0.1, "line")
    assert map_iou(walls.astype(np.float32), grid) == 1.0
    half = walls.astype(np.float32)
    half[5, 5:] = 0.4
    assert map_iou(half, grid) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="shape"):
        map_iou(np.zeros((3, 3)), grid)


def _fake_result(map_name, start, coverage, iou, planner="mapex"):
    return {"map": map_name, "start_index": start, "planner": planner, "coverage": coverage,
            "coverage_with_carving": [c + 0.01 for c in coverage], "iou": {"iou": iou}}


def test_paired_differences_on_hand_built_runs():
    baseline = [_fake_result("a", 0, [0.1, 0.2, 0.3], [0.4]), _fake_result("a", 1, [0.1, 0.1], [0.5]),
                _fake_result("b", 0, [0.2, 0.4, 0.6], [0.3])]
    # listed in another order: pairing goes by scenario, not position
    candidate = [_fake_result("b", 0, [0.2, 0.3, 0.5], [0.3]), _fake_result("a", 0, [0.2, 0.3, 0.5], [0.6]),
                 _fake_result("a", 1, [0.1, 0.1], [0.5])]
    paired = paired_differences(baseline, candidate, [1, 3])
    assert paired["coverage@1"] == {"n": 3, "median": pytest.approx(0.0), "mean": pytest.approx(0.1 / 3),
                                    "better": 1, "worse": 0, "tied": 2,
                                    "baseline_mean": pytest.approx(0.4 / 3), "candidate_mean": pytest.approx(0.5 / 3)}
    # step 3: +0.2 (a/0), 0 (a/1 ended at step 2 and keeps its last value), -0.1 (b/0)
    assert paired["coverage@3"]["median"] == pytest.approx(0.0)
    assert paired["coverage@3"]["mean"] == pytest.approx(0.1 / 3)
    assert (paired["coverage@3"]["better"], paired["coverage@3"]["worse"], paired["coverage@3"]["tied"]) == (1, 1, 1)
    assert paired["final_iou"]["mean"] == pytest.approx(0.2 / 3)
    carved = paired_differences(baseline, candidate, [1], series="coverage_with_carving")
    assert carved["coverage@1"]["mean"] == pytest.approx(0.1 / 3 + 0.01)


def test_paired_differences_refuse_mismatched_runs():
    run = [_fake_result("a", 0, [0.1], [0.4])]
    with pytest.raises(ValueError, match="different scenarios"):
        paired_differences(run, [_fake_result("a", 1, [0.1], [0.4])], [1])
    with pytest.raises(ValueError, match="twice"):
        paired_differences(run, run + run, [1])
    with pytest.raises(ValueError, match="series"):
        paired_differences(run, run, [1], series="coverage_auc")
