"""Prediction reuse and crops (#16) on hand-built maps with exact expected crops, the explorer's use of them,
and the asynchronous mode's staleness bound."""

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.explorer import ExplorerConfig, PredictionSchedule
from superex_deploy.onboard.planners import make_planner
from superex_deploy.onboard.prediction import ObservedAsPrediction
from superex_deploy.onboard.prediction_reuse import PredictionReuse, ReusingPredictor, _grow, changed_box
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Prediction
from superex_deploy.sim.episode import ExplorationConfig, run_episode


class Recording:
    """A predictor that accepts crops and answers every unknown cell with the number of its call (so which call
    wrote a cell can be read off the result); records the shape of every map it was given."""

    name = "recording"

    def __init__(self, accepts_crops=True, size_multiple=1):
        self.accepts_crops = accepts_crops
        self.size_multiple = size_multiple
        self.shapes = []

    def predict(self, observed, extra=None):
        self.shapes.append(observed.shape)
        mean = np.where(observed == UNKNOWN, np.float32(len(self.shapes) / 100), (observed == OCCUPIED))
        return Prediction(mean=mean.astype(np.float32), variance=np.full(observed.shape, 0.01, np.float32))


def _map(shape=(100, 120)):
    observed = np.full(shape, UNKNOWN, np.int8)
    observed[40:60, 50:70] = FREE
    return observed


def test_changed_box_and_grow_on_hand_built_boxes():
    changed = np.zeros((10, 12), bool)
    assert changed_box(changed) is None
    changed[2, 3] = changed[5, 7] = True
    assert changed_box(changed) == (2, 3, 6, 8)
    assert _grow((2, 3, 6, 8), 2, (10, 12)) == (0, 1, 8, 10)
    # Widened to a multiple of 4 inside the map: 8 rows stay 8; 9 columns become 12 = the whole width.
    assert _grow((2, 3, 6, 8), 2, (10, 12), multiple=4) == (0, 0, 8, 12)
    # A box in the corner grows away from the edges it touches.
    assert _grow((0, 0, 3, 3), 0, (10, 12), multiple=4) == (0, 0, 4, 4)
    assert _grow((7, 9, 10, 12), 0, (10, 12), multiple=4) == (6, 8, 10, 12)


def test_below_the_change_threshold_the_last_prediction_is_merged_with_the_map():
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_cells=5), resolution_m=0.1)
    observed = _map()
    first = reusing.predict(observed)
    assert predictor.shapes == [observed.shape] and reusing.runs == 1
    assert np.all(first.mean[observed == UNKNOWN] == np.float32(0.01))
    observed[30, 50:54] = OCCUPIED  # 4 changed cells < 5
    second = reusing.predict(observed)
    assert len(predictor.shapes) == 1 and reusing.reused == 1
    assert np.all(second.mean[30, 50:54] == 1.0) and np.all(second.variance[30, 50:54] == 0.0)
    assert second.mean[0, 0] == np.float32(0.01) and second.variance[0, 0] == np.float32(0.01)
    observed[31, 50] = FREE  # the 5th cell
    reusing.predict(observed)
    assert len(predictor.shapes) == 2 and reusing.runs == 2


def test_a_crop_covers_the_change_plus_the_margin_and_only_its_inner_part_is_written():
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(crop_margin_m=1.0), resolution_m=0.1)  # 10 cells
    observed = _map()
    reusing.predict(observed)
    # The first prediction: the known box (40:60, 50:70) grown by 10 cells.
    assert predictor.shapes == [(40, 40)]
    observed[20:22, 90:93] = FREE
    result = reusing.predict(observed)
    assert predictor.shapes[-1] == (2 + 20, 3 + 20)
    second = np.float32(0.02)
    inner = np.zeros(observed.shape, bool)
    inner[15:27, 85:98] = True  # the change grown by half the margin
    unknown = observed == UNKNOWN
    assert np.all(result.mean[inner & unknown] == second)
    assert not np.any(result.mean[~inner & unknown] == second)
    # Outside: the first crop's inner part holds the first prediction, the rest was never predicted (0).
    assert result.mean[36, 50] == np.float32(0.01) and result.mean[0, 0] == 0.0


