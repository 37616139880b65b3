"""The learned models at their native scale (superex_deploy.onboard.prediction.scale): the pooling rules, the
refused resolutions, nothing changed at the models' own 0.1 m, and a 0.05 / 0.0333 / 0.025 m copy of a KTH train
floor predicted as the 0.1 m floor is."""

from pathlib import Path

import numpy as np
import pytest

from superex_deploy.maps import list_maps, load_map
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.explorer import Explorer, ExplorerConfig
from superex_deploy.onboard.nlos.processing import SpadProcessing
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.inference import LamaEnsemble, ModelKind, Pix2PixFilter, read_manifest
from superex_deploy.onboard.prediction.reuse import PredictionReuse
from superex_deploy.onboard.prediction.scale import (NativeScaleFilter, NativeScalePredictor, at_resolution, filter_area,
                                                     pool_mean, pool_observed, pool_prediction, repeat_cells,
                                                     scale_factors, upsample_linear)
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Prediction

U, F, W = UNKNOWN, FREE, OCCUPIED


class Spy:
    """A predictor trained at 0.1 m that records what it is given and answers the evidence (or 0.5) everywhere."""

    name = "spy"
    accepts_crops = True
    size_multiple = 8
    resolution_m = 0.1

    def __init__(self):
        self.inputs = []

    def predict(self, observed, extra=None):
        self.inputs.append((observed.copy(), None if extra is None else extra.copy()))
        mean = np.full(observed.shape, 0.5, np.float32) if extra is None else extra.astype(np.float32)
        return Prediction(mean=mean, variance=np.full(observed.shape, 0.25, np.float32))


