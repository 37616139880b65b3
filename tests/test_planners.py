import numpy as np
import pytest

from superex_deploy.explore.planners import (
    PLANNERS, HectorPlanner, MapexPlanner, NearestFrontier, UpenPlanner, VisibilityConfig, _fill_visibility,
    _grow_rrt, _ray_visible_ranges, grow_rrt, make_planner, predicted_visibility, visible_gains)
from superex_deploy.explore.prediction import OraclePredictor
from superex_deploy.explore.types import FREE, OCCUPIED, UNKNOWN, Frontier, PlanningContext, Prediction
from superex_deploy.maps import OccupancyGrid
from tests.naive import naive_fill_visibility, naive_grow_rrt, naive_visible_ranges


def _frontier(r, c):
    return Frontier(cell_rc=(r, c), cells=np.array([[r, c]], np.int32))


def _context(observed, frontiers, travel_cost, prediction, pose=(20, 20), seed=0):
    return PlanningContext(observed=observed, pose_rc=pose, frontiers=tuple(frontiers),
                           travel_cost=travel_cost, traversable=observed == FREE, resolution_m=0.1,
                           predict=lambda: prediction, rng=np.random.default_rng(seed))


def _corridor_scene(right_room_big):
    """41x41 world: a known corridor (rows 18-22, cols 15-25) between a big unknown room on the left and, on the
    right, either a big room or a 3x3 closet. Frontier cells at (20, 15) and (20, 25), 5 cells from the robot."""
    walls = np.zeros((41, 41), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:17, 14:27] = walls[24:, 14:27] = True  # corridor walls
    if not right_room_big:
        walls[:, 29:] = True
        walls[17:19, 26:29] = walls[22:24, 26:29] = True
    observed = np.full(walls.shape, UNKNOWN, np.int8)
    observed[17:24, 14:27] = np.where(walls[17:24, 14:27], OCCUPIED, FREE)
    travel = np.full(walls.shape, np.inf)
    rows, cols = np.nonzero(observed == FREE)
    travel[rows, cols] = np.abs(cols - 20) + np.abs(rows - 20)
    grid = OccupancyGrid(walls, ~walls, 0.1, "corridor")
    return grid, observed, travel, [_frontier(20, 15), _frontier(20, 25)]


def test_nearest_picks_least_travel_cost_and_skips_unreachable():
    observed = np.zeros((10, 10), np.int8)
    travel = np.arange(100, dtype=float).reshape(10, 10)
    travel[1, 1] = np.inf
    frontiers = [_frontier(5, 5), _frontier(1, 1), _frontier(2, 3)]
    ctx = _context(observed, frontiers, travel, None, pose=(0, 0))
    assert NearestFrontier().choose_goal(ctx) == (2, 3)
    travel[2, 3] = np.inf
    assert NearestFrontier().choose_goal(ctx) == (5, 5)
    travel[5, 5] = np.inf
    assert NearestFrontier().choose_goal(ctx) is None
    assert NearestFrontier().choose_goal(_context(observed, [], travel, None)) is None


def test_probabilistic_ray_stops_when_blocking_probability_reaches_threshold():
    mean = np.zeros((3, 12), np.float32)
    mean[1, 2:] = 0.5  # accumulated blocking 0.5, 0.75, 0.875: the third such cell (col 4) stops the ray
    ranges = np.empty(4)
    _ray_visible_ranges(mean, 1.5, 0.5, 4, 100.0, 0.8, ranges)
    assert ranges[0] == pytest.approx(4.0)  # enters col 4 at t = 3.5, stops at its centre
    _ray_visible_ranges(mean, 1.5, 0.5, 4, 100.0, 0.9, ranges)
    assert ranges[0] == pytest.approx(5.0)  # 0.9375 only at col 5
    mean[1, 0] = 0.85  # a viewpoint inside a likely wall sees only its own cell
    _ray_visible_ranges(mean, 1.5, 0.5, 4, 100.0, 0.8, ranges)
    np.testing.assert_allclose(ranges, 0.5)


def test_visibility_of_a_walled_room_is_exactly_the_room():
    mean = np.ones((15, 15), np.float32)
    mean[3:9, 4:12] = 0.0
    visible = predicted_visibility(mean, (5, 6), VisibilityConfig(n_rays=720, range_m=5.0), 0.1)
    expected = np.zeros_like(visible)
    expected[3:9, 4:12] = True
    assert np.all(visible[expected])
    # Beyond the room, only wall cells 4-adjacent to it may appear (a ray stops at its blocking cell's centre).
    touching = expected.copy()
    touching[1:] |= expected[:-1]
    touching[:-1] |= expected[1:]
    touching[:, 1:] |= expected[:, :-1]
    touching[:, :-1] |= expected[:, 1:]
    assert not np.any(visible & ~touching)


def test_visibility_kernels_match_naive_on_random_maps():
    rng = np.random.default_rng(3)
    for _ in range(12):
        shape = tuple(rng.integers(5, 18, size=2))
        mean = (rng.random(shape) * (rng.random(shape) < 0.3)).astype(np.float32)
        observed = rng.integers(-1, 2, size=shape).astype(np.int8)
        variance = rng.random(shape).astype(np.float32)
        # Off-centre origins: from a cell centre, 45-degree rays pass exactly through corners, where float
        # rounding (sin(pi/4) != cos(pi/4)) rather than geometry decides which neighbour is entered.
        y0, x0 = rng.uniform(0, shape[0]), rng.uniform(0, shape[1])
        n_rays, max_t, threshold = int(rng.integers(8, 40)), float(rng.uniform(2, 20)), float(rng.uniform(0.3, 1))
        ranges = np.empty(n_rays)
        _ray_visible_ranges(mean, y0, x0, n_rays, max_t, threshold, ranges)
        np.testing.assert_allclose(ranges, naive_visible_ranges(mean, y0, x0, n_rays, max_t, threshold), atol=1e-9)
        visible = np.zeros(shape, bool)
        count, var_sum = _fill_visibility(ranges, y0, x0, shape[0], shape[1], observed, variance, visible, True)
        ref_visible, ref_count, ref_var = naive_fill_visibility(ranges, y0, x0, observed, variance)
        np.testing.assert_array_equal(visible, ref_visible)
        assert count == ref_count and var_sum == pytest.approx(ref_var, rel=1e-6)