def test_a_crop_is_widened_to_the_networks_size_multiple():
    predictor = Recording(size_multiple=8)
    reusing = ReusingPredictor(predictor, PredictionReuse(crop_margin_m=1.0), resolution_m=0.1)
    reusing.predict(_map())
    assert predictor.shapes == [(40, 40)]
    observed = _map()
    observed[20:22, 90:93] = FREE
    reusing.predict(observed)
    assert predictor.shapes[-1] == (24, 24)


def test_a_predictor_that_takes_no_crops_gets_the_whole_map():
    predictor = Recording(accepts_crops=False)
    reusing = ReusingPredictor(predictor, PredictionReuse(crop_margin_m=1.0), resolution_m=0.1)
    assert not reusing.crops
    observed = _map()
    reusing.predict(observed)
    observed[20, 90] = FREE
    reusing.predict(observed)
    assert predictor.shapes == [observed.shape] * 2


def test_a_look_without_commit_leaves_no_trace():
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_cells=1, crop_margin_m=1.0), resolution_m=0.1)
    observed = _map()
    reusing.predict(observed)
    changed = observed.copy()
    changed[20:22, 90:93] = FREE
    looked = reusing.predict(changed, commit=False)
    assert reusing.runs == 1 and reusing.reused == 0 and reusing.predicted_cells == 40 * 40
    committed = reusing.predict(changed)
    np.testing.assert_array_equal(looked.mean[changed == UNKNOWN] > 0.015, committed.mean[changed == UNKNOWN] > 0.025)
    assert reusing.runs == 2


def test_evidence_that_rose_counts_as_a_change():
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_cells=1, crop_margin_m=1.0), resolution_m=0.1)
    observed, evidence = _map(), np.zeros((100, 120), np.float32)
    reusing.predict(observed, evidence)
    evidence[80, 20] = 0.04  # below evidence_change = 0.05: no change
    reusing.predict(observed, evidence)
    assert reusing.runs == 1
    evidence[80, 20] = 0.06
    reusing.predict(observed, evidence)
    assert reusing.runs == 2 and predictor.shapes[-1] == (21, 21)


def test_bad_settings_and_inputs():
    with pytest.raises(ValueError, match=r"min_changed_cells must be an integer >= 0, got -1"):
        PredictionReuse(min_changed_cells=-1)
    with pytest.raises(ValueError, match=r"crop_margin_m must be a positive number of metres or None, got 0"):
        PredictionReuse(crop_margin_m=0)
    with pytest.raises(ValueError, match=r"evidence_change must lie in \[0, 1\), got 1.5"):
        PredictionReuse(evidence_change=1.5)
    with pytest.raises(ValueError, match=r"evidence_change must lie in \[0, 1\), got None"):
        PredictionReuse(evidence_change=None)
    with pytest.raises(ValueError, match=r"min_changed_cells must be an integer >= 0, got 2.0"):
        PredictionReuse(min_changed_cells=2.0)
    with pytest.raises(ValueError, match=r"crop_margin_m must be a positive number of metres or None, got True"):
        PredictionReuse(crop_margin_m=True)
    with pytest.raises(ValueError, match=r"wait_first must be True or False, got 'no'"):
        PredictionSchedule(True, 2, 2, wait_first="no")
    assert ReusingPredictor(Recording(), PredictionReuse(crop_margin_m=1.1), 0.1)._margin == 11
    with pytest.raises(ValueError, match="cfg must be a PredictionReuse, got dict"):
        ReusingPredictor(Recording(), {}, 0.1)
    reusing = ReusingPredictor(Recording(), PredictionReuse(min_changed_cells=3), 0.1)
    reusing.predict(_map())
    with pytest.raises(ValueError, match=r"observed has shape \(50, 50\), the last prediction \(100, 120\)"):
        reusing.predict(_map((50, 50)))


