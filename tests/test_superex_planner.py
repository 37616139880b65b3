"""The SuperEx planner on hand-built grids with known answers, and its helpers against slow twins."""

import numpy as np
import pytest

from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.planning.motion import planning_map
from superex_deploy.onboard.planning.planners import MapexPlanner, make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.oracle import OraclePredictor
from superex_deploy.onboard.planning.planners.superex import SuperexConfig, SuperexPlanner, descend
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, PlanningContext, Prediction
from superex_deploy.onboard.planning.visibility import VisibilityConfig, predicted_visibility
from superex_deploy.maps import OccupancyGrid
from tests.naive import naive_path_gain


def _context(observed, pose, prediction, frontiers=None):
    plan = planning_map(observed, pose, 0.1)
    frontiers = find_frontiers(observed, 10) if frontiers is None else frontiers
    return PlanningContext(observed=observed, pose_rc=pose, frontiers=tuple(frontiers),
                           travel_cost=plan.travel_cost, traversable=plan.traversable, resolution_m=0.1,
                           predict=lambda: prediction, rng=np.random.default_rng(0))


def _corridor_with_rooms():
    """A corridor (rows 40-49) running right from a known stretch (cols 1-79); above it, a 6 x 3.8 m room whose
    door (cols 20-29) opens next to the robot at (45, 25); the corridor goes on unknown to col 398."""
    walls = np.zeros((100, 400), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[39, :] = walls[50, :] = True
    walls[0:39, 60] = True
    walls[39, 20:30] = False
    observed = np.full(walls.shape, UNKNOWN, np.int8)
    observed[40:50, 1:80] = FREE
    observed[39, 1:80] = np.where(walls[39, 1:80], OCCUPIED, FREE)
    observed[50, 1:80] = OCCUPIED
    observed[40:50, 0] = OCCUPIED
    return OccupancyGrid(walls, ~walls, 0.1, "corridor and room"), observed


def test_a_dead_end_room_beside_the_robot_is_finished_before_the_far_corridor():
    grid, observed = _corridor_with_rooms()
    ctx = _context(observed, (45, 25), OraclePredictor(grid).predict(observed))
    frontiers = {f.cell_rc for f in ctx.frontiers}
    assert frontiers == {(39, 24), (44, 79)}
    assert SuperexPlanner().choose_goal(ctx) == (39, 24)


def test_pathwise_gain_matches_the_naive_union_of_views_along_the_path():
    grid, observed = _corridor_with_rooms()
    prediction = OraclePredictor(grid).predict(observed)
    ctx = _context(observed, (45, 25), prediction)
    cfg = SuperexConfig(n_rays=48, sense_every_m=2.0, range_m=6.0, gain="path")
    gains = SuperexPlanner(cfg).gains(ctx, prediction, list(ctx.frontiers))
    visibility = VisibilityConfig(n_rays=48, range_m=6.0, hit_threshold=cfg.wall_threshold)
    for frontier, gain in zip(ctx.frontiers, gains):
        path = descend(ctx.travel_cost, frontier.cell_rc)
        views = [predicted_visibility(prediction.mean, path[k], visibility, 0.1)
                 for k in list(range(20, len(path) - 1, 20)) + [len(path) - 1]]
        assert gain == np.count_nonzero(np.logical_or.reduce(views) & (observed == UNKNOWN))
        # The naive kernels agree up to rays through cell corners, where float rounding picks the neighbour.
        assert gain == pytest.approx(naive_path_gain(prediction.mean, observed, path, 20, 48, 60.0,
                                                     cfg.wall_threshold), rel=0.005)
    goal_only = SuperexPlanner(SuperexConfig(n_rays=48, range_m=6.0, gain="goal")).gains(
        ctx, prediction, list(ctx.frontiers))
    assert np.all(gains >= goal_only) and gains[1] > goal_only[1]  # the corridor's path passes the room's door
    # The same for the expected gain (the default) against its goal-only form.
    expected = SuperexPlanner(SuperexConfig(n_rays=48, sense_every_m=2.0, range_m=6.0)).gains(
        ctx, prediction, list(ctx.frontiers))
    expected_goal = SuperexPlanner(SuperexConfig(n_rays=48, range_m=6.0, gain="expected_goal")).gains(
        ctx, prediction, list(ctx.frontiers))
    assert np.all(expected >= expected_goal) and expected[1] > expected_goal[1]


def test_the_prediction_changes_the_choice_where_the_observed_map_cannot():
    """Two doors at the same travel cost from the robot: a closet behind the left one, a hall behind the
    right one. Unknown taken as free, both look alike; the true map makes the hall the clear choice."""
    walls = np.zeros((80, 81), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[50, :] = True
    walls[50, 15:25] = walls[50, 56:66] = False  # two 1 m doors, symmetric about the robot
    walls[:50, 40] = True
    walls[35, 1:40] = True  # the left side is a 1.5 m deep closet
    observed = np.full(walls.shape, UNKNOWN, np.int8)
    observed[51:79, 1:80] = FREE
    observed[50, :] = np.where(walls[50, :], OCCUPIED, FREE)
    observed[79, :] = observed[51:79, 0] = observed[51:79, 80] = OCCUPIED
    grid = OccupancyGrid(walls, ~walls, 0.1, "closet and hall")
    pose = (65, 40)
    oracle = _context(observed, pose, OraclePredictor(grid).predict(observed))
    blind = _context(observed, pose, ObservedAsPrediction().predict(observed))
    cells = [f.cell_rc for f in oracle.frontiers]
    assert len(cells) == 2 and oracle.travel_cost[cells[0]] == pytest.approx(oracle.travel_cost[cells[1]], rel=0.05)
    planner = SuperexPlanner()
    true_gains = planner.gains(oracle, oracle.predict(), list(oracle.frontiers))
    blind_gains = planner.gains(blind, blind.predict(), list(blind.frontiers))
    left = int(np.argmin([c[1] for c in cells]))
    assert true_gains[left] < 0.5 * true_gains[1 - left]
    assert blind_gains[left] == pytest.approx(blind_gains[1 - left], rel=0.1)
    assert planner.choose_goal(oracle) == cells[1 - left]


def test_descend_follows_the_cost_to_go_down_to_the_robot():
    rng = np.random.default_rng(3)
    for _ in range(20):
        walls = rng.random((30, 40)) < 0.15
        observed = np.where(walls, OCCUPIED, FREE).astype(np.int8)
        observed[15, 20] = FREE
        plan = planning_map(observed, (15, 20), 0.1)
        reachable = np.argwhere(np.isfinite(plan.travel_cost))
        goal = tuple(int(v) for v in reachable[rng.integers(len(reachable))])
        path = descend(plan.travel_cost, goal)
        assert path[0] == (15, 20) and path[-1] == goal
        steps = np.abs(np.diff(np.array(path), axis=0))
        assert steps.max(initial=0) <= 1  # 8-connected
        costs = [plan.travel_cost[cell] for cell in path]
        assert all(a < b for a, b in zip(costs[:-1], costs[1:]))
    with pytest.raises(ValueError, match="unreachable"):
        descend(np.full((3, 3), np.inf), (1, 1))


def test_goals_are_kept_until_reached_unless_drop_resolved_is_set():
    observed = np.zeros((20, 20), np.int8)
    observed[0:3, :] = UNKNOWN
    keeper, dropper = SuperexPlanner(), SuperexPlanner(SuperexConfig(drop_resolved_m=0.3))
    assert keeper.keep_goal(observed, (10, 10), (15, 15), 5)
    assert not dropper.keep_goal(observed, (10, 10), (15, 15), 5)  # no unknown within 3 cells
    assert dropper.keep_goal(observed, (10, 10), (5, 15), 5)  # unknown 3 cells away


def test_superex_episodes_run_and_are_deterministic():
    grid, _ = _corridor_with_rooms()
    runs = [run_episode(grid, (45, 25), make_planner("superex"), OraclePredictor(grid), steps=60, seed=0)
            for _ in range(2)]
    assert runs[0].goals == runs[1].goals and np.array_equal(runs[0].coverage, runs[1].coverage)
    assert runs[0].goals[0][0] < 39  # into the room first (its door was seen from the start)
    mapex = run_episode(grid, (45, 25), MapexPlanner(), OraclePredictor(grid), steps=60, seed=0)
    assert runs[0].coverage[-1] >= mapex.coverage[-1] - 0.02


@pytest.mark.parametrize("field, value, message", [
    ("gain", "view", "gain must be 'path', 'goal', 'expected' or 'expected_goal'"),
    ("wall_threshold", 0.0, "wall_threshold must lie in"),
    ("sense_every_m", 0.0, "sense_every_m must be positive"),
    ("drop_resolved_m", -1.0, "drop_resolved_m must be None"),
    ("n_rays", 2.5, "n_rays must be an integer"),
])
def test_bad_configuration_is_refused(field, value, message):
    with pytest.raises(ValueError, match=message):
        SuperexConfig(**{field: value})
    with pytest.raises(ValueError, match="bad configuration"):
        make_planner("superex", no_such_field=1)


@pytest.mark.parametrize("field", ["choice", "candidates", "rollout_goals", "horizon_m", "rollout_cell_m",
                                   "rollout_frontier_cells", "tour_frontiers"])
def test_the_retired_rollout_and_tour_options_are_no_fields(field):
    from superex_deploy.recording.convert import RETIRED

    value = RETIRED["superex"][1][field]  # even at its old default: the option no longer exists
    with pytest.raises(TypeError, match=field):
        SuperexConfig(**{field: value})
    with pytest.raises(ValueError, match=f"bad configuration for planner 'superex': .*'{field}'"):
        make_planner("superex", **{field: value})
