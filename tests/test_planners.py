import numpy as np
import pytest

from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.onboard.planning.planners import (
    PLANNERS, HectorConfig, HectorPlanner, MapexConfig, MapexPlanner, NearestFrontier, UpenConfig, UpenPlanner,
    VisibilityConfig, connected_unknown_gains, grow_rrt, make_planner, predicted_visibility,
    visible_gains, visible_ranges)
from superex_deploy.onboard.planning.planners.upen import _grow_rrt
from superex_deploy.sim.oracle import OraclePredictor
from superex_deploy.onboard.planning.viewpoint_gains import union_visible_unknown
from superex_deploy.onboard.planning.visibility import _NO_STAMP, _fill_visibility, ray_visible_ranges
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Frontier, PlanningContext, Prediction
from superex_deploy.maps import OccupancyGrid
from tests.naive import naive_fill_visibility, naive_grow_rrt, naive_visible_ranges


def _frontier(r, c):
    return Frontier(cell_rc=(r, c), cells=np.array([[r, c]], np.int32))


def _context(observed, frontiers, travel_cost, prediction, pose=(20, 20), seed=0):
    return PlanningContext(observed=observed, pose_rc=pose, frontiers=tuple(frontiers),
                           travel_cost=travel_cost, traversable=observed == FREE, resolution_m=0.1,
                           predict=lambda: prediction, rng=np.random.default_rng(seed))


def _manhattan_travel(observed, pose):
    travel = np.full(observed.shape, np.inf)
    rows, cols = np.nonzero(observed == FREE)
    travel[rows, cols] = np.abs(rows - pose[0]) + np.abs(cols - pose[1])
    return travel


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
    grid = OccupancyGrid(walls, ~walls, 0.1, "corridor")
    return grid, observed, _manhattan_travel(observed, (20, 20)), [_frontier(20, 15), _frontier(20, 25)]


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


def test_probabilistic_ray_stops_at_the_hit_threshold():
    mean = np.zeros((3, 12), np.float32)
    mean[1, 2:] = 0.5
    mean[1, 6] = 0.85
    ranges = np.empty(4)  # ray 0 along +col from the centre of (1, 0); ray 1 along +row

    def ray_range(threshold, accumulate, max_t=100.0):
        ray_visible_ranges(mean, 1.5, 0.5, 4, max_t, threshold, accumulate, ranges)
        return ranges[0]

    # Per cell (MapEx as run): the first cell of probability >= 0.8 is col 6, entered at t = 5.5.
    assert ray_range(0.8, False) == 6.0
    assert ray_range(0.5, False) == 2.0  # the threshold itself blocks
    assert ray_range(0.8, False, max_t=3.0) == 3.0
    # Accumulated: 1 - 0.5^k reaches 0.875 at col 4 and 0.9375 at col 5.
    assert ray_range(0.8, True) == 4.0
    assert ray_range(0.9, True) == 5.0
    assert ranges[1] == 1.5  # down through row 2, out of the grid at t = 1.5
    mean[1, 6] = 0.0
    assert ray_range(0.8, False) == 11.5  # out of the grid at the east border
    # From inside a likely wall nothing is visible (MapEx returns an empty mask).
    mean[1, 0] = 0.85
    np.testing.assert_array_equal(visible_ranges(mean, (1, 0), VisibilityConfig(n_rays=4), 0.1), 0.0)
    assert not predicted_visibility(mean, (1, 0), VisibilityConfig(n_rays=4), 0.1).any()
    assert predicted_visibility(mean, (1, 0), VisibilityConfig(n_rays=4, hit_threshold=0.9), 0.1).any()


def _fill(ranges, observed, variance=None):
    variance = np.ones(observed.shape, np.float32) if variance is None else variance
    visible = np.zeros(observed.shape, bool)
    count, var_sum = _fill_visibility(np.asarray(ranges, float), 5.5, 5.5, observed, variance, visible, True,
                                      _NO_STAMP, -1)
    return visible, count, var_sum


