"""Prediction reuse and crops on hand-built maps with exact expected crops, the explorer's use of them,
and the asynchronous mode's staleness bound."""

import numpy as np
import pytest

from superex_deploy.onboard.explorer import ExplorerConfig, PredictionSchedule
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.prediction.reuse import (RAMPS, PredictionReuse, ReusingPredictor, _grow, changed_box,
                                                     feather_weights, merge_with_map)
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Prediction
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.exploration import ExplorationConfig


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
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_m2=0.05), resolution_m=0.1)
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


def test_a_crop_covers_the_change_plus_the_margin_and_with_hard_edges_only_its_inner_part_is_written():
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(crop_margin_m=1.0, feather_m=0), resolution_m=0.1)
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


def test_a_feathered_crop_writes_its_inner_part_blends_the_band_and_leaves_the_rest():
    """The rule of the module docstring: the inner part is the crop's answer bit for bit, the band between it and
    the crop's edge a convex blend of the crop and the last prediction (mean; variance: the mixture's), every
    cell outside the crop untouched."""
    predictor = Recording()
    reusing = ReusingPredictor(predictor, PredictionReuse(crop_margin_m=1.0, feather_m=0.3), resolution_m=0.1)
    observed = _map()
    first = reusing.predict(observed)
    observed[20:22, 90:93] = FREE
    result = reusing.predict(observed)
    assert reusing.last_crop == ((10, 80, 32, 103), (15, 85, 27, 98))
    last = merge_with_map(first, observed)
    unknown = observed == UNKNOWN
    inner = np.zeros(observed.shape, bool)
    inner[15:27, 85:98] = True
    outer = np.zeros(observed.shape, bool)
    outer[10:32, 80:103] = True
    crop_mean, crop_variance = np.float32(0.02), np.float32(0.01)
    assert np.all(result.mean[inner & unknown] == crop_mean) and np.all(result.variance[inner] == crop_variance)
    np.testing.assert_array_equal(result.mean[~outer], last.mean[~outer])
    np.testing.assert_array_equal(result.variance[~outer], last.variance[~outer])
    band = outer & ~inner & unknown
    low, high = np.minimum(last.mean, crop_mean)[band], np.maximum(last.mean, crop_mean)[band]
    assert np.all((result.mean[band] >= low - 1e-7) & (result.mean[band] <= high + 1e-7))
    weight = (result.mean[band] - last.mean[band]) / (crop_mean - last.mean[band])
    mixture = (weight * crop_variance + (1 - weight) * last.variance[band]
               + weight * (1 - weight) * (crop_mean - last.mean[band]) ** 2)
    np.testing.assert_allclose(result.variance[band], mixture, atol=1e-6)
    # The band is 5 cells wide; the 3-cell ramp reaches 0 two cells before the crop's edge.
    assert weight.min() >= 0 and weight.max() < 1
    np.testing.assert_array_equal(result.mean[10:12, 80:103], last.mean[10:12, 80:103])
    assert np.all(result.mean[12:15, 85:98] > last.mean[12:15, 85:98])
    # Known cells take the map's value wherever the blend reaches (the crop's and the last prediction agree).
    known = outer & ~unknown
    np.testing.assert_array_equal(result.mean[known], (observed[known] == OCCUPIED).astype(np.float32))


class TwoConstants:
    """A predictor that answers every cell of its first map with (0.2, 0.01), of every later one with
    (0.6, 0.05): a crop's blend into the first prediction can be written down by hand."""

    name, accepts_crops, size_multiple = "constants", True, 1

    def __init__(self):
        self.calls = 0

    def predict(self, observed, extra=None):
        self.calls += 1
        mean, variance = (0.2, 0.01) if self.calls == 1 else (0.6, 0.05)
        return Prediction(mean=np.full(observed.shape, mean, np.float32),
                          variance=np.full(observed.shape, variance, np.float32))


def _constant_crop(feather_m, ramp="linear", margin_m=1.0):
    """The first prediction on the whole 100 x 120 map (its corners are known), then a crop around (50, 60):
    with a 1 m margin its box is rows 40:61, cols 50:71 and its inner part rows 45:56, cols 55:66."""
    reusing = ReusingPredictor(TwoConstants(), PredictionReuse(crop_margin_m=margin_m, feather_m=feather_m,
                                                               feather_ramp=ramp), resolution_m=0.1)
    observed = np.full((100, 120), UNKNOWN, np.int8)
    observed[0, 0] = observed[-1, -1] = FREE
    reusing.predict(observed)
    assert reusing.last_crop == ((0, 0, 100, 120), (0, 0, 100, 120))
    observed[50, 60] = FREE
    return reusing.predict(observed), reusing.last_crop


