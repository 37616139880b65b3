import numpy as np
import pytest
from scipy import ndimage

from superex_deploy.onboard.planning.motion import MotionConfig, dijkstra, path_is_clear, planning_map, wall_distance
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.sim.world import advance
from tests.naive import naive_planning_costs, naive_travel_cost


def _random_observed(rng, shape=(13, 17)):
    observed = rng.choice(np.array([FREE, UNKNOWN, OCCUPIED], np.int8), size=shape, p=[0.7, 0.15, 0.15])
    # In an episode every observed wall is 4-adjacent to a cell a ray crossed, so the known free cells' bounding
    # box (plus the one-cell margin motion.planning_map searches over) holds every wall; free corners reproduce
    # that here.
    observed[0, 0] = observed[-1, -1] = FREE
    return observed


@pytest.mark.parametrize("cfg", [MotionConfig(), MotionConfig(robot_radius_m=0.0, wall_cost_weight=3.0,
                                                              wall_cost_range_m=0.5)])
def test_travel_cost_matches_a_cell_by_cell_dijkstra(cfg):
    rng = np.random.default_rng(11)
    for _ in range(25):
        observed = _random_observed(rng)
        free = np.argwhere(observed == FREE)
        pose = tuple(int(v) for v in free[rng.integers(len(free))])
        plan = planning_map(observed, pose, 0.1, cfg)
        costs = naive_planning_costs(observed, pose, 0.1, cfg.robot_radius_m, cfg.wall_cost_weight,
                                     cfg.wall_cost_range_m)
        np.testing.assert_array_equal(plan.traversable, np.isfinite(costs))
        np.testing.assert_allclose(plan.travel_cost, naive_travel_cost(costs, pose), rtol=1e-12, atol=1e-12)


def test_paths_are_connected_traversable_and_cost_what_the_cost_to_go_says():
    rng = np.random.default_rng(5)
    cfg = MotionConfig()
    checked = 0
    for _ in range(25):
        observed = _random_observed(rng)
        free = np.argwhere(observed == FREE)
        pose = tuple(int(v) for v in free[rng.integers(len(free))])
        plan = planning_map(observed, pose, 0.1, cfg)
        costs = naive_planning_costs(observed, pose, 0.1, cfg.robot_radius_m, cfg.wall_cost_weight,
                                     cfg.wall_cost_range_m)
        for goal in map(tuple, np.argwhere(np.isfinite(plan.travel_cost))[:8]):
            path = plan.path_to(goal)
            assert path[0] == pose and path[-1] == goal
            steps = np.diff(np.asarray(path), axis=0)
            assert np.all(np.abs(steps).max(axis=1) == 1)
            assert all(plan.traversable[cell] for cell in path)
            length = sum(0.5 * (costs[a] + costs[b]) * np.hypot(b[0] - a[0], b[1] - a[1])
                         for a, b in zip(path, path[1:]))
            assert length == pytest.approx(plan.travel_cost[goal], rel=1e-12, abs=1e-12)
            checked += 1
        for goal in map(tuple, np.argwhere(~np.isfinite(plan.travel_cost))[:4]):
            assert plan.path_to(goal) == []
    assert checked >= 100  # not vacuous: most random scenes have at least 8 reachable cells
    assert plan.path_to((-1, 0)) == [] and plan.path_to((0, 10_000)) == []


def test_start_cell_inside_the_inflation_stays_traversable():
    observed = np.full((7, 9), FREE, np.int8)
    observed[3, 5] = OCCUPIED  # a wall seen next to the robot: its cell is inside the 0.15 m inflation
    plan = planning_map(observed, (3, 4), 0.1, MotionConfig())
    assert plan.traversable[3, 4] and plan.travel_cost[3, 4] == 0.0
    assert not plan.traversable[2, 4] and not plan.traversable[4, 6]  # inflated cells
    assert np.isfinite(plan.travel_cost[3, 0])  # the robot can leave (through (3,3) or diagonals away)
    assert plan.path_to((3, 0))[:2] == [(3, 4), (3, 3)]


def test_unknown_cells_are_not_traversable_and_not_inflated():
    observed = np.full((5, 9), FREE, np.int8)
    observed[:, 6:] = UNKNOWN
    plan = planning_map(observed, (2, 0), 0.1, MotionConfig())
    assert plan.traversable[:, :6].all() and not plan.traversable[:, 6:].any()
    assert np.isfinite(plan.travel_cost[2, 5])  # a frontier cell next to the unknown is reachable
    # Without walls the proximity cost is 1 everywhere: the cost-to-go is the 8-connected (octile) distance.
    assert plan.travel_cost[0, 5] == pytest.approx(3 + 2 * np.sqrt(2))


