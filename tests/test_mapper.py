"""The onboard map (superex_deploy.onboard.mapping.mapper): the log-odds scan kernel against its slow twin, the update
rules (no cell decided for good by one reading, a wall wins over a free history, a wall seen from two poses a cell
apart stays a wall), scans of the simulated world (what is seen, what stays unknown, invalid readings), the SLAM-map
layer, and carving kept apart as bounded evidence."""

import numpy as np
import pytest

from superex_deploy.geometry import cast_rays
from superex_deploy.maps import OccupancyGrid, load_map, start_poses
from superex_deploy.messages import LaserScan, MapFrame, Pose2D
from superex_deploy.onboard.mapping.log_odds import OccupancyConfig, integrate_log_odds
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.maps import coverage
from superex_deploy.sim.world import LidarConfig, World, WorldConfig
from tests.naive import naive_integrate_log_odds


def test_the_log_odds_kernel_matches_its_naive_twin_on_random_scans():
    rng = np.random.default_rng(24)
    cfg = OccupancyConfig()
    for _ in range(30):
        shape = tuple(int(n) for n in rng.integers(5, 30, 2))
        occupied = rng.random(shape) < 0.2
        # A history to update: values on the clamps, between them and at the thresholds.
        log_odds = rng.choice(np.array([cfg.lowest, -0.8, -0.4, 0.0, 0.1, 0.5, 2.5, cfg.highest], np.float32),
                              size=shape)
        for _ in range(3):  # a few scans in a row, from different origins
            y0, x0 = rng.uniform(0, shape[0]), rng.uniform(0, shape[1])
            occupied[int(y0), int(x0)] = False
            angles = rng.uniform(-np.pi, np.pi, 40)
            max_t = float(rng.uniform(2, 40))
            hits = cast_rays(occupied, (y0, x0), angles, max_t)
            ranges = np.where(hits.hit_mask, hits.distance_cells, np.inf)
            ranges[rng.random(40) < 0.2] = np.inf  # lost returns: free up to the range
            short = rng.random(40) < 0.1
            ranges[short] = rng.uniform(0, 3, int(short.sum()))  # spurious short returns, inside free space
            usable = float(rng.choice([np.inf, rng.uniform(1, 40)]))  # no-return rays cut at the usable range
            expected = naive_integrate_log_odds(log_odds, y0, x0, angles, ranges, max_t, cfg.hit, cfg.miss,
                                                cfg.lowest, cfg.highest, usable_t=usable,
                                                stop_at=cfg.occupied_threshold)
            integrate_log_odds(log_odds, (y0, x0), angles, ranges, max_t, cfg, usable_range_cells=usable)
            np.testing.assert_array_equal(log_odds, expected)


def test_the_log_odds_wrapper_refuses_bad_input():
    grid = np.zeros((5, 5), np.float32)
    with pytest.raises(ValueError, match="float32"):
        integrate_log_odds(np.zeros((5, 5)), (2.5, 2.5), [0.0], [1.0], 10.0)
    with pytest.raises(ValueError, match="NaN or a negative range"):
        integrate_log_odds(grid, (2.5, 2.5), [0.0], [np.nan], 10.0)
    with pytest.raises(ValueError, match="ranges_cells has shape"):
        integrate_log_odds(grid, (2.5, 2.5), [0.0, 1.0], [1.0], 10.0)
    with pytest.raises(ValueError, match="outside the grid"):
        integrate_log_odds(grid, (7.5, 2.5), [0.0], [1.0], 10.0)
    with pytest.raises(ValueError, match="touched"):
        integrate_log_odds(grid, (2.5, 2.5), [0.0], [1.0], 10.0, touched=np.zeros((4, 5), np.int8))
    with pytest.raises(ValueError, match="max_range_cells"):
        integrate_log_odds(grid, (2.5, 2.5), [0.0], [1.0], 0.0)
    for bad in [dict(miss=0.1), dict(hit=-1.0), dict(free_threshold=0.1), dict(lowest=-0.1),
                dict(occupied_threshold=4.0), dict(carve_step=-2.0), dict(slam_free_percent=70),
                dict(slam_occupied_percent=101), dict(hit=float("nan"))]:
        with pytest.raises(ValueError, match="OccupancyConfig"):
            OccupancyConfig(**bad)
    with pytest.raises(ValueError, match="OccupancyConfig"):
        Mapper((5, 5), cfg=dict())