def test_a_constant_crop_gives_the_exact_ramp():
    result, crops = _constant_crop(0.3)
    assert crops == ((40, 50, 61, 71), (45, 55, 56, 66))
    ramp = np.array([0.0, 0.0, 0.25, 0.5, 0.75])  # 3 cells of a linear ramp, then the 2 cells it does not reach
    rows = np.ones(100)
    rows[40:45], rows[56:61] = ramp, ramp[::-1]
    rows[:40] = rows[61:] = 0.0
    cols = np.ones(120)
    cols[50:55], cols[66:71] = ramp, ramp[::-1]
    cols[:50] = cols[71:] = 0.0
    weight = rows[:, None] * cols[None, :]
    expected_mean = 0.2 + weight * (0.6 - 0.2)
    expected_variance = 0.01 + weight * (0.05 - 0.01) + weight * (1 - weight) * (0.6 - 0.2) ** 2
    known = np.zeros((100, 120), bool)
    known[0, 0] = known[-1, -1] = True
    expected_mean[known], expected_variance[known] = 0.0, 0.0
    np.testing.assert_allclose(result.mean, expected_mean, rtol=0, atol=1e-7)
    np.testing.assert_allclose(result.variance, expected_variance, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(result.mean[45:56, 55:66], np.float32(0.6))
    # The weights themselves, and the cosine ramp over the same 3 cells.
    row_w, col_w = feather_weights((40, 50, 61, 71), (45, 55, 56, 66), 3)
    np.testing.assert_allclose(row_w, rows[40:61], atol=1e-7)
    np.testing.assert_allclose(col_w, cols[50:71], atol=1e-7)
    row_w, _ = feather_weights((40, 50, 61, 71), (45, 55, 56, 66), 3, "cosine")
    np.testing.assert_allclose(row_w[:5], [0, 0, 0.5 - 0.5 * np.sqrt(0.5), 0.5, 0.5 + 0.5 * np.sqrt(0.5)], atol=1e-7)
    # A ramp longer than the band is shortened to it: 5 cells, reaching 1/6 at the crop's outermost cell.
    row_w, _ = feather_weights((40, 50, 61, 71), (45, 55, 56, 66), 20)
    np.testing.assert_allclose(row_w[:5], np.arange(1, 6) / 6, atol=1e-7)


@pytest.mark.parametrize("ramp", RAMPS)
@pytest.mark.parametrize("feather_m", [0.1, 0.3, 0.5, 2.0])
def test_no_seam_step_is_steeper_than_the_ramp(feather_m, ramp):
    result, crops = _constant_crop(feather_m, ramp)
    length = min(int(round(feather_m / 0.1)), 5)  # the band is 5 cells wide on every side
    bound = (1 if ramp == "linear" else np.pi / 2) / (length + 1) * (0.6 - 0.2)
    mean = result.mean.astype(np.float64)
    mean[0, 0] = mean[-1, -1] = 0.2  # the two known corners are far from the crop
    steps = max(np.abs(np.diff(mean, axis=0)).max(), np.abs(np.diff(mean, axis=1)).max())
    assert 0 < steps <= bound + 1e-6
    hard, _ = _constant_crop(0.0, ramp)
    assert np.abs(np.diff(hard.mean[30:70, 60], axis=0)).max() == pytest.approx(0.4)  # the seam feathering removes


class RandomAnswers:
    """A predictor whose every answer is fresh noise (mean and variance), keeping observed cells (their value,
    variance 0) as the LaMa ensembles do."""

    name, accepts_crops, size_multiple = "random", True, 8

    def __init__(self):
        self.rng = np.random.default_rng(7)

    def predict(self, observed, extra=None):
        mean = self.rng.random(observed.shape, dtype=np.float32)
        variance = self.rng.random(observed.shape, dtype=np.float32) * np.float32(0.1)
        mean[observed != UNKNOWN] = (observed[observed != UNKNOWN] == OCCUPIED)
        variance[observed != UNKNOWN] = 0.0
        return Prediction(mean=mean, variance=variance)


def test_feather_zero_is_the_hard_write_back_bit_for_bit():
    """feather_m = 0 against the rule before feathering, written out here: the last prediction merged with the
    map, the crop's inner part copied over it."""
    reusing = ReusingPredictor(RandomAnswers(), PredictionReuse(crop_margin_m=1.2, feather_m=0), resolution_m=0.1)
    twin = RandomAnswers()
    rng = np.random.default_rng(3)
    observed = _map()
    mean = variance = None
    for step in range(6):
        result = reusing.predict(observed)
        outer, inner = reusing.last_crop
        crop = twin.predict(np.ascontiguousarray(observed[outer[0]:outer[2], outer[1]:outer[3]]))
        if mean is None:
            mean, variance = (observed == OCCUPIED).astype(np.float32), np.zeros(observed.shape, np.float32)
        else:
            merged = merge_with_map(Prediction(mean=mean, variance=variance), observed)
            mean, variance = merged.mean, merged.variance
        rows, cols = slice(inner[0] - outer[0], inner[2] - outer[0]), slice(inner[1] - outer[1], inner[3] - outer[1])
        mean[inner[0]:inner[2], inner[1]:inner[3]] = crop.mean[rows, cols]
        variance[inner[0]:inner[2], inner[1]:inner[3]] = crop.variance[rows, cols]
        np.testing.assert_array_equal(result.mean, mean)
        np.testing.assert_array_equal(result.variance, variance)
        top, left = rng.integers(0, 90), rng.integers(0, 110)
        observed[top:top + rng.integers(1, 10), left:left + rng.integers(1, 10)] = rng.choice([FREE, OCCUPIED])


def test_the_blend_keeps_every_known_cell_and_every_untouched_cell_bit_for_bit():
    reusing = ReusingPredictor(RandomAnswers(), PredictionReuse(crop_margin_m=1.2, feather_m=0.4, feather_ramp="cosine"),
                               resolution_m=0.1)
    observed = _map()
    last = reusing.predict(observed)
    observed[70:75, 20:30] = OCCUPIED
    result = reusing.predict(observed)
    outer, inner = reusing.last_crop
    inside = np.zeros(observed.shape, bool)
    inside[outer[0]:outer[2], outer[1]:outer[3]] = True
    merged = merge_with_map(last, observed)
    known = observed != UNKNOWN
    np.testing.assert_array_equal(result.mean[known], merged.mean[known])
    np.testing.assert_array_equal(result.variance[known], 0.0)
    np.testing.assert_array_equal(result.mean[~inside], merged.mean[~inside])
    assert result.mean.dtype == result.variance.dtype == np.float32


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
    # Hard edges: the call that wrote a cell can be read off its value.
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_m2=0.01, crop_margin_m=1.0, feather_m=0),
                               resolution_m=0.1)
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
    reusing = ReusingPredictor(predictor, PredictionReuse(min_changed_m2=0.01, crop_margin_m=1.0), resolution_m=0.1)
    observed, evidence = _map(), np.zeros((100, 120), np.float32)
    reusing.predict(observed, evidence)
    evidence[80, 20] = 0.04  # below evidence_change = 0.05: no change
    reusing.predict(observed, evidence)
    assert reusing.runs == 1
    evidence[80, 20] = 0.06
    reusing.predict(observed, evidence)
    assert reusing.runs == 2 and predictor.shapes[-1] == (21, 21)