def test_visible_region_is_the_filled_polygon_of_the_ray_ends():
    observed = np.full((11, 11), UNKNOWN, np.int8)
    rows, cols = np.mgrid[:11, :11]
    visible, count, var_sum = _fill([3.2] * 4, observed)  # a diamond |dr| + |dc| <= 3.2
    np.testing.assert_array_equal(visible, np.abs(rows - 5) + np.abs(cols - 5) <= 3)
    assert count == 25 and var_sum == 25.0
    observed[5, :] = FREE  # only unknown cells count
    visible, count, var_sum = _fill([3.2, 1.2, 3.2, 1.2], observed)  # |dc| / 3.2 + |dr| / 1.2 <= 1
    expected = np.zeros((11, 11), bool)
    expected[5, 2:9] = expected[4, 5] = expected[6, 5] = True
    np.testing.assert_array_equal(visible, expected)
    assert count == 2 and var_sum == 2.0
    # A room behind a door seen by one ray alone is still seen along that ray (a sector-wise minimum of the
    # ranges would drop it): 8 rays, the one pointing down (+row) reaching 5.2 cells.
    visible, _, _ = _fill([1.0, 1.0, 5.2, 1.0, 1.0, 1.0, 1.0, 1.0], observed)
    assert visible[6:11, 5].all() and not visible[7:, [4, 6]].any()
    assert _fill([0.0] * 8, observed)[1:] == (0, 0.0) and not _fill([0.0] * 8, observed)[0].any()


def test_visibility_of_a_walled_room_is_exactly_the_room():
    mean = np.ones((15, 15), np.float32)
    mean[3:9, 4:12] = 0.0
    visible = predicted_visibility(mean, (5, 6), VisibilityConfig(n_rays=720, range_m=5.0), 0.1)
    room = np.zeros_like(visible)
    room[3:9, 4:12] = True
    assert np.all(visible[room])
    # Beyond the room, only wall cells 4-adjacent to it may appear (a ray ends inside its blocking cell).
    touching = room.copy()
    touching[1:] |= room[:-1]
    touching[:-1] |= room[1:]
    touching[:, 1:] |= room[:, :-1]
    touching[:, :-1] |= room[:, 1:]
    assert not np.any(visible & ~touching)


@pytest.mark.parametrize("accumulate", [False, True])
def test_visibility_kernels_match_naive_on_random_maps(accumulate):
    rng = np.random.default_rng(3 + accumulate)
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
        ray_visible_ranges(mean, y0, x0, n_rays, max_t, threshold, accumulate, ranges)
        np.testing.assert_allclose(ranges, naive_visible_ranges(mean, y0, x0, n_rays, max_t, threshold, accumulate),
                                   atol=1e-9)
        visible = np.zeros(shape, bool)
        count, var_sum = _fill_visibility(ranges, y0, x0, observed, variance, visible, True, _NO_STAMP, -1)
        ref_visible, ref_count, ref_var = naive_fill_visibility(ranges, y0, x0, observed, variance)
        np.testing.assert_array_equal(visible, ref_visible)
        assert count == ref_count and var_sum == pytest.approx(ref_var, rel=1e-6)
        # Counting without the mask gives the same numbers.
        no_mask = np.zeros((1, 1), bool)
        assert _fill_visibility(ranges, y0, x0, observed, variance, no_mask, False, _NO_STAMP, -1) == (
            count, pytest.approx(var_sum))