def _ray_east(mapper, row, wall_col, reps=1, origin_col=0.5):
    """``reps`` scans of one ray along +x from ``(row + 0.5, origin_col)``: a return at the face of ``wall_col``
    (None: no return, free to the range)."""
    distance = np.inf if wall_col is None else wall_col - origin_col
    for _ in range(reps):
        mapper.integrate_ranges((row + 0.5, origin_col), [0.0], [distance], 50.0)


def test_one_reading_decides_no_cell_for_good():
    cfg = OccupancyConfig()
    mapper = Mapper((3, 30), cfg)
    _ray_east(mapper, 1, 10)
    assert mapper.observed()[1, 10] == OCCUPIED and mapper.observed()[1, 9] == FREE  # one reading decides now
    # ... but not for good: scans that see through the cell clear it, after more scans than one hit weighs.
    needed = int(np.ceil((cfg.hit - cfg.free_threshold) / -cfg.miss))
    _ray_east(mapper, 1, 20, reps=needed - 1)
    assert mapper.observed()[1, 10] != FREE
    _ray_east(mapper, 1, 20)
    assert mapper.observed()[1, 10] == FREE and mapper.observed()[1, 20] == OCCUPIED
    # A cell held free (even at the clamp) becomes a wall with one hit: a wall wins over a free history.
    _ray_east(mapper, 1, None, reps=50)
    assert mapper.log_odds[1, 15] == cfg.lowest and mapper.observed()[1, 15] == FREE
    _ray_east(mapper, 1, 15)
    assert mapper.observed()[1, 15] == OCCUPIED
    # A confirmed wall (at the upper clamp) survives 8 scans through it, as documented, and no more than 10.
    _ray_east(mapper, 1, 15, reps=20)
    assert mapper.log_odds[1, 15] == np.float32(cfg.highest)
    _ray_east(mapper, 1, 25, reps=8)
    assert mapper.observed()[1, 15] == OCCUPIED
    _ray_east(mapper, 1, 25, reps=2)
    assert mapper.observed()[1, 15] == FREE


def test_a_ray_without_a_return_never_lowers_a_wall_and_clears_only_to_the_usable_range():
    # A reading that says "no return" (inf, range_max or above) or a return beyond the usable range clears free
    # space up to the usable range and stops at a cell the map holds occupied (a SICK LMS's no-echo code at 81.83 m
    # would otherwise clear 80 m through the building's walls).
    cfg = OccupancyConfig(usable_range_m=1.5)
    mapper = Mapper((3, 40), cfg)
    frame = MapFrame((3, 40), 0.1, (0.0, 0.0))
    pose = Pose2D(0.05, 0.15)
    east = lambda r: LaserScan(0.0, 0.1, 0.0, 3.0, np.array([r], np.float32))
    mapper.integrate_scan(frame, pose, east(1.0))  # a wall at column 10
    for reading in (np.inf, 3.0, 81.83, 2.5):  # no return, range_max, above it, a return beyond the usable range
        for _ in range(20):
            mapper.integrate_scan(frame, pose, east(reading))
        observed = mapper.observed()
        assert observed[1, 10] == OCCUPIED and (observed[1, :10] == FREE).all() and (observed[1, 11:] == -1).all()
    fresh = Mapper((3, 40), cfg)
    fresh.integrate_scan(frame, pose, east(np.inf))
    assert (fresh.observed()[1, :15] == FREE).all() and (fresh.observed()[1, 16:] == -1).all()  # 1.5 m, no more
    with pytest.raises(ValueError, match="usable_range_m must be a positive finite number"):
        OccupancyConfig(usable_range_m=0.0)