def _rooms():
    """Three rooms along a corridor: enough frontiers and goal choices for the explorer in 150 steps."""
    walls = np.ones((80, 160), bool)
    walls[36:44, 2:158] = False  # corridor
    for left in (10, 60, 110):
        walls[4:34, left:left + 40] = False
        walls[46:76, left:left + 40] = False
        walls[34:36, left + 18:left + 22] = False  # doors
        walls[44:46, left + 18:left + 22] = False
    return OccupancyGrid(walls, ~walls, 0.1, "rooms")


def _goals(cfg, predictor=None, planner="mapex", iou_every=0):
    result = run_episode(_rooms(), (40, 6), make_planner(planner), predictor or ObservedAsPrediction(), steps=150,
                         cfg=ExplorationConfig(iou_every=iou_every, explorer=ExplorerConfig(prediction=cfg[0], reuse=cfg[1])))
    return result


def test_crops_of_a_cellwise_predictor_change_nothing():
    """The observed predictor's output at a cell depends on that cell alone, so predicting crops must give the
    very episode the whole-map predictions give."""
    class Shapes(ObservedAsPrediction):
        def __init__(self):
            self.shapes = []

        def predict(self, observed, extra=None):
            self.shapes.append(observed.shape)
            return super().predict(observed, extra)

    full = _goals((PredictionSchedule(), PredictionReuse()))
    shapes = Shapes()
    cropped = _goals((PredictionSchedule(), PredictionReuse(crop_margin_m=0.5)), shapes)
    assert full.goals == cropped.goals and len(full.goals) >= 4
    np.testing.assert_array_equal(full.coverage, cropped.coverage)
    # The planner was served crops, not the whole 80 x 160 map.
    assert len(shapes.shapes) >= 4 and all(rows * cols < 80 * 160 for rows, cols in shapes.shapes)


def test_an_evaluation_between_requests_does_not_change_the_episode():
    """IoU evaluations call explorer.predict() at steps where the planner did not ask: with reuse on, that look
    must not become the last prediction."""
    class Shifting(ObservedAsPrediction):
        """Unknown cells get a wall probability that depends on the map's size: crops differ from whole maps."""

        def predict(self, observed, extra=None):
            base = super().predict(observed, extra)
            mean = np.where(observed == UNKNOWN, np.float32(0.3 * observed.shape[0] / 80), base.mean)
            return Prediction(mean=mean.astype(np.float32), variance=np.full(observed.shape, 0.1, np.float32))

    reuse = PredictionReuse(min_changed_cells=50, crop_margin_m=1.0)
    quiet = _goals((PredictionSchedule(), reuse), Shifting())
    evaluated = _goals((PredictionSchedule(), reuse), Shifting(), iou_every=1)
    assert quiet.goals == evaluated.goals and len(quiet.iou) == 0 and len(evaluated.iou) >= 100


@pytest.mark.parametrize("every,after,wait_first", [(5, 3, False), (4, 4, False), (2, 1, True), (1, 1, False),
                                                    (2, 2, True)])
def test_the_deterministic_asynchronous_mode_keeps_its_staleness_bound(every, after, wait_first):
    """Step t plans with the prediction of step k * every for the largest k with k * every + after <= t (with
    ``wait_first``, the first step's own prediction until then)."""
    from superex_deploy.sim.episode import make_world_and_explorer

    cfg = ExplorationConfig(iou_every=0, explorer=ExplorerConfig(
        prediction=PredictionSchedule(True, every, after, wait_first=wait_first), reuse=PredictionReuse(crop_margin_m=1.0)))
    world, explorer = make_world_and_explorer(_rooms(), (40, 6), make_planner("mapex"), ObservedAsPrediction(),
                                              cfg=cfg)
    with explorer:
        for t in range(60):
            command = explorer.step(world.observe())
            expected = ((t - after) // every) * every if t >= after else (0 if wait_first else -1)
            assert command.prediction_step == expected, t
            assert t - command.prediction_step <= every + after - 1 or expected == -1
            assert (command.prediction is None) == (expected == -1)
            if command.finished:
                break
            world.apply(command)