def test_rrt_kernel_matches_naive_and_stays_on_traversable_cells():
    rng = np.random.default_rng(5)
    traversable = np.ones((30, 30), bool)
    traversable[10:20, 5:25] = False
    samples = rng.random((200, 2)) * 30
    node_yx = np.empty((201, 2))
    parent = np.empty(201, np.int64)
    depth = np.empty(201, np.int64)
    n = _grow_rrt(traversable, 2.5, 2.5, samples, 4.0, node_yx, parent, depth)
    ref_nodes, ref_parent, ref_depth = naive_grow_rrt(traversable, 2.5, 2.5, samples, 4.0)
    np.testing.assert_allclose(node_yx[:n], ref_nodes)
    np.testing.assert_array_equal(parent[:n], ref_parent)
    np.testing.assert_array_equal(depth[:n], ref_depth)
    assert traversable[node_yx[:n, 0].astype(int), node_yx[:n, 1].astype(int)].all()
    with pytest.raises(ValueError, match="not traversable"):
        grow_rrt(traversable, (15, 15), 10, 4.0, rng)


def test_hector_and_mapex_prefer_the_frontier_facing_the_larger_unknown_area():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=False)
    prediction = OraclePredictor(grid).predict(observed)
    ctx = _context(observed, frontiers, travel, prediction)
    counts, _ = visible_gains(prediction.mean, prediction.variance, observed, [(20, 15), (20, 25)],
                              VisibilityConfig(), 0.1)
    assert counts[0] > 2 * counts[1] > 0
    assert HectorPlanner().choose_goal(ctx) == (20, 15)
    assert MapexPlanner().choose_goal(ctx) == (20, 15)  # zero variance: falls back to visible unknown cells
    # Mirror the scene: the preference must follow the big room, not a fixed side.
    mirrored = _context(observed[:, ::-1].copy(), [_frontier(20, 15), _frontier(20, 25)], travel[:, ::-1].copy(),
                        Prediction(prediction.mean[:, ::-1].copy(), prediction.variance[:, ::-1].copy()))
    assert HectorPlanner().choose_goal(mirrored) == (20, 25)
    assert MapexPlanner().choose_goal(mirrored) == (20, 25)


def test_mapex_prefers_high_variance_unknown_regions():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=True)
    mean = OraclePredictor(grid).predict(observed).mean
    variance = np.zeros(grid.shape, np.float32)
    variance[:, 30:] = 0.2
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance))
    assert MapexPlanner().choose_goal(ctx) == (20, 25)
    variance = variance[:, ::-1].copy()
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance))
    assert MapexPlanner().choose_goal(ctx) == (20, 15)
    # Variance on known cells is worthless: only unknown cells count.
    variance = np.zeros(grid.shape, np.float32)
    variance[observed != UNKNOWN] = 1.0
    variance[:, 30:] = 0.01
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance))
    assert MapexPlanner().choose_goal(ctx) == (20, 25)


def test_upen_is_deterministic_and_returns_reachable_goals():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=True)
    observed[17:24, 14:27] = FREE
    observed[1:40, 1:14] = FREE  # a known left room for the tree to grow in
    rows, cols = np.nonzero(observed == FREE)
    travel = np.full(grid.shape, np.inf)
    travel[rows, cols] = np.hypot(rows - 20, cols - 20)
    variance = np.zeros(grid.shape, np.float32)
    variance[1:8, 1:14] = 0.3  # uncertain top of the left room
    prediction = Prediction(np.zeros(grid.shape, np.float32), variance)
    goals = [UpenPlanner().choose_goal(_context(observed, frontiers, travel, prediction, seed=11)) for _ in range(2)]
    assert goals[0] == goals[1]
    assert np.isfinite(travel[goals[0]]) and goals[0][0] < 14
    # Zero variance: UPEN has no signal and documents its fall back to the nearest frontier.
    flat = Prediction(np.zeros(grid.shape, np.float32), np.zeros(grid.shape, np.float32))
    ctx = _context(observed, frontiers, travel, flat)
    assert UpenPlanner().choose_goal(ctx) == NearestFrontier().choose_goal(ctx)


def test_registry_and_bad_inputs():
    assert set(PLANNERS) == {"nearest", "hector", "upen", "mapex"}
    assert make_planner("mapex").name == "mapex"
    assert make_planner("upen", rrt_samples=10).cfg.rrt_samples == 10
    with pytest.raises(ValueError, match="unknown planner 'frontier'; choose one of hector, mapex, nearest, upen"):
        make_planner("frontier")
    with pytest.raises(ValueError, match="bad configuration"):
        make_planner("mapex", no_such_field=1)
    with pytest.raises(ValueError, match="takes no configuration"):
        make_planner("nearest", weight=2)
    with pytest.raises(ValueError, match="hit_threshold"):
        VisibilityConfig(hit_threshold=0.0)
    mean = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match="outside the map"):
        predicted_visibility(mean, (4, 0), VisibilityConfig(), 0.1)
    with pytest.raises(ValueError, match="float32"):
        visible_gains(mean.astype(np.float64), mean, np.zeros((4, 4), np.int8), [(0, 0)], VisibilityConfig(), 0.1)