def _floor_observed():
    """A KTH train floor at 0.1 m and an observed map of it: the cells within 3 m of a free cell near the middle."""
    grid = load_map(list_maps("train")[0])
    occupied = grid.occupied
    rows, cols = np.mgrid[:occupied.shape[0], :occupied.shape[1]]
    free = np.argwhere(~occupied)
    r0, c0 = free[len(free) // 2]
    seen = np.hypot(rows - r0, cols - c0) < 30
    observed = np.full(occupied.shape, UNKNOWN, np.int8)
    observed[seen] = np.where(occupied[seen], OCCUPIED, FREE)
    return observed


def test_pooled_blocks_follow_the_wall_unknown_free_rules():
    observed = np.array([[U, U, U, F, W, F, U],
                         [U, U, U, U, F, F, U],
                         [F, F, U, W, F, U, W],
                         [F, F, U, U, F, F, U]], np.int8)
    pooled = pool_observed(observed, 2)
    # [all unknown, one free, a wall among free | a wall, free and unknown, all free, a wall past which is the edge]
    assert pooled.dtype == np.int8
    np.testing.assert_array_equal(pooled, [[U, F, W, U], [F, W, F, W]])
    np.testing.assert_array_equal(pool_observed(observed, 1), observed)
    np.testing.assert_array_equal(pool_observed(observed, 4), [[W, W]])
    np.testing.assert_array_equal(pool_observed(np.full((3, 3), U, np.int8), 3), [[U]])


def test_pooled_evidence_is_the_block_mean_and_upsampling_keeps_constants():
    evidence = np.array([[0.0, 1.0, 0.5],
                         [0.5, 0.5, 0.5],
                         [1.0, 1.0, 0.25]], np.float32)
    np.testing.assert_allclose(pool_mean(evidence, 2), [[0.5, 0.5], [1.0, 0.25]])
    up = upsample_linear(np.full((2, 3), 0.7, np.float32), 3, (5, 9))
    assert up.shape == (5, 9) and up.dtype == np.float32
    np.testing.assert_allclose(up, 0.7, rtol=1e-6)
    ramp = upsample_linear(np.array([[0.0, 1.0]], np.float32), 2, (1, 4))
    np.testing.assert_allclose(ramp, [[0.0, 0.25, 0.75, 1.0]])  # centres at 0.25, 0.75 of a coarse cell
    np.testing.assert_array_equal(repeat_cells(np.array([[U, W]], np.int8), 2), [[U, U, W, W], [U, U, W, W]])
    fine = Prediction(mean=np.array([[0.0, 1.0], [1.0, 1.0]], np.float32), variance=np.zeros((2, 2), np.float32))
    back = pool_prediction(fine, 2, (1, 1))
    np.testing.assert_allclose(back.mean, [[0.75]])
    np.testing.assert_allclose(back.variance, [[0.1875]])  # the four cells as one mixture


def test_served_and_refused_resolutions():
    assert scale_factors(0.1, 0.1) == (1, 1)
    assert scale_factors(0.05, 0.1) == (2, 1)
    assert scale_factors(0.1 / 3, 0.1) == (3, 1)
    assert scale_factors(0.025, 0.1) == (4, 1)
    assert scale_factors(0.2, 0.1) == (1, 2)
    for resolution in (0.02, 0.01, 0.04, 0.07, 0.15, 0.3, 0.4):
        with pytest.raises(ValueError, match="cannot be served by a model trained at 0.1 m/cell"):
            scale_factors(resolution, 0.1)
    for bad in (0.0, -0.05, float("nan"), True, "0.05"):
        with pytest.raises(ValueError, match="resolution_m must be a positive number"):
            scale_factors(bad, 0.1)
    with pytest.raises(ValueError, match="cannot be served"):
        NativeScalePredictor(Spy(), 0.07)
    spy = Spy()
    frame = MapFrame(shape=(40, 40), resolution_m=0.07)
    with pytest.raises(ValueError, match="a 0.07 m grid cannot be served"):
        Explorer(frame, make_planner("nearest"), spy)
    with pytest.raises(ValueError, match="a 0.3 m grid cannot be served"):
        SpadProcessing(bp_filter=Pix2PixFilter.from_manifest().filter_map).check_resolution(0.3)
    # Predictors without a training resolution work at any.
    plain = type("Plain", (), {"predict": lambda self, observed, extra=None: None})()
    assert at_resolution(plain, 0.07) is plain


def test_nothing_changes_at_the_models_resolution():
    lama = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS)
    p2p = Pix2PixFilter.from_manifest()
    assert lama.resolution_m == p2p.resolution_m == 0.1
    assert at_resolution(lama, 0.1) is lama
    assert at_resolution(p2p.filter_map, 0.1) == p2p.filter_map
    frame = MapFrame(shape=(40, 40), resolution_m=0.1)
    cfg = ExplorerConfig(reuse=PredictionReuse(crop_margin_m=2.0))
    assert Explorer(frame, make_planner("nearest"), lama, cfg=cfg).reusing.predictor is lama
    fine = Explorer(MapFrame(shape=(40, 40), resolution_m=0.05), make_planner("nearest"), lama, cfg=cfg)
    assert isinstance(fine.reusing.predictor, NativeScalePredictor) and fine.reusing.predictor.predictor is lama
    assert fine.reusing.predictor.size_multiple == 2 * lama.size_multiple
    assert fine.predictor is lama


def test_manifest_gives_every_model_its_training_resolution():
    assert {entry.resolution_m for entry in read_manifest(Path(__file__).resolve().parents[1] / "exported")} == {0.1}


@pytest.mark.parametrize("k", [2, 3, 4])
def test_the_model_gets_the_coarse_map_of_a_finer_copy(k):
    observed = _floor_observed()
    evidence = np.random.default_rng(k).random(observed.shape).astype(np.float32)
    spy = Spy()
    fine = np.kron(observed, np.ones((k, k), np.int8))
    wrapped = at_resolution(spy, 0.1 / k)
    result = wrapped.predict(fine, np.kron(evidence, np.ones((k, k), np.float32)))
    (given, given_evidence), = spy.inputs
    np.testing.assert_array_equal(given, observed)
    np.testing.assert_allclose(given_evidence, evidence, rtol=1e-6)
    assert result.mean.shape == result.variance.shape == fine.shape
    known = fine != UNKNOWN
    np.testing.assert_array_equal(result.mean[known], fine[known] == OCCUPIED)  # observed cells keep their value
    assert (result.variance[known] == 0).all() and np.allclose(result.variance[~known], 0.25)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_lama_on_a_finer_copy_of_a_train_floor_predicts_as_on_the_floor(k):
    observed = _floor_observed()
    lama = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS)
    expected = lama.predict(observed).mean
    fine = np.kron(observed, np.ones((k, k), np.int8))
    back = pool_mean(at_resolution(lama, 0.1 / k).predict(fine).mean, k)
    unknown = observed == UNKNOWN
    error = np.abs(back - expected)
    # What is left is the bilinear interpolation across a model cell, largest beside walls. The model run
    # unchanged on the 0.05 m copy is off by 0.038 on average over the unknown cells (0.65 at worst).
    assert error[unknown].mean() < 0.006 and error.max() < 0.2
    np.testing.assert_allclose(back[~unknown], expected[~unknown], atol=1e-6)


