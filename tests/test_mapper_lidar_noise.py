"""The onboard map under a noisy LiDAR (superex_deploy.onboard.mapping.mapper): the per-scan vote and the calibrated
return shift against the slow twin, a noisy wall that does not thicken, spurious returns that do not become walls,
footprint clearing (never of a confirmed wall) and a spurious return next to the robot that does not end
exploration."""

import dataclasses

import numpy as np
import pytest

from superex_deploy.geometry import cast_rays
from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import MapFrame
from superex_deploy.onboard import Explorer
from superex_deploy.onboard.explorer import ExplorerConfig
from superex_deploy.onboard.mapping.log_odds import OccupancyConfig, integrate_log_odds
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.planners import NearestFrontier
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.sim.world import World
from tests.naive import naive_integrate_log_odds


def test_the_shifted_vote_matches_its_naive_twin_on_random_noisy_scans():
    rng = np.random.default_rng(2024)
    cfg = OccupancyConfig()
    for trial in range(30):
        shape = tuple(int(n) for n in rng.integers(5, 30, 2))
        occupied = rng.random(shape) < 0.2
        log_odds = rng.choice(np.array([cfg.lowest, -0.4, 0.0, 0.1, 2.5, cfg.highest], np.float32), size=shape)
        shift = [0.0, 0.4, 0.6, 1.3][trial % 4]
        for _ in range(3):
            y0, x0 = rng.uniform(0, shape[0]), rng.uniform(0, shape[1])
            occupied[int(y0), int(x0)] = False
            angles = rng.uniform(-np.pi, np.pi, 60)
            max_t = float(rng.uniform(2, 40))
            hits = cast_rays(occupied, (y0, x0), angles, max_t)
            ranges = np.where(hits.hit_mask, hits.distance_cells, np.inf)
            ranges = np.where(np.isfinite(ranges), np.maximum(ranges + rng.normal(0, 0.2, 60), 0.0), ranges)
            short = rng.random(60) < 0.1
            ranges[short] = rng.uniform(0, 3, int(short.sum()))
            expected = naive_integrate_log_odds(log_odds, y0, x0, angles, ranges, max_t, cfg.hit, cfg.miss,
                                                cfg.lowest, cfg.highest, hit_shift=shift, stop_at=cfg.occupied_threshold)
            integrate_log_odds(log_odds, (y0, x0), angles, ranges, max_t, cfg, hit_shift_cells=shift)
            np.testing.assert_array_equal(log_odds, expected)
    with pytest.raises(ValueError, match="hit_shift_cells"):
        integrate_log_odds(log_odds, (1.5, 1.5), [0.0], [1.0], 5.0, hit_shift_cells=-0.1)
    for bad in [dict(range_sigma_m=-0.01), dict(range_hit_sigmas=float("inf")), dict(footprint_clearing=1),
                dict(footprint_margin_sigmas=-1.0)]:
        with pytest.raises(ValueError, match="OccupancyConfig"):
            OccupancyConfig(**bad)


def _noisy_scans(world, sigma_m, n, rng):
    """``n`` scans from the world's robot, every return moved by N(0, sigma_m)."""
    obs = world.observe()
    for _ in range(n):
        ranges = obs.scan.ranges.astype(np.float64)
        ranges = np.where(np.isfinite(ranges), ranges + rng.normal(0.0, sigma_m, ranges.shape), ranges)
        yield obs.pose, dataclasses.replace(obs.scan, ranges=ranges.astype(np.float32))


def test_a_noisy_range_scan_of_a_wall_does_not_thicken_it_once_the_sigma_is_calibrated(wall_room):
    grid = wall_room()
    frame = MapFrame(grid.shape, 0.1)
    world = World(grid, (20, 12))
    calibrated = Mapper(grid.shape, OccupancyConfig(range_sigma_m=0.02))
    uncalibrated = Mapper(grid.shape)
    rng = np.random.default_rng(5)
    for pose, scan in _noisy_scans(world, 0.02, 40, rng):
        calibrated.integrate_scan(frame, pose, scan)
        uncalibrated.integrate_scan(frame, pose, scan)
        # The cells in front of the wall stay free and the wall stays a wall, after every scan.
        assert np.all(calibrated.observed()[8:32, 24] == FREE)
        assert np.all(calibrated.observed()[8:32, 25] == OCCUPIED)
    # Taken as exact, the same ranges make some free cells in front of the wall walls (where as many returns fell
    # short of the face as crossed it): the wall grows towards the robot.
    assert np.count_nonzero(uncalibrated.observed()[8:32, 24] == OCCUPIED) >= 3