def test_bad_settings_and_inputs():
    with pytest.raises(ValueError, match=r"min_changed_m2 must be a number of square metres >= 0, got -1"):
        PredictionReuse(min_changed_m2=-1)
    with pytest.raises(ValueError, match=r"crop_margin_m must be a positive number of metres or None, got 0"):
        PredictionReuse(crop_margin_m=0)
    with pytest.raises(ValueError, match=r"evidence_change must lie in \[0, 1\), got 1.5"):
        PredictionReuse(evidence_change=1.5)
    with pytest.raises(ValueError, match=r"evidence_change must lie in \[0, 1\), got None"):
        PredictionReuse(evidence_change=None)
    with pytest.raises(ValueError, match=r"min_changed_m2 must be a number of square metres >= 0, got True"):
        PredictionReuse(min_changed_m2=True)
    with pytest.raises(TypeError, match="min_changed_cells"):  # the old cell count is no field
        PredictionReuse(min_changed_cells=2)
    with pytest.raises(ValueError, match=r"crop_margin_m must be a positive number of metres or None, got True"):
        PredictionReuse(crop_margin_m=True)
    with pytest.raises(ValueError, match=r"feather_m must be a number of metres >= 0, got -0.1"):
        PredictionReuse(feather_m=-0.1)
    with pytest.raises(ValueError, match=r"feather_m must be a number of metres >= 0, got None"):
        PredictionReuse(feather_m=None)
    with pytest.raises(ValueError, match=r"feather_ramp must be one of linear, cosine, got 'gauss'"):
        PredictionReuse(feather_ramp="gauss")
    with pytest.raises(ValueError, match=r"inner box \(0, 0, 5, 5\) must lie inside the outer box \(1, 1, 5, 5\)"):
        feather_weights((1, 1, 5, 5), (0, 0, 5, 5), 2)
    with pytest.raises(ValueError, match=r"feather_cells must be an integer >= 0, got -1"):
        feather_weights((0, 0, 5, 5), (1, 1, 4, 4), -1)
    with pytest.raises(ValueError, match=r"ramp must be one of linear, cosine, got 'step'"):
        feather_weights((0, 0, 5, 5), (1, 1, 4, 4), 1, "step")
    assert ReusingPredictor(Recording(), PredictionReuse(feather_m=0.3), 0.1)._feather == 3
    with pytest.raises(ValueError, match=r"wait_first must be True or False, got 'no'"):
        PredictionSchedule("simulated", 2, 2, wait_first="no")
    assert ReusingPredictor(Recording(), PredictionReuse(crop_margin_m=1.1), 0.1)._margin == 11
    with pytest.raises(ValueError, match="cfg must be a PredictionReuse, got dict"):
        ReusingPredictor(Recording(), {}, 0.1)
    reusing = ReusingPredictor(Recording(), PredictionReuse(min_changed_m2=0.03), 0.1)
    reusing.predict(_map())
    with pytest.raises(ValueError, match=r"observed has shape \(50, 50\), the last prediction \(100, 120\)"):
        reusing.predict(_map((50, 50)))


