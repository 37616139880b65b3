"""The expected-visibility gain against a brute-force enumeration of wall configurations on
tiny hand-built maps, against its slow twin, and wired into the superex and MapEx planners."""

import numpy as np
import pytest

from superex_deploy.onboard.planning.expected_visibility import ExpectedVisibility, expected_visible_gains
from superex_deploy.onboard.planning.planners import MapexConfig, MapexPlanner, SuperexConfig, SuperexPlanner
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, PlanningContext, Prediction
from tests.naive import brute_force_expected_visible, naive_expected_gain

# Odd ray counts: no ray runs exactly through a cell corner from a cell centre, where float rounding rather
# than geometry decides which neighbour the DDA and the crossing list enter.
N_RAYS = 97
RANGE_CELLS = 10.0


def _gain(mean, observed, viewpoint, n_rays=N_RAYS, min_transmittance=0.0):
    cfg = ExpectedVisibility(n_rays=n_rays, range_m=RANGE_CELLS, min_transmittance=min_transmittance)
    return float(expected_visible_gains(mean, observed, [[viewpoint]], cfg, 1.0)[0][0])


def _corridor():
    """5 x 6: a corridor (row 2) between known walls (rows 1, 3); the robot at (2, 0); four uncertain cells in a
    row in front of it, then one free unknown cell. Every ray that reaches (2, c) crossed (2, 1) .. (2, c - 1)."""
    observed = np.full((5, 6), UNKNOWN, np.int8)
    observed[[1, 3], :] = OCCUPIED
    observed[2, 0] = FREE
    mean = np.zeros((5, 6), np.float32)
    mean[2, 1:5] = [0.3, 0.6, 0.2, 0.9]
    return mean, observed


def _cross():
    """5 x 5: the robot at the centre, known walls on the four diagonal neighbours, an uncertain cell on each of
    the four others (a ray crosses at most one of them, and a cell behind one is reached only through it)."""
    observed = np.full((5, 5), UNKNOWN, np.int8)
    observed[2, 2] = FREE
    observed[[1, 1, 3, 3], [1, 3, 1, 3]] = OCCUPIED
    mean = np.zeros((5, 5), np.float32)
    mean[[1, 2, 2, 3], [2, 1, 3, 2]] = [0.3, 0.5, 0.7, 0.9]
    return mean, observed


@pytest.mark.slow
def test_single_ray_corridor_is_exact_against_brute_force():
    mean, observed = _corridor()
    exact = brute_force_expected_visible(mean, observed, (2, 0), N_RAYS, RANGE_CELLS)
    # (2, 1) is seen always, (2, 2) when (2, 1) is free, ... each cell revealed whether wall or free.
    by_hand = 1 + 0.7 + 0.7 * 0.4 + 0.7 * 0.4 * 0.8 + 0.7 * 0.4 * 0.8 * 0.1
    assert exact == pytest.approx(by_hand, abs=1e-6)  # float32 probabilities
    # Correlated cells (walls together): a ray passes a cell with probability 1 - max p over those before it, the
    # most any dependence between the cells allows: at least the independent enumeration's.
    assert _gain(mean, observed, (2, 0)) == pytest.approx(1 + 0.7 + 0.4 + 0.4 + 0.1, abs=1e-6)
    assert _gain(mean, observed, (2, 0)) > exact


def test_one_uncertain_cell_per_ray_is_exact_against_brute_force():
    mean, observed = _cross()
    exact = brute_force_expected_visible(mean, observed, (2, 2), N_RAYS, RANGE_CELLS)
    assert _gain(mean, observed, (2, 2)) == pytest.approx(exact, abs=1e-6)
    # Certain maps: the expectation is the count of unknown cells the rays reach.
    for p in (0.0, 1.0):
        binary = np.where(mean > 0, np.float32(p), mean)
        assert _gain(binary, observed, (2, 2)) == brute_force_expected_visible(binary, observed, (2, 2), N_RAYS,
                                                                                 RANGE_CELLS)


