"""Planning on blocks of a fine map (superex_deploy.onboard.planning.coarse): the block size, the kernels against
their slow twins in tests/naive.py, paths of blocks as paths of cells, and an explorer on a 0.05 m floor whose
commanded paths the simulator accepts."""

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard import Explorer, ExplorerConfig
from superex_deploy.onboard.mapping.blocks import coarsen_observed
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.coarse import CoarsePrediction, PlanningGrid, planning_factor, pool_prediction_blocks
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.prediction.scale import pool_mean
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Frontier, Prediction
from superex_deploy.sim.world import World
from tests.naive import naive_coarsen, naive_pool_mean, naive_pool_mixture


@pytest.mark.parametrize("resolution, factor", [(0.1, 1), (0.05, 2), (0.1 / 3, 3), (0.025, 4), (0.2, 1), (0.07, 1),
                                                (0.03, 3), (0.04, 2), (float(np.float32(0.05)), 2)])
def test_the_block_is_the_most_cells_within_the_planning_cell(resolution, factor):
    assert planning_factor(resolution, 0.1) == factor


@pytest.mark.parametrize("value", [0.0, -0.1, float("nan"), float("inf"), "0.1", True])
def test_a_bad_size_is_refused(value):
    with pytest.raises(ValueError, match="must be a positive, finite number of metres"):
        planning_factor(value, 0.1)
    with pytest.raises(ValueError, match="must be a positive, finite number of metres"):
        planning_factor(0.05, value)


def test_coarsening_matches_its_slow_twin_over_random_maps():
    rng = np.random.default_rng(0)
    for _ in range(60):
        shape = tuple(int(n) for n in rng.integers(1, 40, size=2))
        observed = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=shape, p=[0.2, 0.7, 0.1])
        for k in (1, 2, 3, 4):
            np.testing.assert_array_equal(coarsen_observed(observed, k), naive_coarsen(observed, k))
    assert coarsen_observed(observed, 1) is observed
    with pytest.raises(ValueError, match="integer >= 1"):
        coarsen_observed(observed, 0)
    with pytest.raises(ValueError, match="int8"):
        coarsen_observed(observed.astype(np.int16), 2)


def test_the_maps_blocks_stay_those_of_its_classes_through_scans_carving_and_writes():
    """Mapper.blocks is kept up to date over the rectangle each write changed: after every change it equals the
    coarsening of the whole map, with and without carving."""
    rng = np.random.default_rng(3)
    mapper = Mapper((61, 47))
    for k in (2, 3):
        for carving in (True, False):
            mapper.blocks(k, carving)
    for step in range(40):
        kind = step % 4
        if kind == 0:
            origin = (rng.uniform(1, 60), rng.uniform(1, 46))
            angles = np.linspace(-np.pi, np.pi, 90, endpoint=False)
            mapper.integrate_ranges(origin, angles, rng.uniform(1, 15, 90), 12.0)
        elif kind == 1:
            carved = np.zeros(mapper.shape, bool)
            r, c = int(rng.integers(0, 55)), int(rng.integers(0, 40))
            carved[r:r + 6, c:c + 7] = rng.random((6, 7))[:carved[r:r + 6, c:c + 7].shape[0],
                                                           :carved[r:r + 6, c:c + 7].shape[1]] < 0.7
            mapper.merge_carved(carved)
        elif kind == 2:
            mapper.clear_footprint((rng.uniform(0, 61), rng.uniform(0, 47)), 2.5)
        else:
            mapper.log_odds[int(rng.integers(0, 61)), int(rng.integers(0, 47))] = 3.0  # written in place
        for k in (2, 3):
            for carving in (True, False):
                np.testing.assert_array_equal(mapper.blocks(k, carving), naive_coarsen(mapper.observed(carving), k))
        fresh = Mapper(mapper.shape)
        fresh.log_odds[...], fresh.carve_log_odds[...] = mapper.log_odds, mapper.carve_log_odds
        np.testing.assert_array_equal(mapper.observed(), fresh.observed())
        np.testing.assert_array_equal(mapper.observed(False), fresh.observed(False))
        np.testing.assert_array_equal(mapper.known(), fresh.known())
        np.testing.assert_array_equal(mapper.carved_free, fresh.carved_free)
    with pytest.raises(ValueError, match="integer >= 1"):
        mapper.blocks(0)