def test_the_filter_gets_the_renormalised_block_mean_and_the_robots_block():
    calls = []

    def spy(bp, pose_rc):
        calls.append((bp.copy(), pose_rc))
        return np.full(bp.shape, 0.3, np.float32)

    spy.resolution_m = 0.1
    bp = np.array([[0.0, 0.2, 0.4, 0.4], [0.2, 0.2, 0.0, 0.0]], np.float32)
    out = NativeScaleFilter(spy, 0.05)(bp, (1, 3))
    (given, pose), = calls
    np.testing.assert_allclose(given, [[0.75, 1.0]])  # block means 0.15 and 0.2, brought to a maximum of 1
    assert pose == (0, 1)
    np.testing.assert_allclose(out, 0.3)
    assert out.shape == bp.shape


def _rings(shape=(90, 100), seed=0):
    """A back-projection-like map in [0, 1]: a few blurred rings (the arcs of hidden walls), maximum 1."""
    rows, cols = np.mgrid[:shape[0], :shape[1]]
    bp = np.zeros(shape)
    rng = np.random.default_rng(seed)
    for _ in range(6):
        r, c, radius = rng.uniform(20, 70), rng.uniform(20, 80), rng.uniform(5, 25)
        bp += np.exp(-0.5 * ((np.hypot(rows - r, cols - c) - radius) / 1.5) ** 2)
    return (bp / bp.max()).astype(np.float32)


