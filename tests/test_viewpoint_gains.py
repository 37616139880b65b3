"""The batched goal-choice kernels (viewpoint gains, and the superex planner's descents) against the code they
replaced (``tests/naive.py``): the same descents, the same counts and variance sums bit for bit, hence the same
goals, on random hand-built grids."""

import numpy as np
import pytest

from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.planning.motion import planning_map
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.planning.planners.superex import _descend_paths, descend, descend_all, path_viewpoints
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, PlanningContext, Prediction
from superex_deploy.onboard.planning.viewpoint_gains import union_visible_unknown, union_visible_unknown_flat, visible_gains
from superex_deploy.onboard.planning.visibility import VisibilityConfig, reachable_frontiers
from tests import naive


def _random_world(seed: int, shape=(70, 90)):
    """A random floor: rooms of known free space with walls and doors, unknown beyond, and a noisy prediction
    (walls where the world has them, scattered faint and strong predicted walls in the unknown)."""
    rng = np.random.default_rng(seed)
    walls = np.zeros(shape, bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    for _ in range(rng.integers(3, 7)):
        if rng.random() < 0.5:
            r = rng.integers(5, shape[0] - 5)
            walls[r, :] = True
            for _ in range(2):
                door = rng.integers(2, shape[1] - 10)
                walls[r, door:door + rng.integers(4, 9)] = False
        else:
            c = rng.integers(5, shape[1] - 5)
            walls[:, c] = True
            for _ in range(2):
                door = rng.integers(2, shape[0] - 10)
                walls[door:door + rng.integers(4, 9), c] = False
    observed = np.full(shape, UNKNOWN, np.int8)
    r0, c0 = rng.integers(0, shape[0] // 3), rng.integers(0, shape[1] // 3)
    known = np.zeros(shape, bool)
    known[r0:r0 + rng.integers(shape[0] // 3, shape[0]), c0:c0 + rng.integers(shape[1] // 3, shape[1])] = True
    known &= rng.random(shape) > 0.02  # unknown specks inside the known part
    observed[known] = np.where(walls[known], OCCUPIED, FREE)
    mean = np.where(observed == UNKNOWN, np.where(walls, 0.9, 0.1 * rng.random(shape)), walls).astype(np.float32)
    mean[(observed == UNKNOWN) & (rng.random(shape) < 0.03)] = 0.7
    variance = (rng.random(shape) * 0.1 * (observed == UNKNOWN)).astype(np.float32)
    free = np.argwhere((observed == FREE) & ~np.pad(walls, 1)[2:, 1:-1] & ~np.pad(walls, 1)[:-2, 1:-1])
    pose = tuple(int(v) for v in free[rng.integers(len(free))])
    return observed, Prediction(mean, variance), pose


def _context(observed, prediction, pose, min_cells=3):
    plan = planning_map(observed, pose, 0.1)
    return PlanningContext(observed=observed, pose_rc=pose, frontiers=find_frontiers(observed, min_cells),
                           travel_cost=plan.travel_cost, traversable=plan.traversable, resolution_m=0.1,
                           predict=lambda: prediction, rng=np.random.default_rng(0))


def test_descents_of_every_reachable_cell_match_the_first_written_descent():
    for seed in range(6):
        observed, _, pose = _random_world(seed)
        cost = planning_map(observed, pose, 0.1).travel_cost
        goals = np.argwhere(np.isfinite(cost))[::7]
        cells, offsets = descend_all(cost, goals)
        assert len(offsets) == len(goals) + 1
        for i, goal in enumerate(goals):
            expected = naive.naive_descend(cost, goal)
            assert [tuple(c) for c in cells[offsets[i]:offsets[i + 1]].tolist()] == expected
        assert descend(cost, goals[-1]) == naive.naive_descend(cost, goals[-1])


def test_descent_takes_the_first_least_cell_of_a_tie_as_argmin_does():
    cost = np.array([[2.0, 1.0, 1.0], [3.0, 2.5, 0.0], [1.0, 9.0, 9.0]])
    rows, cols, offsets = _descend_paths(cost, np.array([2]), np.array([0]))
    # From (2, 0) the window rows 1-2, cols 0-1 holds 3, 2.5, 1, 9: (2, 0) itself is least: a local minimum.
    assert list(zip(rows, cols)) == naive.naive_descend(cost, (2, 0)) == [(2, 0)]
    rows, cols, _ = _descend_paths(cost, np.array([0]), np.array([0]))
    assert list(zip(rows.tolist(), cols.tolist())) == naive.naive_descend(cost, (0, 0)) == [(1, 2), (0, 1), (0, 0)]


def test_descent_refuses_an_unreachable_goal_or_a_bad_map():
    cost = np.full((3, 3), np.inf)
    cost[1, 1] = 0.0
    with pytest.raises(ValueError, match="unreachable"):
        descend_all(cost, [(1, 1), (0, 0)])
    with pytest.raises(ValueError, match="outside the map"):
        descend_all(cost, [(3, 0)])
    with pytest.raises(ValueError, match="float64"):
        descend_all(cost.astype(np.float32), [(1, 1)])


@pytest.mark.parametrize("accumulate", [False, True])
def test_visible_gains_are_bit_identical_to_one_cast_and_fill_per_viewpoint(accumulate):
    cfg = VisibilityConfig(n_rays=97, range_m=3.0, hit_threshold=0.6, accumulate=accumulate)
    for seed in range(6):
        observed, prediction, _ = _random_world(seed)
        cells = np.argwhere(observed != OCCUPIED)[::37]
        cells = np.concatenate([cells, cells[:3]])  # repeated viewpoints are cast once, counted each time
        counts, var_sums = visible_gains(prediction, observed, cells, cfg, 0.1)
        ref_counts, ref_sums = naive.reference_visible_gains(prediction, observed, cells, cfg, 0.1)
        assert np.array_equal(counts, ref_counts)
        assert np.array_equal(var_sums, ref_sums)  # the same additions in the same order
        assert counts.sum() > 0


def test_union_of_views_is_identical_to_the_reference_for_random_groups():
    cfg = VisibilityConfig(n_rays=61, range_m=2.5, hit_threshold=0.5)
    for seed in range(6):
        observed, prediction, _ = _random_world(seed)
        rng = np.random.default_rng(100 + seed)
        pool = np.argwhere(observed != OCCUPIED)
        groups = [[tuple(pool[k]) for k in rng.integers(len(pool), size=rng.integers(0, 6))] for _ in range(12)]
        # Chains that share their first viewpoints (as the SuperEx paths from the robot do), repeats included.
        chains = [[tuple(pool[k]) for k in rng.integers(len(pool), size=8)] for _ in range(3)]
        groups += [chain[:rng.integers(1, 9)] + [tuple(pool[rng.integers(len(pool))])] for chain in chains
                   for _ in range(4)] + [chains[0] + chains[0][:2]]
        rng.shuffle(groups)
        counts = union_visible_unknown(prediction.mean, observed, groups, cfg, 0.1)
        assert np.array_equal(counts, naive.reference_union_visible_unknown(prediction.mean, observed, groups, cfg,
                                                                            0.1))
        assert counts.sum() > 0


def test_union_flat_refuses_offsets_that_do_not_cover_the_cells():
    observed, prediction, _ = _random_world(0)
    cfg = VisibilityConfig(n_rays=16, range_m=1.0)
    cells = np.array([[5, 5], [6, 6]])
    for offsets in ([0, 1], [1, 2], [0, 2, 1, 2], []):
        with pytest.raises(ValueError, match="group_offsets"):
            union_visible_unknown_flat(prediction.mean, observed, cells, offsets, cfg, 0.1)


def test_path_viewpoints_sample_the_descent_as_the_planner_did():
    observed, _, pose = _random_world(3)
    cost = planning_map(observed, pose, 0.1).travel_cost
    goals = np.argwhere(np.isfinite(cost))[::29]
    for every in (1, 4, 15):
        cells, offsets = path_viewpoints(cost, goals, every)
        for i, goal in enumerate(goals):
            path = naive.naive_descend(cost, goal)
            expected = [path[k] for k in list(range(every, len(path) - 1, every)) + [len(path) - 1]]
            assert [tuple(c) for c in cells[offsets[i]:offsets[i + 1]].tolist()] == expected


@pytest.mark.parametrize("name", ["superex", "mapex", "hector"])
def test_planners_choose_the_same_goal_as_with_the_reference_scoring(name):
    from superex_deploy.onboard.planning.planners import hector, mapex, superex

    chosen = 0
    for seed in range(10):
        observed, prediction, pose = _random_world(seed, (60, 120))
        ctx = _context(observed, prediction, pose)
        frontiers, _ = reachable_frontiers(ctx)
        if len(frontiers) < 2:
            continue
        planner = make_planner(name, **({"gain": "path"} if name == "superex" else {}))  # the reference's gain
        goal = planner.choose_goal(ctx)
        saved = (superex.SuperexPlanner.gains, mapex.visible_gains, hector.visible_gains)
        superex.SuperexPlanner.gains = lambda self, c, p, f: naive.reference_superex_gains(self, c, p, f)
        mapex.visible_gains = hector.visible_gains = naive.reference_visible_gains
        try:
            reference_goal = planner.choose_goal(ctx)
        finally:
            superex.SuperexPlanner.gains, mapex.visible_gains, hector.visible_gains = saved
        if name == "superex":
            assert np.array_equal(planner.gains(ctx, prediction, frontiers),
                                  naive.reference_superex_gains(planner, ctx, prediction, frontiers))
        assert goal == reference_goal
        chosen += 1
    assert chosen >= 5