def test_rrt_kernel_matches_naive_and_stays_on_passable_cells():
    rng = np.random.default_rng(5)
    passable = np.ones((30, 30), bool)
    passable[10:20, 5:25] = False
    reachable = np.zeros((30, 30), bool)
    reachable[:10, :12] = True
    variance = rng.random((30, 30)).astype(np.float32)
    samples = rng.random((200, 2)) * 30
    node_yx, parent, depth, path_var, exit_rc = (np.empty((201, 2)), np.empty(201, np.int64),
                                                 np.empty(201, np.int64), np.empty(201), np.empty((201, 2), np.int64))
    n = _grow_rrt(passable, reachable, 2.5, 2.5, samples, 4.0, variance, node_yx, parent, depth, path_var, exit_rc)
    ref_nodes, ref_parent, ref_depth, ref_var, ref_exit = naive_grow_rrt(passable, reachable, 2.5, 2.5, samples,
                                                                         4.0, variance)
    assert n > 100
    np.testing.assert_allclose(node_yx[:n], ref_nodes)
    np.testing.assert_array_equal(parent[:n], ref_parent)
    np.testing.assert_array_equal(depth[:n], ref_depth)
    np.testing.assert_allclose(path_var[:n], ref_var, rtol=1e-9)
    np.testing.assert_array_equal(exit_rc[:n], ref_exit)
    assert passable[node_yx[:n, 0].astype(int), node_yx[:n, 1].astype(int)].all()
    assert reachable[exit_rc[:n, 0], exit_rc[:n, 1]].all() and (exit_rc[:n, 1] >= 12).sum() == 0
    # The public wrapper: its path cells are the ones the variance was summed over.
    tree = grow_rrt(passable, (2, 2), 300, 4.0, np.random.default_rng(1), variance)
    for node in np.flatnonzero(tree.depth >= 3)[:10]:
        cells = tree.path_cells(node)
        assert tuple(cells[0]) == (2, 2) and tuple(cells[-1]) == tuple(np.floor(tree.nodes_yx[node]).astype(int))
        assert tree.path_variance[node] == pytest.approx(variance[cells[1:, 0], cells[1:, 1]].sum(dtype=float))
        assert tuple(tree.exit_rc[node]) == tuple(cells[-1])  # everything reachable: the node's own cell
    with pytest.raises(ValueError, match="not passable"):
        grow_rrt(passable, (15, 15), 10, 4.0, rng)
    with pytest.raises(ValueError, match="variance must be"):
        grow_rrt(passable, (2, 2), 10, 4.0, rng, variance.astype(np.float64))


def test_hector_and_mapex_prefer_the_frontier_facing_the_larger_unknown_area():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=False)
    prediction = OraclePredictor(grid).predict(observed)
    ctx = _context(observed, frontiers, travel, prediction)
    counts, _ = visible_gains(prediction, observed, [(20, 15), (20, 25)], VisibilityConfig(), 0.1)
    assert counts[0] > 2 * counts[1] > 0
    assert HectorPlanner().choose_goal(ctx) == (20, 15)
    assert MapexPlanner().choose_goal(ctx) == (20, 15)  # zero variance: counts the visible unknown cells
    # Mirror the scene: the preference follows the big room, not a fixed side.
    mirrored = _context(observed[:, ::-1].copy(), [_frontier(20, 15), _frontier(20, 25)], travel[:, ::-1].copy(),
                        Prediction(prediction.mean[:, ::-1].copy(), prediction.variance[:, ::-1].copy()))
    assert HectorPlanner().choose_goal(mirrored) == (20, 25)
    assert MapexPlanner().choose_goal(mirrored) == (20, 25)
    # The info-gain term is worth floor(200 * (sqrt(IG max) - sqrt(IG))) (MapEx's int()): a detour longer than
    # that outweighs it, a shorter one does not.
    seed_gap = 200 * (np.sqrt(counts[0]) - np.sqrt(counts[1]))
    assert seed_gap % 1 > 0.1  # so that the truncation matters below
    for extra, expected in ((-0.5, (20, 15)), (0.5 * (seed_gap % 1), (20, 25)), (1.0, (20, 25))):
        travel[20, 15] = 5 + np.floor(seed_gap) + extra
        assert HectorPlanner().choose_goal(_context(observed, frontiers, travel, prediction)) == expected