def test_spurious_short_returns_in_free_space_do_not_become_walls(wall_room):
    grid = wall_room()
    frame = MapFrame(grid.shape, 0.1)
    obs = World(grid, (20, 12)).observe()
    mapper = Mapper(grid.shape)
    mapper.integrate_scan(frame, obs.pose, obs.scan)
    ranges = obs.scan.ranges.copy()
    rng = np.random.default_rng(3)
    spurious = rng.choice(ranges.size, 30, replace=False)
    ranges[spurious] = rng.uniform(0.1, 0.8, 30)  # short returns in the free room, 1 to 8 cells out
    mapper.integrate_scan(frame, obs.pose, dataclasses.replace(obs.scan, ranges=ranges))
    truth_free = ~grid.occupied
    assert not np.any(mapper.seen_wall & truth_free)  # each was outvoted by the rays crossing its cell


def test_footprint_clearing_frees_a_phantom_under_the_robot_but_never_a_confirmed_wall():
    cfg = OccupancyConfig()
    mapper = Mapper((9, 9), cfg)
    mapper.log_odds[...] = -0.4  # seen free
    mapper.log_odds[0, :] = 0.0  # never seen
    mapper.log_odds[4, 5] = cfg.hit - 0.4  # a phantom hit once, next to the robot
    mapper.log_odds[3, 3] = cfg.highest  # a wall hit by many scans, inside the footprint
    mapper.log_odds[4, 7] = cfg.hit  # a wall outside the footprint
    changed = mapper.clear_footprint((4.5, 4.5), 1.5)
    observed = mapper.observed()
    assert changed == 1 and observed[4, 5] == FREE and mapper.log_odds[4, 5] == np.float32(cfg.lowest)
    assert observed[3, 3] == OCCUPIED and mapper.log_odds[3, 3] == np.float32(cfg.highest)
    assert observed[4, 7] == OCCUPIED
    assert mapper.log_odds[4, 4] == np.float32(cfg.lowest) and mapper.log_odds[6, 6] == np.float32(-0.4)
    # The robot's own cell is cleared at any radius; unknown cells are never made free.
    mapper.log_odds[2, 2] = cfg.hit
    mapper.log_odds[1, 1] = 0.0
    assert mapper.clear_footprint((2.9, 2.9), 0.0) == 1 and mapper.observed()[2, 2] == FREE
    assert mapper.clear_footprint((1.5, 1.5), 3.0) == 0 and mapper.observed()[1, 1] == UNKNOWN
    assert np.all(mapper.observed()[0] == UNKNOWN)
    with pytest.raises(ValueError, match="outside the map"):
        mapper.clear_footprint((9.5, 1.0), 1.0)
    with pytest.raises(ValueError, match="radius_cells"):
        mapper.clear_footprint((1.5, 1.5), -1.0)


@pytest.mark.parametrize("clearing", [True, False])
def test_a_phantom_wall_under_the_robot_does_not_end_exploration(clearing):
    walls = np.zeros((30, 60), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:, 30] = True
    walls[13:17, 30] = False  # a door to an unseen room
    grid = OccupancyGrid(walls, ~walls, 0.1, "two rooms")
    world = World(grid, (15, 10))
    cfg = ExplorerConfig(occupancy=OccupancyConfig(footprint_clearing=clearing)).for_simulation()
    explorer = Explorer(world.frame, NearestFrontier(), ObservedAsPrediction(), cfg=cfg)
    obs = world.observe()
    assert not explorer.step(obs).finished
    # A phantom hit in the robot's own cell (what one spurious return left under the binary "a hit wins" rule,
    # or a scan misplaced by a pose error): every neighbour is within the robot radius of it, so no path leaves.
    explorer.mapper.log_odds[15, 10] = explorer.mapper.cfg.hit
    command = explorer.step(obs)
    if clearing:
        assert not command.finished and command.goal_rc is not None
        assert explorer.observed[15, 10] == FREE
    else:  # the scan's misses alone leave it a wall: the explorer reports the floor finished
        assert explorer.observed[15, 10] == OCCUPIED and command.finished