def test_a_hit_wins_over_the_misses_of_the_same_scan():
    mapper = Mapper((3, 30))
    # Two rays of one scan: one returns at column 10, the other passes through it (a grazing ray).
    mapper.integrate_ranges((1.5, 0.5), [0.0, 0.0], [9.5, np.inf], 20.0)
    assert mapper.log_odds[1, 10] == np.float32(OccupancyConfig().hit)
    assert mapper.log_odds[1, 5] == np.float32(OccupancyConfig().miss)  # one update per scan, not per ray


def test_a_wall_seen_from_two_poses_one_cell_apart_stays_a_wall(wall_room):
    grid = wall_room()
    frame = MapFrame(grid.shape, 0.1)
    mapper = Mapper(grid.shape)
    lidar = LidarConfig(n_rays=720, range_m=5.0)
    # The robot scans from (20, 10) and, believing itself there again, from (20, 11): the second scan is placed
    # one cell off, so it sees the wall one cell farther (through the true wall cells) than the first.
    at_a = World(grid, (20, 10), WorldConfig(lidar=lidar)).observe()
    at_b = World(grid, (20, 9), WorldConfig(lidar=lidar)).observe()
    believed_b = frame.centre_xy((20, 10))
    for _ in range(30):  # alternating, many times
        mapper.integrate_scan(frame, at_a.pose, at_a.scan)
        mapper.integrate_scan(frame, Pose2D(*believed_b), at_b.scan)
        observed = mapper.observed()
        assert np.all(observed[8:32, 25] == OCCUPIED)  # the true wall's face, every time
    assert np.all(observed[8:32, 26] == OCCUPIED)  # the misplaced scans' wall too: it is hit as often


def test_a_slam_map_replaces_the_line_of_sight_layer_and_carving_is_bounded_evidence():
    cfg = OccupancyConfig()
    mapper = Mapper((4, 6), cfg)
    slam = np.array([[-1, 0, 25, 26, 64, 65],
                     [100, 10, -1, -1, -1, -1],
                     [-1, -1, -1, -1, -1, -1],
                     [0, 0, 0, 0, 0, 0]], np.int8)
    mapper.set_line_of_sight(slam)
    expected = np.array([[UNKNOWN, FREE, FREE, UNKNOWN, UNKNOWN, OCCUPIED],
                         [OCCUPIED, FREE, UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN],
                         [UNKNOWN] * 6, [FREE] * 6], np.int8)
    np.testing.assert_array_equal(mapper.observed(), expected)
    carved = np.zeros((4, 6), bool)
    carved[0:3, :] = True
    for _ in range(10):
        mapper.merge_carved(carved)
    observed = mapper.observed()
    # Carving frees the unknown and the uncertain cells, never a wall held with confidence; its weight is bounded.
    assert observed[1, 0] == OCCUPIED and observed[0, 5] == OCCUPIED
    assert np.all(observed[2] == FREE) and observed[0, 3] == FREE and observed[0, 4] == FREE
    assert mapper.carve_log_odds.min() == np.float32(cfg.carve_lowest)
    np.testing.assert_array_equal(mapper.observed(include_carved=False), expected)
    np.testing.assert_array_equal(mapper.drivable(), expected == FREE)  # carved cells are not driven through
    assert mapper.drivable(include_carved=True)[2].all()
    # The next SLAM map replaces the line of sight again; the carving evidence stays.
    mapper.set_line_of_sight(np.full((4, 6), -1, np.int8))
    assert np.all(mapper.observed()[0:3] == FREE) and np.all(mapper.observed()[3] == UNKNOWN)
    with pytest.raises(ValueError, match="occupancy_percent"):
        mapper.set_line_of_sight(np.zeros((4, 5), np.int8))


def test_an_uncertain_cell_is_neither_free_nor_occupied():
    mapper = Mapper((3, 30))
    _ray_east(mapper, 1, 10)
    _ray_east(mapper, 1, 20, reps=6)  # 2.5 - 6 * 0.4 = 0.1: between the thresholds
    assert mapper.observed()[1, 10] == UNKNOWN
    assert not mapper.known()[1, 10] and not mapper.drivable()[1, 10]