def test_path_is_clear_uses_the_planning_map_rule():
    observed = np.full((9, 9), FREE, np.int8)
    path = [(4, c) for c in range(1, 8)]
    assert path_is_clear(observed, path, 1.5) and path_is_clear(observed, [], 1.5)
    blocked = observed.copy()
    blocked[5, 7] = OCCUPIED  # diagonal neighbour of the path's last cell: within 1.5 cells
    assert not path_is_clear(blocked, path, 1.5)
    assert path_is_clear(blocked, path, 0.9)  # a 0.9-cell radius only reaches 4-neighbours... none is a wall
    blocked[4, 8] = OCCUPIED
    assert not path_is_clear(blocked, path, 1.0)
    unknown = observed.copy()
    unknown[4, 3] = UNKNOWN
    assert not path_is_clear(unknown, path, 0.0)
    for radius in (0.0, 1.0, 1.5, 2.5):  # agrees with planning_map's traversable rule on random maps
        rng = np.random.default_rng(int(radius * 10))
        for _ in range(10):
            observed = _random_observed(rng)
            pose = tuple(int(v) for v in np.argwhere(observed == FREE)[0])
            plan = planning_map(observed, pose, 0.1, MotionConfig(robot_radius_m=radius * 0.1))
            for cell in map(tuple, np.argwhere(observed == FREE)[:30]):
                if cell != pose:
                    assert path_is_clear(observed, [cell], radius) == bool(plan.traversable[cell])


def test_advance_moves_step_cells_and_reports_metres():
    path = [(0, 0), (1, 1), (1, 2), (2, 3), (2, 4)]
    pose, rest, metres = advance(path, 3, 0.1)
    assert pose == (2, 3) and rest == [(2, 3), (2, 4)]
    assert metres == pytest.approx(0.1 * (2 * np.sqrt(2) + 1))
    pose, rest, metres = advance(rest, 3, 0.1)  # the path ends sooner
    assert pose == (2, 4) and rest == [(2, 4)] and metres == pytest.approx(0.1)
    assert advance([(5, 5)], 3, 0.1) == ((5, 5), [(5, 5)], 0.0)
    with pytest.raises(ValueError, match="empty path"):
        advance([], 3, 0.1)


def test_bad_inputs_raise_value_error():
    observed = np.zeros((4, 4), np.int8)
    with pytest.raises(ValueError, match="int8"):
        planning_map(observed.astype(np.int16), (0, 0), 0.1)
    with pytest.raises(ValueError, match="outside"):
        planning_map(observed, (4, 0), 0.1)
    with pytest.raises(ValueError, match="resolution_m"):
        planning_map(observed, (0, 0), 0.0)
    with pytest.raises(ValueError, match="MotionConfig"):
        MotionConfig(robot_radius_m=-0.1)
    with pytest.raises(ValueError, match="MotionConfig"):
        MotionConfig(goal_reached_m=float("nan"))


def test_wall_distance_is_the_exact_distance_up_to_its_reach():
    rng = np.random.default_rng(8)
    for density in (0.02, 0.05, 0.3, 0.6, 0.9):  # dense walls exercise the skipping of interior wall cells
        walls = rng.random((int(rng.integers(1, 25)), int(rng.integers(1, 25)))) < density
        reach = float(rng.uniform(0.0, 6.0))
        got = wall_distance(walls, reach)
        exact = ndimage.distance_transform_edt(~walls) if walls.any() else np.full(walls.shape, np.inf)
        np.testing.assert_allclose(got, np.where(exact <= reach, exact, np.inf), rtol=1e-12)
    with pytest.raises(ValueError, match="bool"):
        wall_distance(np.zeros((3, 3), np.uint8), 2.0)
    with pytest.raises(ValueError, match="reach_cells"):
        wall_distance(np.zeros((3, 3), bool), -1.0)


def test_dijkstra_matches_the_reference_and_its_parents_form_least_cost_paths():
    rng = np.random.default_rng(3)
    for _ in range(15):
        shape = (int(rng.integers(1, 15)), int(rng.integers(1, 15)))
        costs = np.where(rng.random(shape) < 0.25, np.inf, rng.uniform(1.0, 5.0, shape))
        source = tuple(int(v) for v in rng.integers(shape))
        costs[source] = 2.0
        cost_to_go, parent = dijkstra(costs, source)
        np.testing.assert_allclose(cost_to_go, naive_travel_cost(costs, source), rtol=1e-12, atol=1e-12)
        assert parent[source] == -1 and np.all((parent >= 0) == (np.isfinite(cost_to_go) & (cost_to_go > 0)))
        for cell in map(tuple, np.argwhere(parent >= 0)):
            before = divmod(int(parent[cell]), shape[1])
            assert max(abs(before[0] - cell[0]), abs(before[1] - cell[1])) == 1
            step = 0.5 * (costs[before] + costs[cell]) * np.hypot(before[0] - cell[0], before[1] - cell[1])
            assert cost_to_go[cell] == pytest.approx(cost_to_go[before] + step, rel=1e-12)
    with pytest.raises(ValueError, match="impassable"):
        dijkstra(np.full((2, 2), np.inf), (0, 0))
    with pytest.raises(ValueError, match="outside"):
        dijkstra(np.ones((2, 2)), (2, 0))
    with pytest.raises(ValueError, match="> 0"):
        dijkstra(np.zeros((2, 2)), (0, 0))


def test_cost_to_go_and_path_on_a_hand_built_map(observed_from_text):
    observed = observed_from_text([
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