def _goals(grid, cfg, predictor=None, planner="mapex", iou_every=0):
    result = run_episode(grid, (40, 6), make_planner(planner), predictor or ObservedAsPrediction(), steps=150,
                         cfg=ExplorationConfig(iou_every=iou_every, explorer=ExplorerConfig(prediction=cfg[0], reuse=cfg[1])))
    return result


def test_crops_of_a_cellwise_predictor_change_nothing(corridor_rooms):
    """The observed predictor's output at a cell depends on that cell alone, so predicting crops must give the
    very episode the whole-map predictions give."""
    class Shapes(ObservedAsPrediction):
        def __init__(self):
            self.shapes = []

        def predict(self, observed, extra=None):
            self.shapes.append(observed.shape)
            return super().predict(observed, extra)

    full = _goals(corridor_rooms(), (PredictionSchedule(), PredictionReuse()))
    shapes = Shapes()
    cropped = _goals(corridor_rooms(), (PredictionSchedule(), PredictionReuse(crop_margin_m=0.5)), shapes)
    assert full.goals == cropped.goals and len(full.goals) >= 4
    np.testing.assert_array_equal(full.coverage, cropped.coverage)
    # The planner was served crops, not the whole 80 x 160 map.
    assert len(shapes.shapes) >= 4 and all(rows * cols < 80 * 160 for rows, cols in shapes.shapes)


def test_an_evaluation_between_requests_does_not_change_the_episode(corridor_rooms):
    """IoU evaluations call explorer.predict() at steps where the planner did not ask: with reuse on, that look
    must not become the last prediction."""
    class Shifting(ObservedAsPrediction):
        """Unknown cells get a wall probability that depends on the map's size: crops differ from whole maps."""

        def predict(self, observed, extra=None):
            base = super().predict(observed, extra)
            mean = np.where(observed == UNKNOWN, np.float32(0.3 * observed.shape[0] / 80), base.mean)
            return Prediction(mean=mean.astype(np.float32), variance=np.full(observed.shape, 0.1, np.float32))

    reuse = PredictionReuse(min_changed_m2=0.5, crop_margin_m=1.0)
    quiet = _goals(corridor_rooms(), (PredictionSchedule(), reuse), Shifting())
    evaluated = _goals(corridor_rooms(), (PredictionSchedule(), reuse), Shifting(), iou_every=1)
    assert quiet.goals == evaluated.goals and len(quiet.iou) == 0 and len(evaluated.iou) >= 100


@pytest.mark.parametrize("every,after,wait_first", [(5, 3, False), (4, 4, False), (2, 1, True), (1, 1, False),
                                                    (2, 2, True)])
def test_the_deterministic_asynchronous_mode_keeps_its_staleness_bound(corridor_rooms, every, after, wait_first):
    """Step t plans with the prediction of step k * every for the largest k with k * every + after <= t (with
    ``wait_first``, the first step's own prediction until then)."""
    from superex_deploy.evaluation.episodes import make_world_and_explorer

    cfg = ExplorationConfig(iou_every=0, explorer=ExplorerConfig(
        prediction=PredictionSchedule("simulated", every, after, wait_first=wait_first),
        reuse=PredictionReuse(crop_margin_m=1.0)))
    world, explorer = make_world_and_explorer(corridor_rooms(), (40, 6), make_planner("mapex"), ObservedAsPrediction(),
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