def test_hector_as_coded_in_mapex_counts_the_connected_predicted_free_region():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=False)
    mean = OraclePredictor(grid).predict(observed).mean
    # Both frontiers open onto the same predicted-free region through the known corridor: equal IG, the
    # unknown cells of the left room (13 x 39) and of the closet (3 x 2), so the nearer frontier wins.
    gains = connected_unknown_gains(mean, observed, [(20, 15), (20, 25), (0, 0), (5, 27)])
    np.testing.assert_array_equal(gains, [13 * 39 + 3 * 2, 13 * 39 + 3 * 2, 0, 16 * 2])  # (0, 0): a wall;
    # (5, 27): a sealed pocket of 16 x 2 cells beside the closet.
    travel[20, 25] = 4
    planner = HectorPlanner(HectorConfig(visibility=None))
    assert planner.choose_goal(_context(observed, frontiers, travel, Prediction(mean, np.zeros_like(mean)))) \
        == (20, 25)
    # A predicted wall across the closet's mouth leaves it its own 3 x 2 unknown cells; values up to the
    # threshold (0.5) count as free.
    sealed = mean.copy()
    sealed[19:22, 26] = 0.6
    assert connected_unknown_gains(sealed, observed, [(20, 27), (20, 15)]).tolist() == [6, 13 * 39]
    sealed[19:22, 26] = 0.5
    assert connected_unknown_gains(sealed, observed, [(20, 27)]).tolist() == [13 * 39 + 6]


def test_mapex_prefers_high_variance_unknown_regions():
    grid, observed, travel, frontiers = _corridor_scene(right_room_big=True)
    mean = OraclePredictor(grid).predict(observed).mean
    variance = np.zeros(grid.shape, np.float32)
    variance[:, 30:] = 0.2
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance))
    assert MapexPlanner().choose_goal(ctx) == (20, 25)
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance[:, ::-1].copy()))
    assert MapexPlanner().choose_goal(ctx) == (20, 15)
    # Variance on known cells is worthless: only unknown cells count.
    variance = np.zeros(grid.shape, np.float32)
    variance[observed != UNKNOWN] = 1.0
    variance[:, 30:] = 0.01
    ctx = _context(observed, frontiers, travel, Prediction(mean, variance))
    assert MapexPlanner().choose_goal(ctx) == (20, 25)
    # Score = visible variance / travel cost: doubling one frontier's cost halves its score exactly.
    frontiers_out, costs, scores = MapexPlanner().score(ctx)
    travel[20, 25] *= 2
    _, _, halved = MapexPlanner().score(_context(observed, frontiers, travel, Prediction(mean, variance)))
    assert [f.cell_rc for f in frontiers_out] == [(20, 15), (20, 25)]
    assert halved[1] == pytest.approx(scores[1] / 2) and halved[0] == scores[0]
    # MapEx's own divisor: the straight-line distance from the robot, whatever the travel cost.
    euclidean = MapexPlanner(MapexConfig(distance="euclidean"))
    information = euclidean.information(Prediction(mean, variance), observed, [(20, 15), (20, 25)], 0.1)
    _, _, straight = euclidean.score(_context(observed, frontiers, travel, Prediction(mean, variance)))
    np.testing.assert_allclose(straight, information / 5.0)  # both frontiers 5 cells from (20, 20)
    travel[20, 15] *= 7  # a detour: the travel divisor changes, the straight line does not
    _, _, detoured = euclidean.score(_context(observed, frontiers, travel, Prediction(mean, variance)))
    np.testing.assert_array_equal(detoured, straight)
    with pytest.raises(ValueError, match="distance"):
        MapexConfig(distance="manhattan")


