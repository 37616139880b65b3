import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, load_map, start_poses
from superex_deploy.messages import LaserScan, MapFrame, Pose2D
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.sim.metrics import coverage
from superex_deploy.sim.world import LidarConfig, World, WorldConfig


def _scan(mapper, grid, pose, lidar=LidarConfig()):
    """Integrate the scan the simulated world measures at cell ``pose``."""
    world = World(grid, pose, WorldConfig(lidar=lidar))
    observation = world.observe()
    mapper.integrate_scan(world.frame, observation.pose, observation.scan)


def _box(shape=(20, 20)):
    walls = np.zeros(shape, bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    return OccupancyGrid(walls, ~walls, 0.1, "box")


def test_an_empty_room_is_fully_seen_from_anywhere():
    grid = _box()
    mapper = Mapper(grid.shape)
    _scan(mapper, grid, (4, 13), LidarConfig(n_rays=720, range_m=5.0))
    observed = mapper.observed()
    # Every wall cell is hit except the four corners: a ray reaches one only through its shared corner point,
    # and the DDA steps into a side wall first.
    corners = np.zeros(grid.shape, bool)
    corners[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    np.testing.assert_array_equal(observed == OCCUPIED, grid.occupied & ~corners)
    np.testing.assert_array_equal(observed == UNKNOWN, corners)
    assert coverage(mapper.known(), grid.valid) == 1.0


def test_cells_beyond_the_range_stay_unknown():
    grid = _box((41, 41))
    mapper = Mapper(grid.shape)
    _scan(mapper, grid, (20, 20), LidarConfig(n_rays=2000, range_m=1.0))  # 10 cells
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
        _scan(mapper, grid, pose)
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
    _scan(mapper, grid, (10, 5), LidarConfig(n_rays=360, range_m=5.0))
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


def test_bad_inputs_raise_value_error():
    grid = _box()
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


def test_invalid_readings_are_skipped_and_only_no_return_means_free():
    grid = _box((30, 30))
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
