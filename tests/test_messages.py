"""The robot-data messages: a SLAM map (nav_msgs/OccupancyGrid) and a pose covariance, against hand-built cases."""

import numpy as np
import pytest

from superex_deploy.messages import MapFrame, Observation, OccupancyGridMessage, Pose2D, PoseCovariance
from tests.naive import naive_in_frame


def test_a_frame_grid_round_trips_through_the_message():
    frame = MapFrame(shape=(3, 4), resolution_m=0.5, origin_xy=(-1.0, 2.0))
    grid = np.arange(12, dtype=np.int8).reshape(3, 4)
    grid[0, 0] = -1
    message = OccupancyGridMessage.from_frame_grid(frame, grid)
    # ROS row 0 is the bottom row: our last row.
    assert message.data[:4].tolist() == grid[2].tolist()
    np.testing.assert_array_equal(message.in_frame(frame), grid)


def test_a_shifted_message_lands_on_the_right_cells_and_the_rest_is_unknown():
    frame = MapFrame(shape=(4, 4), resolution_m=1.0, origin_xy=(0.0, 0.0))
    # A 2 x 2 message whose lower-left corner is at (x, y) = (1, 2): frame columns 1-2, rows from the bottom 2-3,
    # i.e. frame rows (top = 0) 1 and 0.
    data = np.array([10, 20, 30, 40], np.int8)  # bottom row 10 20, top row 30 40
    message = OccupancyGridMessage(resolution_m=1.0, width=2, height=2, origin_xy=(1.0, 2.0), data=data)
    out = message.in_frame(frame)
    expected = np.full((4, 4), -1, np.int8)
    expected[0, 1:3] = [30, 40]
    expected[1, 1:3] = [10, 20]
    np.testing.assert_array_equal(out, expected)
    # Partly outside: only the overlap is kept.
    outside = OccupancyGridMessage(resolution_m=1.0, width=2, height=2, origin_xy=(3.0, -1.0), data=data)
    expected = np.full((4, 4), -1, np.int8)
    expected[3, 3] = 30
    np.testing.assert_array_equal(outside.in_frame(frame), expected)
    far = OccupancyGridMessage(resolution_m=1.0, width=2, height=2, origin_xy=(40.0, 0.0), data=data)
    assert (far.in_frame(frame) == -1).all()


def test_a_finer_message_is_max_pooled_onto_the_frame():
    # A 0.05 m map of 4 x 4 cells on a 0.1 m frame of 2 x 2: a frame cell takes the largest of its four (a wall
    # in any of them; unknown only where all four are).
    rows_from_bottom = np.array([[0, 0, -1, -1],
                                 [0, 100, -1, -1],
                                 [-1, 0, 30, 0],
                                 [-1, -1, 0, 0]], np.int8)
    message = OccupancyGridMessage(resolution_m=0.05, width=4, height=4, origin_xy=(0.0, 0.0),
                                   data=rows_from_bottom.reshape(-1))
    out = message.in_frame(MapFrame(shape=(2, 2), resolution_m=0.1))
    np.testing.assert_array_equal(out, [[0, 30], [100, -1]])  # row 0 at the top
    again = message.in_frame(MapFrame(shape=(2, 2), resolution_m=0.1))  # the same map at the next step: kept
    assert again is out and not out.flags.writeable
    assert message.in_frame(MapFrame(shape=(2, 3), resolution_m=0.1)).shape == (2, 3)  # another frame: anew
    with pytest.raises(ValueError, match="resolution 0.05 m differs"):
        message.lattice_offset(MapFrame(shape=(2, 2), resolution_m=0.1))


def test_a_coarser_message_or_one_off_the_lattice_is_sampled_at_the_frame_cells_centres():
    message = OccupancyGridMessage(resolution_m=0.2, width=2, height=1, origin_xy=(0.0, 0.0),
                                   data=np.array([100, 0], np.int8))
    out = message.in_frame(MapFrame(shape=(3, 5), resolution_m=0.1))
    np.testing.assert_array_equal(out, [[-1, -1, -1, -1, -1], [100, 100, 0, 0, -1], [100, 100, 0, 0, -1]])
    shifted = OccupancyGridMessage(resolution_m=0.1, width=2, height=1, origin_xy=(0.03, 0.0),
                                   data=np.array([100, 0], np.int8))
    np.testing.assert_array_equal(shifted.in_frame(MapFrame(shape=(1, 3), resolution_m=0.1)), [[100, 0, -1]])
    with pytest.raises(ValueError, match="whole number of cells"):
        shifted.lattice_offset(MapFrame(shape=(1, 3), resolution_m=0.1))