def _long_corridor():
    """41 x 81: a known corridor (rows 18-22, cols 10-70) between two unknown rooms; the robot at (20, 40)."""
    walls = np.zeros((41, 81), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:18, 10:71] = walls[23:, 10:71] = True
    observed = np.full(walls.shape, UNKNOWN, np.int8)
    observed[17:24, 10:71] = np.where(walls[17:24, 10:71], OCCUPIED, FREE)
    return observed, _manhattan_travel(observed, (20, 40))


def test_upen_heads_for_the_uncertain_room_deterministically():
    observed, travel = _long_corridor()
    frontiers = [_frontier(20, 10), _frontier(20, 70)]
    variance = np.zeros(observed.shape, np.float32)
    variance[:, 71:] = 0.3  # the right room is uncertain
    prediction = Prediction(np.zeros(observed.shape, np.float32), variance)
    # No frontiers offered: the nearest-frontier fall-back would return None, so these goals are UPEN's own.
    goals = [UpenPlanner().choose_goal(_context(observed, [], travel, prediction, (20, 40), seed=11))
             for _ in range(2)]
    assert goals[0] == goals[1]
    # The goal is where the best path leaves the known corridor on the right: reachable, at its east end.
    assert np.isfinite(travel[goals[0]]) and goals[0][1] >= 66
    prediction = Prediction(prediction.mean, variance[:, ::-1].copy())
    goal = UpenPlanner().choose_goal(_context(observed, [], travel, prediction, (20, 40), seed=11))
    assert np.isfinite(travel[goal]) and goal[1] <= 14
    # Zero variance: UPEN has no signal and falls back to the nearest frontier.
    flat = Prediction(prediction.mean, np.zeros(observed.shape, np.float32))
    travel[20, 70] = 5
    ctx = _context(observed, frontiers, travel, flat, (20, 40))
    assert UpenPlanner().choose_goal(ctx) == NearestFrontier().choose_goal(ctx) == (20, 70)


def test_upen_never_returns_unreachable_or_too_close_goals():
    observed, travel = _long_corridor()
    rng = np.random.default_rng(0)
    goals = set()
    for seed in range(8):
        variance = (rng.random(observed.shape) * (rng.random(observed.shape) < 0.2)).astype(np.float32)
        ctx = _context(observed, [], travel, Prediction(np.zeros_like(variance), variance), (20, 40), seed)
        goal = UpenPlanner(UpenConfig(rrt_samples=400)).choose_goal(ctx)
        assert goal is not None and np.isfinite(travel[goal]) and np.hypot(goal[0] - 20, goal[1] - 40) > 10
        goals.add(goal)
    assert len(goals) > 1  # the seeds and variance maps do steer it