@pytest.mark.parametrize("seed", range(4))
def test_kernel_matches_its_slow_twin_on_random_maps(seed):
    rng = np.random.default_rng(seed)
    shape = tuple(int(v) for v in rng.integers(8, 20, size=2))
    observed = rng.choice(np.array([UNKNOWN, UNKNOWN, FREE, OCCUPIED], np.int8), size=shape)
    mean = (rng.random(shape) * (rng.random(shape) < 0.4)).astype(np.float32)
    mean[rng.random(shape) < 0.05] = 1.0
    variance = rng.random(shape).astype(np.float32)
    cells = [tuple(int(v) for v in rng.integers(0, shape)) for _ in range(5)]
    groups = [cells[:2], [cells[2]], [], cells[1:] + [cells[1]]]
    n_rays, max_t, cut = int(rng.integers(5, 40)) * 2 + 1, float(rng.uniform(3, 15)), [0.0, 1e-3, 0.2, 0.5][seed]
    cfg = ExpectedVisibility(n_rays=n_rays, range_m=max_t * 0.1, min_transmittance=cut)
    expected, expected_variance = expected_visible_gains(mean, observed, groups, cfg, 0.1, variance)
    ref, ref_variance = naive_expected_gain(mean, observed, groups, n_rays, max_t, cut, variance)
    np.testing.assert_allclose(expected, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(expected_variance, ref_variance, rtol=1e-6, atol=1e-6)
    assert expected[2] == 0.0


def test_viewpoint_rules_and_bad_inputs():
    mean, observed = _cross()
    observed_wall = observed.copy()
    observed_wall[2, 2] = OCCUPIED
    assert _gain(mean, observed_wall, (2, 2)) == 0.0  # nothing is seen from inside a wall
    own_unknown = observed.copy()
    own_unknown[2, 2] = UNKNOWN
    assert _gain(mean, own_unknown, (2, 2)) == pytest.approx(_gain(mean, observed, (2, 2)) + 1.0)
    cfg = ExpectedVisibility()
    with pytest.raises(ValueError, match="float32"):
        expected_visible_gains(mean.astype(np.float64), observed, [[(2, 2)]], cfg, 0.1)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        expected_visible_gains(np.full((5, 5), np.nan, np.float32), observed, [[(2, 2)]], cfg, 0.1)
    with pytest.raises(ValueError, match="outside the map"):
        expected_visible_gains(mean, observed, [[(5, 0)]], cfg, 0.1)
    with pytest.raises(ValueError, match="observed has shape"):
        expected_visible_gains(mean, observed[:4], [[(2, 2)]], cfg, 0.1)
    with pytest.raises(ValueError, match="resolution_m"):
        expected_visible_gains(mean, observed, [[(2, 2)]], cfg, 0.0)
    for bad in ({"n_rays": 2}, {"range_m": float("inf")}, {"min_transmittance": 1.0}):
        with pytest.raises(ValueError):
            ExpectedVisibility(**bad)


def _open_scene():
    """60 x 60: the robot in a known free strip (cols 25-34); to its left an unknown region that the prediction
    fills with faint walls (0.4, under the 0.5 threshold: invisible to the thresholded gain), to its right one with
    no predicted wall. Frontier cells (30, 24) and (30, 35), one step from the robot either way."""
    from superex_deploy.onboard.types import Frontier

    observed = np.full((60, 60), UNKNOWN, np.int8)
    observed[:, 25:35] = FREE
    mean = np.zeros((60, 60), np.float32)
    mean[:, :25] = 0.4
    frontiers = tuple(Frontier((30, c), np.array([[30, c]], np.int32)) for c in (24, 35))
    travel = np.full((60, 60), np.inf)
    travel[:, 25:35] = 1.0 + np.abs(np.arange(25, 35)[None, :] - 29.5)
    travel[30, 24] = travel[30, 35] = 6.0
    travel[30, 29] = travel[30, 30] = 0.0
    return observed, mean, frontiers, travel


def test_planners_with_the_expected_gain_see_through_faint_walls_but_not_behind_likely_ones():
    observed, mean, frontiers, travel = _open_scene()
    prediction = Prediction(mean, np.zeros_like(mean))
    ctx = PlanningContext(observed=observed, pose_rc=(30, 30), frontiers=frontiers, travel_cost=travel,
                          traversable=observed == FREE, resolution_m=0.1, predict=lambda: prediction,
                          rng=np.random.default_rng(0))
    # Thresholded at 0.5, both sides look equally open: the tie goes to the lower cell, the left one.
    assert SuperexPlanner(SuperexConfig(gain="goal", n_rays=61)).choose_goal(ctx) == (30, 24)
    # Expected: a ray into the left side passes its faint walls with probability 0.6 however many it crosses, so
    # the left is worth less than the right.
    for gain in ("expected", "expected_goal"):
        planner = SuperexPlanner(SuperexConfig(gain=gain, n_rays=61))
        gains = planner.gains(ctx, prediction, list(frontiers))
        assert gains[1] > gains[0]
        assert planner.choose_goal(ctx) == (30, 35)
    assert MapexPlanner(MapexConfig(gain="expected")).choose_goal(ctx) == (30, 35)


def test_defaults_are_unchanged():
    assert SuperexConfig().gain == "expected"
    assert MapexConfig().gain == "visible"