def test_resampling_matches_its_slow_twin_over_random_messages():
    rng = np.random.default_rng(0)
    for _ in range(60):
        res_m = float(rng.choice([0.025, 0.05, 0.07, 0.1, 0.2, 0.3]))
        width, height = (int(n) for n in rng.integers(1, 30, size=2))
        data = rng.choice(np.array([-1, 0, 50, 100], np.int8), size=width * height, p=[0.4, 0.4, 0.1, 0.1])
        message = OccupancyGridMessage(res_m, width, height, tuple(float(v) for v in rng.uniform(-1, 1, size=2)), data)
        frame = MapFrame(shape=(int(rng.integers(1, 25)), int(rng.integers(1, 25))), resolution_m=0.1,
                         origin_xy=(-1.0, -1.0))
        np.testing.assert_array_equal(message.in_frame(frame), naive_in_frame(message, frame))


@pytest.mark.parametrize("kwargs, message", [
    (dict(data=np.zeros(3, np.int8)), r"int8 \[height \* width\]"),
    (dict(data=np.zeros(4, np.int16)), "int8"),
    (dict(data=np.array([0, 0, 0, 101], np.int8)), "0..100"),
    (dict(data=np.array([0, 0, 0, -2], np.int8)), "0..100"),
    (dict(width=0), "width must be a positive integer"),
    (dict(height=2.0), "height must be a positive integer"),
    (dict(resolution_m=float("nan")), "resolution_m must be finite"),
    (dict(origin_xy=(0.0,)), "origin_xy"),
])
def test_bad_occupancy_grids_are_refused(kwargs, message):
    base = dict(resolution_m=0.1, width=2, height=2, origin_xy=(0.0, 0.0), data=np.zeros(4, np.int8))
    base.update(kwargs)
    with pytest.raises(ValueError, match=message):
        OccupancyGridMessage(**base)


def test_the_message_keeps_its_own_copy():
    data = np.zeros(4, np.int8)
    message = OccupancyGridMessage(resolution_m=0.1, width=2, height=2, origin_xy=(0.0, 0.0), data=data)
    data[0] = 100
    assert message.data[0] == 0
    with pytest.raises(ValueError):
        message.data[0] = 1


def test_pose_covariance_from_sigmas_and_from_ros():
    cov = PoseCovariance.from_sigmas(0.05, np.deg2rad(1.0))
    assert cov.sigma_xy_m == pytest.approx(0.05)
    assert cov.sigma_yaw_rad == pytest.approx(np.deg2rad(1.0))
    ros = np.zeros((6, 6))
    ros[0, 0], ros[1, 1], ros[5, 5], ros[0, 1], ros[1, 0] = 0.04, 0.01, 0.0009, 0.01, 0.01
    cov = PoseCovariance.from_ros(ros.reshape(-1))
    np.testing.assert_array_equal(cov.matrix, [[0.04, 0.01, 0.0], [0.01, 0.01, 0.0], [0.0, 0.0, 0.0009]])
    # The worst direction of the (x, y) block, not the larger diagonal entry.
    assert cov.sigma_xy_m == pytest.approx(np.sqrt(np.linalg.eigvalsh([[0.04, 0.01], [0.01, 0.01]])[-1]))
    assert cov.sigma_yaw_rad == pytest.approx(0.03)


@pytest.mark.parametrize("matrix, message", [
    (np.eye(2), r"\[3, 3\]"),
    (np.diag([1.0, -1.0, 1.0]), "non-negative"),
    (np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "symmetric"),
    (np.diag([1.0, np.nan, 1.0]), "finite"),
])
def test_bad_pose_covariances_are_refused(matrix, message):
    with pytest.raises(ValueError, match=message):
        PoseCovariance(matrix)


def test_an_observation_needs_a_scan_or_a_map(laser_scan):
    pose, scan = Pose2D(0.5, 0.5), laser_scan(np.ones(4), angle_increment=0.5, dtype=np.float32)
    with pytest.raises(ValueError, match="scan must be a LaserScan"):
        Observation(stamp_s=0.0, pose=pose, scan=None)
    grid = OccupancyGridMessage(resolution_m=0.1, width=2, height=2, origin_xy=(0.0, 0.0), data=np.zeros(4, np.int8))
    assert Observation(stamp_s=0.0, pose=pose, scan=None, occupancy_grid=grid).scan is None
    with pytest.raises(ValueError, match="pose_covariance must be a PoseCovariance"):
        Observation(stamp_s=0.0, pose=pose, scan=scan, pose_covariance=np.eye(3))
    with pytest.raises(ValueError, match="occupancy_grid must be an OccupancyGridMessage"):
        Observation(stamp_s=0.0, pose=pose, scan=scan, occupancy_grid=np.zeros((2, 2), np.int8))
