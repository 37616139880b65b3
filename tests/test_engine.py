import numpy as np
import pytest

from superex_deploy.sim.episode import run_episode
from superex_deploy.onboard.planning.frontiers import find_frontiers, frontier_cells
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.sim.metrics import coverage
from superex_deploy.sim.world import LidarConfig, World, WorldConfig
from superex_deploy.sim.metrics import map_iou, paired_differences, summarise
from superex_deploy.onboard.planning.motion import MotionConfig, planning_map
from superex_deploy.onboard.planning.planners import MapexPlanner, NearestFrontier, make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.oracle import OraclePredictor
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.maps import OccupancyGrid, load_map, start_poses


def _observed(rows):
    codes = {".": FREE, "#": OCCUPIED, "?": UNKNOWN}
    return np.array([[codes[ch] for ch in row] for row in rows], np.int8)


def test_frontiers_on_a_hand_built_map():
    observed = _observed([
        "#############",
        "#.....?????..",
        "#.....?????..",
        "#............",
        "#############",
    ])
    cells = frontier_cells(observed)
    expected = {(1, 5), (2, 5), (3, 6), (3, 7), (3, 8), (3, 9), (3, 10), (1, 11), (2, 11)}
    assert set(map(tuple, np.argwhere(cells).tolist())) == expected
    (region,) = find_frontiers(observed, min_cells=9)
    assert region.size == 9
    assert region.cell_rc == (3, 8)  # nearest to the centroid (2.33, 8.0)
    assert find_frontiers(observed, min_cells=10) == ()


def test_separate_frontier_regions_are_ordered_and_filtered():
    observed = np.full((12, 12), FREE, np.int8)
    observed[0:3, 0:3] = UNKNOWN     # frontier: 3 + 3 cells along two sides (diagonal neighbours do not count)
    observed[8:12, 8:12] = UNKNOWN   # 4 + 4 cells
    regions = find_frontiers(observed, min_cells=1)
    assert [r.size for r in regions] == [6, 8]
    assert [r.size for r in find_frontiers(observed, min_cells=7)] == [8]


def test_cost_to_go_and_path_on_a_hand_built_map():
    observed = _observed([
        "...........",
        "...........",
        "#########..",
        "...........",
        "...........",
    ])
    cfg = MotionConfig(robot_radius_m=0.0, wall_cost_weight=0.0)
    plan = planning_map(observed, (0, 0), 0.1, cfg)
    assert plan.travel_cost[0, 9] == pytest.approx(9.0)
    # Diagonal to (1, 1), 7 right to (1, 8), diagonals past the wall's end to (2, 9) and (3, 8), 8 left.
    assert plan.travel_cost[3, 0] == pytest.approx(15 + 3 * np.sqrt(2), abs=1e-9)
    path = plan.path_to((3, 0))
    assert path[0] == (0, 0) and path[-1] == (3, 0)
    assert all(observed[cell] == FREE for cell in path)
    assert all(max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1 for a, b in zip(path, path[1:]))
    closed = observed.copy()
    closed[2, 9:] = OCCUPIED
    assert planning_map(closed, (0, 0), 0.1, cfg).path_to((3, 0)) == []


def test_inflation_and_wall_cost():
    observed = np.full((9, 9), FREE, np.int8)
    observed[:, 4] = OCCUPIED
    observed[4, 4] = FREE  # a one-cell door
    tight = planning_map(observed, (4, 0), 0.1, MotionConfig(robot_radius_m=0.15))
    assert not np.isfinite(tight.travel_cost[4, 8])  # the door is narrower than the robot
    loose = planning_map(observed, (4, 0), 0.1, MotionConfig(robot_radius_m=0.0))
    assert np.isfinite(loose.travel_cost[4, 8])
    flat = planning_map(observed, (4, 0), 0.1, MotionConfig(robot_radius_m=0.0, wall_cost_weight=0.0))
    assert loose.travel_cost[4, 8] > flat.travel_cost[4, 8] == pytest.approx(8.0)