def _closet_and_hall():
    """5 x 14 m: a corridor (rows 30-48) below a wall with two 1 m doors: the west one, nearer the start, opens
    onto a 4 x 3 m closet, the east one onto a 10 x 3 m hall."""
    walls = np.zeros((50, 140), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[29, :] = True
    walls[29, 10:20] = walls[29, 100:110] = False
    walls[:29, 40] = True
    return OccupancyGrid(walls, ~walls, 0.1, "closet and hall")


def test_with_the_oracle_information_gain_covers_more_than_nearest_frontier():
    grid = _closet_and_hall()
    oracle = OraclePredictor(grid)
    nearest = run_episode(grid, (40, 50), NearestFrontier(), oracle, steps=40, seed=0)
    assert nearest.goals[0][1] < 40  # the closet first: its door is nearer
    for planner in (MapexPlanner(), HectorPlanner()):
        informed = run_episode(grid, (40, 50), planner, oracle, steps=40, seed=0)
        assert informed.steps == nearest.steps == 40
        assert informed.goals[0][1] > 40  # the hall first: far more to see per unit of travel
        assert informed.coverage[-1] > nearest.coverage[-1] + 0.1
        assert informed.coverage.sum() > nearest.coverage.sum()  # area under the coverage curve


def test_registry_and_bad_inputs():
    assert set(PLANNERS) == {"nearest", "hector", "upen", "mapex", "superex"}
    assert all(make_planner(name).name == name for name in PLANNERS)
    assert make_planner("upen", rrt_samples=10).cfg.rrt_samples == 10
    with pytest.raises(ValueError,
                       match="unknown planner 'frontier'; choose one of hector, mapex, nearest, superex, upen"):
        make_planner("frontier")
    with pytest.raises(ValueError, match="bad configuration"):
        make_planner("mapex", no_such_field=1)
    with pytest.raises(ValueError, match="takes no configuration"):
        make_planner("nearest", weight=2)
    with pytest.raises(ValueError, match="rrt_samples"):
        make_planner("upen", rrt_samples=0)
    with pytest.raises(ValueError, match="hit_threshold"):
        VisibilityConfig(hit_threshold=0.0)
    with pytest.raises(ValueError, match="n_rays"):
        VisibilityConfig(n_rays=2)
    mean = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match="outside the map"):
        predicted_visibility(mean, (4, 0), VisibilityConfig(), 0.1)
    with pytest.raises(ValueError, match="float32"):
        visible_gains(Prediction(mean.astype(np.float64), mean), np.zeros((4, 4), np.int8), [(0, 0)],
                      VisibilityConfig(), 0.1)
    with pytest.raises(ValueError, match="observed has shape"):
        connected_unknown_gains(mean, np.zeros((4, 5), np.int8), [(0, 0)])


def test_union_of_views_counts_each_unknown_cell_once_per_group():
    rng = np.random.default_rng(11)
    mean = (rng.random((40, 50)) < 0.08).astype(np.float32)
    observed = rng.integers(-1, 2, size=(40, 50)).astype(np.int8)
    cfg = VisibilityConfig(n_rays=64, range_m=1.5)
    groups = [[(5, 5), (20, 25), (5, 5)], [(30, 40)], [], [(20, 25), (35, 10)]]
    counts = union_visible_unknown(mean, observed, groups, cfg, 0.1)
    for group, count in zip(groups, counts):
        seen = np.zeros(mean.shape, bool)
        for cell in group:
            seen |= predicted_visibility(mean, cell, cfg, 0.1)
        assert count == np.count_nonzero(seen & (observed == UNKNOWN))
    assert counts[2] == 0
    with pytest.raises(ValueError, match="outside the map"):
        union_visible_unknown(mean, observed, [[(40, 0)]], cfg, 0.1)


def test_register_planner_adds_a_planner_by_name_and_refuses_what_it_cannot_build():
    from dataclasses import dataclass

    from superex_deploy.onboard.planning.planners import PLANNERS, make_planner, planner_config, register_planner
    from superex_deploy.onboard.types import Planner

    @dataclass(frozen=True)
    class FirstConfig:
        reach_m: float = 1.0

    class First(Planner):
        name = "first-test"

        def __init__(self, cfg=FirstConfig()):
            self.cfg = cfg

        def choose_goal(self, ctx):
            return None

    saved = dict(PLANNERS)
    try:
        assert register_planner(First, FirstConfig) is First
        assert planner_config("first-test") is FirstConfig
        assert make_planner("first-test", reach_m=2.5).cfg == FirstConfig(2.5)
        with pytest.raises(ValueError, match="a planner named 'first-test' is registered already"):
            register_planner(First)
        with pytest.raises(ValueError, match="a planner must be a subclass of"):
            register_planner(FirstConfig)
        nameless = type("Nameless", (First,), {"name": ""})
        with pytest.raises(ValueError, match="Nameless needs a class attribute name"):
            register_planner(nameless)
        renamed = type("Renamed", (First,), {"name": "renamed-test"})
        with pytest.raises(ValueError, match="config_class must be a dataclass or None"):
            register_planner(renamed, dict)
        assert "renamed-test" not in PLANNERS
    finally:
        PLANNERS.clear()
        PLANNERS.update(saved)