def test_a_scan_without_valid_readings_leaves_the_map_as_it_was():
    mapper = Mapper((10, 10))
    frame = MapFrame((10, 10), 0.1)
    scan = LaserScan(0.0, 0.5, 0.2, 2.0, np.array([np.nan, 0.05, -np.inf], np.float32))
    mapper.integrate_scan(frame, Pose2D(0.55, 0.55), scan)
    assert not mapper.log_odds.any() and not mapper._touched.any()


def _integrate_world_scan(mapper, grid, pose, lidar=LidarConfig()):
    """Integrate the scan the simulated world measures at cell ``pose``."""
    world = World(grid, pose, WorldConfig(lidar=lidar))
    observation = world.observe()
    mapper.integrate_scan(world.frame, observation.pose, observation.scan)


def test_an_empty_room_is_fully_seen_from_anywhere(walled_box):
    grid = walled_box()
    mapper = Mapper(grid.shape)
    _integrate_world_scan(mapper, grid, (4, 13), LidarConfig(n_rays=720, range_m=5.0))
    observed = mapper.observed()
    # Every wall cell is hit except the four corners: a ray reaches one only through its shared corner point,
    # and the DDA steps into a side wall first.
    corners = np.zeros(grid.shape, bool)
    corners[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    np.testing.assert_array_equal(observed == OCCUPIED, grid.occupied & ~corners)
    np.testing.assert_array_equal(observed == UNKNOWN, corners)
    assert coverage(mapper.known(), grid.valid) == 1.0


def test_cells_beyond_the_range_stay_unknown(walled_box):
    grid = walled_box(41, 41)
    mapper = Mapper(grid.shape)
    _integrate_world_scan(mapper, grid, (20, 20), LidarConfig(n_rays=2000, range_m=1.0))  # 10 cells
    rows, cols = np.indices(grid.shape)
    distance = np.hypot(rows + 0.5 - 20.5, cols + 0.5 - 20.5)  # centre to cell centre, in cells
    observed = mapper.observed()
    assert np.all(observed[distance > 10 + np.sqrt(0.5)] == UNKNOWN)  # no cell is entered beyond 10 cells
    assert np.all(observed[distance < 9] == FREE)
    assert 0 < coverage(mapper.known(), grid.valid) < 0.3


def test_scans_accumulate_and_never_contradict_the_ground_truth():
    grid = load_map("50052750")
    mapper = Mapper(grid.shape)
    rng = np.random.default_rng(0)
    free = np.argwhere(grid.valid & ~grid.occupied)
    poses = [start_poses("50052750")[0]] + [tuple(free[i]) for i in rng.integers(len(free), size=4)]
    previous_known = mapper.known()
    coverages = []
    for pose in poses:
        _integrate_world_scan(mapper, grid, pose)
        known = mapper.known()
        assert np.all(known[previous_known])  # nothing is forgotten
        previous_known = known
        assert not np.any(mapper.seen_free & grid.occupied)
        assert np.all(grid.occupied[mapper.seen_wall])
        coverages.append(coverage(mapper.known(), grid.valid))
    assert coverages == sorted(coverages) and coverages[-1] > coverages[0]


def test_carving_is_kept_apart_and_never_overrides_a_seen_wall():
    walls = np.zeros((20, 20), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[1:19, 10] = True
    grid = OccupancyGrid(walls, ~walls, 0.1, "two rooms")
    mapper = Mapper(grid.shape)
    _integrate_world_scan(mapper, grid, (10, 5), LidarConfig(n_rays=360, range_m=5.0))
    observed = mapper.observed()
    assert np.all(observed[1:19, 1:10] == FREE) and np.all(observed[1:19, 11:19] == UNKNOWN)
    assert np.all(observed[5:15, 10] == OCCUPIED)
    line_of_sight = coverage(mapper.known(), grid.valid)
    # The left room (8 x 18 free cells plus the bounding walls is known) is 9/18 of the valid area.
    assert line_of_sight == pytest.approx(9 * 18 / (18 * 18 - 18))
    carved = np.zeros(grid.shape, bool)
    carved[5:8, 12:15] = True  # 9 hidden cells of the right room
    carved[6, 10] = True  # a wall already seen: stays a wall
    mapper.merge_carved(carved)
    mapper.merge_carved(np.zeros(grid.shape, bool))  # merging is cumulative
    assert coverage(mapper.known(include_carved=False), grid.valid) == line_of_sight
    assert coverage(mapper.known(), grid.valid) == pytest.approx(line_of_sight + 9 / (18 * 18 - 18))
    assert mapper.observed()[6, 10] == OCCUPIED and mapper.observed()[6, 13] == FREE
    assert mapper.observed(include_carved=False)[6, 13] == UNKNOWN
    assert mapper.carved[6, 13] and not mapper.seen_free[6, 13]


def test_bad_inputs_raise_value_error(walled_box):
    grid = walled_box()
    mapper = Mapper(grid.shape)
    scan = LaserScan(0.0, 0.1, 0.0, 2.0, np.full(10, np.inf, np.float32))
    with pytest.raises(ValueError, match="outside the map"):
        mapper.integrate_scan(MapFrame(grid.shape, 0.1), Pose2D(0.5, 2.5), scan)
    with pytest.raises(ValueError, match="the map frame has shape"):
        mapper.integrate_scan(MapFrame((5, 20), 0.1), Pose2D(0.5, 0.2), scan)
    with pytest.raises(ValueError, match="resolution_m must be positive"):
        MapFrame(grid.shape, 0.0)
    with pytest.raises(ValueError, match="carved"):
        mapper.merge_carved(np.zeros(grid.shape, np.uint8))
    with pytest.raises(ValueError, match="LidarConfig"):
        LidarConfig(n_rays=0)
    with pytest.raises(ValueError, match="LidarConfig"):
        LidarConfig(range_m=float("inf"))
    with pytest.raises(ValueError, match="shape"):
        Mapper((0, 5))


def test_invalid_readings_are_skipped_and_only_no_return_means_free(walled_box):
    grid = walled_box(30, 30)
    frame = MapFrame(grid.shape, 0.1)
    pose = Pose2D(*frame.centre_xy((15, 15)))
    # Four rays along +x, +y (up), -x, -y: a valid return, +inf (no return), NaN and a reading below range_min.
    scan = LaserScan(0.0, np.pi / 2, 0.2, 2.0, np.array([0.5, np.inf, np.nan, 0.05], np.float32))
    mapper = Mapper(grid.shape)
    mapper.integrate_scan(frame, pose, scan)
    assert mapper.seen_wall[15, 20] and mapper.seen_free[15, 16:20].all()  # return at 0.5 m: cells 16-19 free
    assert mapper.seen_free[1:15, 15].all()  # no return up: free to the range (2 m = 20 cells, the wall is nearer)
    assert not mapper.seen_free[15, :15].any() and not mapper.seen_free[16:, 15].any()  # NaN, too close: skipped


def test_cells_include_their_lower_edges_in_the_map_frame():
    frame = MapFrame((10, 10), 0.1, (1.0, 2.0))
    assert frame.cell_of(1.0, 2.0) == (9, 0)  # the lower-left corner is the bottom-left cell
    assert frame.cell_of(1.0 + 0.999, 2.0 + 0.999) == (0, 9)
    assert not frame.contains(frame.cell_of(1.0, 3.0)) and not frame.contains(frame.cell_of(2.0, 2.5))
    for rc in [(0, 0), (9, 9), (3, 7)]:
        assert frame.cell_of(*frame.centre_xy(rc)) == rc
    mapper = Mapper((10, 10))  # a robot on the lower edge scans from the bottom row
    mapper.integrate_scan(frame, Pose2D(1.55, 2.0), LaserScan(0.0, 0.5, 0.0, 0.5, np.full(4, np.inf, np.float32)))
    assert mapper.seen_free[9, 5]