def test_a_return_beyond_the_sensors_range_is_kept_in_the_derived_map():
    """integrate_ranges walks a finite range longer than max_range (and its hit shift): the rectangle marked
    changed holds it, so the derived map is the fresh one."""
    mapper = Mapper((12, 60))
    mapper.observed()
    mapper.integrate_ranges((5.5, 30.5), np.array([0.0, np.pi]), np.array([25.0, 3.0]), 5.0, hit_shift_cells=1.0)
    fresh = Mapper(mapper.shape)
    fresh.log_odds[...] = mapper.log_odds
    np.testing.assert_array_equal(mapper.observed(), fresh.observed())
    assert mapper.observed()[5, 56] == OCCUPIED  # the return, 25 cells and a shift away


def test_block_means_of_any_float_dtype_and_a_growth_aligned_to_nothing_is_refused():
    from superex_deploy.messages import MapFrame
    from superex_deploy.onboard.mapping.growth import MapGrowth, grown_frame

    for dtype in (np.float16, np.float32, np.float64, np.longdouble):
        np.testing.assert_allclose(pool_mean(np.ones((4, 5), dtype), 2), np.ones((2, 3)))
    with pytest.raises(ValueError, match="align must be an integer >= 1"):
        grown_frame(MapFrame((10, 10), 0.1), (0.0, 0.0, 5.0, 5.0), MapGrowth(), align=0)


def test_block_means_and_mixtures_match_their_slow_twins():
    rng = np.random.default_rng(1)
    for _ in range(40):
        shape = tuple(int(n) for n in rng.integers(1, 30, size=2))
        mean = rng.random(shape).astype(np.float32)
        variance = (0.25 * rng.random(shape)).astype(np.float32)
        for k in (2, 3, 4):
            np.testing.assert_allclose(pool_mean(mean, k), naive_pool_mean(mean, k), rtol=1e-6)
            pooled = pool_prediction_blocks(Prediction(mean=mean, variance=variance), k)
            expected_mean, expected_variance = naive_pool_mixture(mean, variance, k)
            np.testing.assert_allclose(pooled.mean, expected_mean, rtol=1e-6)
            np.testing.assert_allclose(pooled.variance, expected_variance, rtol=1e-5, atol=1e-7)
    # A block of one certain wall and three certain free cells: p = 0.25, and that spread as its variance.
    one = pool_prediction_blocks(Prediction(mean=np.array([[1, 0], [0, 0]], np.float32),
                                            variance=np.zeros((2, 2), np.float32)), 2)
    assert one.mean[0, 0] == pytest.approx(0.25) and one.variance[0, 0] == pytest.approx(0.1875)


def test_a_path_of_blocks_is_an_8_connected_path_of_cells_inside_those_blocks():
    rng = np.random.default_rng(2)
    steps = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
    for k in (2, 3, 4):
        grid = PlanningGrid((200, 200), 0.1 / k, k)
        for _ in range(30):
            blocks = [(25, 25)]
            for _ in range(int(rng.integers(0, 15))):
                dr, dc = steps[int(rng.integers(0, 8))]
                blocks.append((blocks[-1][0] + dr, blocks[-1][1] + dc))
            start = (25 * k + int(rng.integers(0, k)), 25 * k + int(rng.integers(0, k)))
            path = grid.fine_path(start, blocks)
            assert path[0] == start and path[-1] == grid.centre(blocks[-1])
            assert all(max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1 for a, b in zip(path, path[1:]))
            assert {grid.block(cell) for cell in path} <= set(blocks)
    assert PlanningGrid((10, 10), 0.1, 1).fine_path((3, 3), [(3, 3), (3, 4)]) == [(3, 3), (3, 4)]
    assert PlanningGrid((10, 10), 0.05, 2).fine_path((3, 3), []) == []