def test_mapper_scans_and_carving_are_separate():
    walls = np.zeros((20, 20), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[1:19, 10] = True
    grid = OccupancyGrid(walls, ~walls, 0.1, "rooms")
    mapper = Mapper(grid.shape)
    world = World(grid, (10, 5), WorldConfig(lidar=LidarConfig(n_rays=360, range_m=5.0)))
    observation = world.observe()
    mapper.integrate_scan(world.frame, observation.pose, observation.scan)
    observed = mapper.observed()
    assert np.all(observed[1:19, 1:10] == FREE) and np.all(observed[1:19, 11:19] == UNKNOWN)
    assert np.all(observed[5:15, 10] == OCCUPIED)
    before = coverage(mapper.known(), grid.valid)
    carved = np.zeros(grid.shape, bool)
    carved[5:8, 12:15] = True
    carved[6, 10] = True  # never overrides an observed wall
    mapper.merge_carved(carved)
    assert coverage(mapper.known(include_carved=False), grid.valid) == before
    assert coverage(mapper.known(), grid.valid) > before
    assert mapper.observed()[6, 10] == OCCUPIED and mapper.observed()[6, 13] == FREE
    assert mapper.observed(include_carved=False)[6, 13] == UNKNOWN


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


@pytest.fixture(scope="module")
def small_map():
    return load_map("50052750")


def test_episode_coverage_never_decreases_and_is_deterministic(small_map):
    start = start_poses("50052750")[1]
    runs = [run_episode(small_map, start, make_planner("nearest"), ObservedAsPrediction(), steps=80, seed=3)
            for _ in range(2)]
    a, b = runs
    assert np.all(np.diff(a.coverage) >= 0) and np.all(np.diff(a.coverage_with_carving) >= 0)
    assert np.all(np.diff(a.path_length_m) >= 0) and a.path_length_m[-1] > 5.0
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.coverage, b.coverage)
    assert a.goals == b.goals
    assert not small_map.occupied[a.poses[:, 0], a.poses[:, 1]].any()
    # Each step moves at most step_cells (0.3 m along 8-connected cells).
    assert np.all(np.diff(np.r_[0.0, a.path_length_m]) <= 3 * np.sqrt(2) * 0.1 + 1e-9)


def test_mapex_with_the_oracle_covers_more_than_nearest_frontier(small_map):
    start = start_poses("50052750")[0]
    oracle = OraclePredictor(small_map)
    nearest = run_episode(small_map, start, NearestFrontier(), oracle, steps=150, seed=0)
    mapex = run_episode(small_map, start, MapexPlanner(), oracle, steps=150, seed=0)
    assert mapex.coverage[-1] > nearest.coverage[-1]
    assert mapex.coverage.sum() > nearest.coverage.sum()  # area under the coverage curve


def test_episode_finishes_when_everything_is_known():
    walls = np.zeros((12, 12), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    grid = OccupancyGrid(walls, ~walls, 0.1, "box")
    result = run_episode(grid, (6, 6), NearestFrontier(), ObservedAsPrediction(), steps=50)
    assert result.finished and result.coverage[-1] == 1.0
    summary = summarise([result.to_json()])
    assert summary[0]["planner"] == "nearest"


def test_bad_inputs(small_map):
    with pytest.raises(ValueError, match="inside a wall"):
        run_episode(small_map, tuple(np.argwhere(small_map.occupied)[0]), NearestFrontier(), ObservedAsPrediction())
    with pytest.raises(ValueError, match="outside"):
        run_episode(small_map, (-1, 0), NearestFrontier(), ObservedAsPrediction())
    with pytest.raises(ValueError, match="Planner"):
        run_episode(small_map, start_poses("50052750")[0], "nearest", ObservedAsPrediction())
    with pytest.raises(ValueError, match="steps"):
        run_episode(small_map, start_poses("50052750")[0], NearestFrontier(), ObservedAsPrediction(), steps=0)
    with pytest.raises(ValueError, match="min_cells"):
        find_frontiers(np.zeros((3, 3), np.int8), min_cells=0)
    with pytest.raises(ValueError, match="MotionConfig"):
        MotionConfig(step_cells=0)
    with pytest.raises(ValueError, match="unknown planner"):
        make_planner("frontier")


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