def test_pix2pix_on_a_finer_copy_filters_as_on_the_coarse_grid():
    p2p = Pix2PixFilter.from_manifest()
    bp = _rings()
    expected = p2p.filter_map(bp, (45, 50))
    for k in (2, 3, 4):
        scaled = at_resolution(p2p.filter_map, 0.1 / k)
        assert isinstance(scaled, NativeScaleFilter)
        fine = np.kron(bp, np.ones((k, k), np.float32)) * 0.5  # a fine map normalised otherwise: renormalised
        back = pool_mean(scaled(fine, (45 * k + k // 2, 50 * k)), k)
        # The interpolation across a model cell is what is left; the filter run unchanged on the 0.05 m copy is
        # off by 0.10 on average.
        assert np.abs(back - expected).mean() < 0.02


def test_a_coarser_grid_is_repeated_to_the_model_and_pooled_back():
    spy = Spy()
    observed = np.array([[U, F], [W, U]], np.int8)
    evidence = np.array([[0.2, 0.0], [0.0, 0.8]], np.float32)
    result = at_resolution(spy, 0.2).predict(observed, evidence)
    (given, given_evidence), = spy.inputs
    np.testing.assert_array_equal(given, np.kron(observed, np.ones((2, 2), np.int8)))
    np.testing.assert_array_equal(given_evidence, np.kron(evidence, np.ones((2, 2), np.float32)))
    np.testing.assert_allclose(result.mean, evidence)
    np.testing.assert_allclose(result.variance, 0.25)
    lama = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS)
    coarse = pool_observed(_floor_observed(), 2)
    prediction = at_resolution(lama, 0.2).predict(coarse)
    assert prediction.mean.shape == coarse.shape
    known = coarse != UNKNOWN
    np.testing.assert_array_equal(prediction.mean[known], coarse[known] == OCCUPIED)


@pytest.mark.slow
def test_an_episode_on_a_0_05_m_copy_runs_the_models_at_their_scale():
    from superex_deploy.maps import OccupancyGrid
    from superex_deploy.pipeline import PROFILES, make_predictor, make_sensing
    from superex_deploy.evaluation.episodes import run_episode

    grid = load_map(list_maps("train")[1])
    fine = OccupancyGrid(np.kron(grid.occupied, np.ones((2, 2), bool)), np.kron(grid.valid, np.ones((2, 2), bool)),
                         0.05, grid.name)
    free = np.argwhere(~fine.occupied & fine.valid)
    lama, shapes = make_predictor("lama_bp", profile=PROFILES["full"]), []

    class Recording:
        """The ensemble, recording the shape of every map it is given."""
        name, accepts_crops, resolution_m, size_multiple = "lama_bp", True, lama.resolution_m, lama.size_multiple

        def predict(self, observed, extra=None):
            shapes.append(observed.shape)
            return lama.predict(observed, extra)

    result = run_episode(fine, tuple(free[len(free) // 2]), make_planner("nearest"), Recording(), steps=30,
                         sensing=make_sensing("lama_bp", True, 0, profile=PROFILES["full"]))
    assert shapes and set(shapes) == {grid.occupied.shape}  # the 0.1 m map, every time
    assert result.collisions == 0 and result.true_walls_carved == 0 and result.explorer_map_iou > 0.1


@pytest.mark.parametrize("resolution_m", [0.1, 0.05, 0.1 / 3, 0.2])
def test_the_filter_run_on_its_area_alone_gives_its_whole_grid_answer(resolution_m):
    """filter_area: the Pix2Pix filter handed only the rectangle around the robot (and the back-projection's patch)
    writes there what it writes on the whole grid, and nothing elsewhere; robots near every edge."""
    p2p = Pix2PixFilter.from_manifest()
    scaled = at_resolution(p2p.filter_map, resolution_m)
    rng = np.random.default_rng(int(resolution_m * 1000))
    side = int(round(30 / resolution_m))  # a 30 m square grid, larger than the window at every scale
    for trial in range(5):
        shape = (side + int(rng.integers(0, 7)), side + int(rng.integers(0, 7)))
        pose = (int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1])))
        if trial == 0:
            pose = (1, shape[1] - 2)
        half = int(rng.integers(5, side // 3))
        patch = (slice(max(pose[0] - half, 0), min(pose[0] + half, shape[0])),
                 slice(max(pose[1] - 2 * half, 0), min(pose[1] + half // 2, shape[1])))
        bp = np.zeros(shape, np.float32)
        bp[patch] = rng.random((patch[0].stop - patch[0].start, patch[1].stop - patch[1].start)) ** 4
        whole = scaled(bp, pose)
        rows, cols = filter_area(p2p.filter_map, resolution_m, pose, shape, patch)
        assert rows.start <= patch[0].start and rows.stop >= patch[0].stop
        alone = scaled(np.ascontiguousarray(bp[rows, cols]), (pose[0] - rows.start, pose[1] - cols.start))
        # Bit for bit where the model cell is a power-of-two number of cells; at 1/3 the interpolation weights,
        # computed from the rectangle's own first cell, may differ in the last bit.
        np.testing.assert_allclose(alone, whole[rows, cols], rtol=0, atol=0 if resolution_m != 0.1 / 3 else 1e-6)
        outside = whole.copy()
        outside[rows, cols] = 0.0
        assert not outside.any()
        assert (rows.stop - rows.start) * (cols.stop - cols.start) < 0.8 * bp.size or min(shape) < 2 * half + 10


def test_a_filter_without_a_window_gets_the_whole_grid():
    def plain(bp, pose_rc):
        return bp

    plain.resolution_m = 0.1
    assert filter_area(plain, 0.05, (3, 4), (20, 30)) == (slice(0, 20), slice(0, 30))
    with pytest.raises(ValueError, match="cannot be served"):
        filter_area(Pix2PixFilter.from_manifest().filter_map, 0.07, (3, 4), (20, 30))