def test_a_frontier_of_blocks_and_a_block_at_the_edge_map_onto_cells():
    grid = PlanningGrid((9, 9), 0.05, 2)
    assert grid.block_shape == (5, 5) and grid.block_m == pytest.approx(0.1)
    assert grid.centre((4, 4)) == (8, 8)  # the cut block's centre stays inside the map
    frontier = grid.fine_frontier(Frontier((1, 2), np.array([[1, 2], [4, 4]], np.int32)))
    assert frontier.cell_rc == (3, 5) and frontier.cells.tolist() == [[3, 5], [8, 8]]


def test_the_planners_read_the_prediction_and_the_evidence_on_blocks():
    class Inner:
        seconds, value = 0.5, None
        evidence = np.arange(16, dtype=np.float32).reshape(4, 4)

        def __call__(self):
            return Prediction(mean=np.full((4, 4), 0.5, np.float32), variance=np.zeros((4, 4), np.float32))

        look = __call__

    coarse = CoarsePrediction(Inner(), 2)
    assert coarse().mean.shape == (2, 2) and np.allclose(coarse.look().mean, 0.5)
    np.testing.assert_allclose(coarse.evidence, [[2.5, 4.5], [10.5, 12.5]])
    assert coarse.seconds >= 0.5


def _upsampled_rooms(k: int) -> OccupancyGrid:
    walls = np.zeros((40, 80), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:, 40] = True
    walls[18:23, 40] = False  # a door between two rooms
    walls[20, 5:30] = True  # a wall inside the first room
    fine = np.kron(walls, np.ones((k, k), bool))
    return OccupancyGrid(fine, ~fine, 0.1 / k, f"rooms@x{k}")


@pytest.mark.parametrize("k", [2, 4])
def test_an_explorer_on_a_fine_floor_plans_on_blocks_and_never_drives_through_a_wall(k):
    grid = _upsampled_rooms(k)
    world = World(grid, (10 * k, 10 * k))
    explorer = Explorer(world.frame, make_planner("nearest"), ObservedAsPrediction(),
                        cfg=ExplorerConfig().for_simulation())
    assert explorer.planning_grid.factor == k
    goals = 0
    for _ in range(120):
        command = explorer.step(world.observe())
        if command.finished:
            break
        path = [tuple(cell) for cell in command.path_rc.tolist()]
        assert path[0] == world.pose_rc
        # Never through a cell the map holds occupied, nor through a wall of the floor.
        assert all(explorer.observed[cell] != OCCUPIED and not grid.occupied[cell] for cell in path[1:])
        goals += command.new_goal
        world.apply(command)  # refuses a path that is not 8-connected from the robot's cell
    assert command.finished and goals >= 2
    assert world.coverage(explorer.mapper.known(include_carved=False)) > 0.9  # both rooms, through the door


def test_a_growing_fine_map_keeps_its_blocks_and_its_goal_through_each_growth():
    """On a map that grows, rows above and columns to the left come in whole blocks: the planning's blocks keep
    their cells, and the goal and its path survive the growth (in blocks shifted by the growth)."""
    from superex_deploy.messages import MapFrame
    from superex_deploy.onboard.mapping.growth import MapGrowth

    from superex_deploy.maps import largest_region_start
    from superex_deploy.sim.generated_floors import FloorLayout, generate_floor

    grid = generate_floor(FloorLayout(width_m=40.0, height_m=24.0), 0.05, 1)
    world = World(grid, largest_region_start(grid, np.random.default_rng(0), 0.5))
    pose = world.observe().pose
    frame = MapFrame.around(pose.x, pose.y, resolution_m=0.05, size_m=4.0)
    explorer = Explorer(frame, make_planner("nearest"), ObservedAsPrediction(),
                        cfg=ExplorerConfig(growth=MapGrowth(margin_m=1.0, chunk_m=1.05)))
    grown = kept = 0
    for _ in range(150):
        before = explorer.frame
        goal_xy = None if explorer.goal is None else explorer.frame.centre_xy(explorer.planning_grid.centre(explorer.goal))
        command = explorer.step(world.observe())
        if explorer.frame != before:
            grown += 1
            shift = (explorer.frame.shape[0] - before.shape[0], before.origin_xy[0] - explorer.frame.origin_xy[0])
            assert round(shift[1] / 0.05) % 2 == 0  # whole blocks added to the left
            kept += goal_xy is not None and command.goal_xy is not None and not command.new_goal and \
                np.allclose(goal_xy, command.goal_xy)
        if command.finished:
            break
        world.apply(command)
    assert grown >= 2 and kept >= 1


def test_the_gymnasium_agent_chooses_among_the_blocks_the_explorer_plans_on(tmp_path):
    """On a 0.05 m map (a map_server YAML) the environment's actions are the explorer's frontier blocks, reachable
    on its planning map: each chosen goal becomes the explorer's goal and the robot drives there."""
    gym_env = pytest.importorskip("superex_deploy.gym_env")
    from PIL import Image

    grid = _upsampled_rooms(2)
    Image.fromarray(np.where(grid.occupied, 0, 254).astype(np.uint8)).save(tmp_path / "rooms.pgm")
    (tmp_path / "rooms.yaml").write_text("image: rooms.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                                         "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    env = gym_env.ExplorationEnv(map=str(tmp_path / "rooms.yaml"), max_steps=200, steps_per_action=10)
    try:
        _, info = env.reset(seed=0)
        assert env._explorer.planning_grid.factor == 2
        agent, taken = env._agent, []
        choose = agent.choose_goal

        def spy(ctx):  # whether the explorer takes the agent's target (else it falls back to the nearest frontier)
            target = agent.target
            chosen = choose(ctx)
            if target is not None:
                taken.append(chosen == target)
            return chosen

        agent.choose_goal = spy
        coverage = info["coverage"]
        for _ in range(8):
            if not info["action_mask"].any():
                break
            # The farthest goal offered: every offered goal must be one the explorer can reach, not just the nearest.
            _, _, terminated, truncated, info = env.step(len(env._goals) - 1)
            if terminated or truncated:
                break
        assert len(taken) >= 2 and all(taken) and info["coverage"] > coverage
    finally:
        env.close()


def test_a_path_leaves_the_robots_block_around_a_wall_in_it_and_ends_on_a_free_cell():
    grid = PlanningGrid((9, 9), 0.1 / 3, 3)
    observed = np.full((9, 9), FREE, np.int8)
    observed[2, 1] = OCCUPIED  # a wall in the robot's own block (kept under a footprint, or a phantom)
    observed[3:6, 3] = UNKNOWN  # the goal block's left column and centre never seen
    observed[4, 4] = UNKNOWN
    goal_rc, path = grid.on_map((2, 0), (1, 1), [(0, 0), (1, 1)], observed)
    cells = [tuple(c) for c in path.tolist()]
    assert cells[0] == (2, 0) and (2, 1) not in cells
    assert all(max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1 for a, b in zip(cells, cells[1:]))
    assert goal_rc == cells[-1] and observed[goal_rc] == FREE  # the free cell nearest the block's centre
    assert np.hypot(goal_rc[0] - 4, goal_rc[1] - 4) == 1.0
    # Without the map: straight through, to the centre (what the planning alone knows).
    assert grid.on_map((2, 0), (1, 1), [(0, 0), (1, 1)])[0] == (4, 4)


@pytest.mark.parametrize("resolution", [0.05, 0.1 / 3])
def test_every_commanded_goal_is_a_free_cell_and_no_path_cell_a_wall_on_a_fine_generated_floor(resolution):
    from superex_deploy.maps import largest_region_start
    from superex_deploy.sim.generated_floors import FloorLayout, generate_floor

    grid = generate_floor(FloorLayout(width_m=30.0, height_m=20.0), resolution, 1)
    world = World(grid, largest_region_start(grid, np.random.default_rng(1), 0.5))
    explorer = Explorer(world.frame, make_planner("nearest"), ObservedAsPrediction())
    goals = 0
    for _ in range(80):
        command = explorer.step(world.observe())
        if command.finished:
            break
        if command.goal_rc is not None:
            goals += 1
            assert explorer.observed[command.goal_rc] == FREE
        assert all(explorer.observed[tuple(cell)] != OCCUPIED for cell in command.path_rc[1:].tolist())
        world.apply(command)
    assert goals >= 10 and world.collisions == 0
