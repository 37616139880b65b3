"""The robot-facing API under a hostile integrator: each defect of the hostile pass, reproduced at its smallest,
must not come back (the same setup as the report: an 80 x 80 frame at 0.1 m, the robot at cell (40, 20), a SLAM map
that knows a walled patch open to the east)."""

import gc
import threading
import weakref

import numpy as np
import pytest

from superex_deploy.messages import (LaserScan, MapFrame, Observation, OccupancyGridMessage, Pose2D, PoseCovariance,
                                     SpadFrame)
from superex_deploy.onboard import Explorer, ExplorerConfig, PredictionSchedule, SpadProcessing
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.motion import MotionConfig
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.spad_types import SpadConfig

FRAME = MapFrame((80, 80), 0.1, (0.0, 0.0))
P = Pose2D(2.05, 3.95, 0.0)  # cell (40, 20)


def _new(frame=FRAME, **kwargs) -> Explorer:
    return Explorer(frame, make_planner("nearest"), ObservedAsPrediction(), **kwargs)


def _slam() -> np.ndarray:
    slam = np.full(FRAME.shape, -1, np.int8)
    slam[30:50, 5:35] = 0
    slam[30, 5:35] = slam[49, 5:35] = slam[30:50, 5] = 100
    return slam


def _map_step(explorer, grid, pose=P, stamp=0.0):
    return explorer.step(Observation(stamp, pose, None, occupancy_grid=OccupancyGridMessage.from_frame_grid(FRAME,
                                                                                                            grid)))


def _ring_scan(range_m: float, n: int = 360, range_max: float = 4.0) -> LaserScan:
    return LaserScan(0.0, 2 * np.pi / n, 0.05, range_max, np.full(n, range_m, np.float32))


# 1. SLAM-map mode and the robot's own cell


@pytest.mark.parametrize("spoil", ["occupied", "unknown"])
def test_a_slam_map_with_a_wall_or_nothing_under_the_robot_still_gives_a_goal(spoil):
    slam = _slam()
    if spoil == "occupied":
        slam[40, 20] = 100
    else:
        slam[39:42, 19:22] = -1
    command = _map_step(_new(), slam)
    assert not command.finished and command.goal_rc is not None


def test_a_robot_just_past_the_edge_of_a_stale_slam_map_still_gets_a_goal():
    # The patch ends at column 34; the robot stands on column 35, which the map leaves unknown.
    command = _map_step(_new(), _slam(), pose=Pose2D(3.55, 3.95, 0.0))
    assert not command.finished and command.goal_rc is not None


def test_alternating_scan_and_map_observations_never_say_finished_while_frontiers_remain():
    # The robot has driven (on its scans) just past the edge of what a stale SLAM map knows.
    explorer = _new()
    slam = _slam()
    edge = Pose2D(3.55, 3.95, 0.0)
    scan = _ring_scan(np.inf)  # nothing within 4 m: frontiers all round
    for t in range(6):
        if t % 2:
            command = _map_step(explorer, slam, pose=edge, stamp=float(t))
        else:
            command = explorer.step(Observation(float(t), edge, scan))
        assert not command.finished, t
        assert command.goal_rc is not None, t


# 2. "no return" reported as range_max


def test_ranges_at_range_max_are_no_return_and_build_no_walls():
    explorer = _new(MapFrame((200, 200), 0.1))
    command = explorer.step(Observation(0.0, Pose2D(10.05, 9.95), _ring_scan(4.0)))
    assert not command.finished and command.goal_rc is not None
    assert not np.any(explorer.observed == OCCUPIED)
    assert np.count_nonzero(explorer.observed == FREE) > 1000


def test_a_return_just_short_of_range_max_is_still_a_wall():
    explorer = _new(MapFrame((200, 200), 0.1))
    explorer.step(Observation(0.0, Pose2D(10.05, 9.95), _ring_scan(float(np.nextafter(np.float32(4.0),
                                                                                        np.float32(0.0))))))
    assert np.count_nonzero(explorer.observed == OCCUPIED) > 100


# 4. a scan given at a wrong pose and the footprint clearing


def test_a_scan_given_inside_a_confirmed_wall_does_not_erase_it():
    mapper = Mapper((40, 60))
    walls = (slice(15, 26), 40)
    mapper.log_odds[walls] = mapper.cfg.highest  # a wall confirmed by many scans
    mapper.log_odds[15:26, 25:40] = mapper.cfg.lowest
    frame = MapFrame((40, 60), 0.1)
    inside_wall = Pose2D(*frame.centre_xy((20, 40)))
    freed = mapper.integrate_scan(frame, inside_wall, _ring_scan(0.3, range_max=4.0), footprint_radius_cells=1.5)
    assert freed == 0
    assert np.all(mapper.seen_wall[19:22, 40])  # one scan's misses lower it, never past the occupied threshold


def test_footprint_clearing_still_removes_a_phantom_under_the_robot():
    mapper = Mapper((40, 60))
    frame = MapFrame((40, 60), 0.1)
    pose = Pose2D(*frame.centre_xy((20, 30)))
    mapper.integrate_scan(frame, pose, _ring_scan(1.0))
    mapper.log_odds[20, 31] = mapper.cfg.hit  # a phantom hit once, next to the robot
    freed = mapper.integrate_scan(frame, pose, _ring_scan(1.0), footprint_radius_cells=1.5)
    assert freed == 1 and mapper.seen_free[20, 31]


# 5. float32 resolutions of real nav_msgs/OccupancyGrid messages


def test_a_float32_resolution_is_the_frames_resolution():
    slam = _slam()
    message = OccupancyGridMessage.from_frame_grid(FRAME, slam)
    real = OccupancyGridMessage(resolution_m=float(np.float32(0.1)), width=message.width, height=message.height,
                                origin_xy=message.origin_xy, data=message.data)
    assert np.array_equal(real.in_frame(FRAME), slam)


def test_a_frame_built_from_a_float32_resolution_accepts_a_far_origin():
    resolution = float(np.float32(0.05))
    frame = MapFrame((100, 100), resolution, (0.0, 0.0))
    far = OccupancyGridMessage(resolution_m=resolution, width=10, height=10, origin_xy=(-250.0, -250.0),
                               data=np.zeros(100, np.int8))
    assert far.in_frame(frame).shape == (100, 100) and far.lattice_offset(frame) == (-5000, -5000)
    # Off the lattice, or at another resolution: not copied cell for cell but resampled.
    shifted = OccupancyGridMessage(resolution_m=resolution, width=10, height=10, origin_xy=(0.02, 0.0),
                                   data=np.zeros(100, np.int8))
    with pytest.raises(ValueError, match="not a whole number of cells"):
        shifted.lattice_offset(frame)
    assert np.count_nonzero(shifted.in_frame(frame) == 0) == 100
    coarse = OccupancyGridMessage(resolution_m=0.1, width=10, height=10, origin_xy=(0.0, 0.0),
                                  data=np.zeros(100, np.int8))
    with pytest.raises(ValueError, match="resolution .* differs"):
        coarse.lattice_offset(frame)
    assert np.count_nonzero(coarse.in_frame(frame) == 0) == 400


# 7. a refused SPAD frame leaves nothing integrated


def test_a_refused_spad_frame_leaves_the_scan_unintegrated():
    explorer = _new(spad_processing=SpadProcessing(sensor=SpadConfig(n_rays=8)))
    wrong = SpadFrame.from_dense(np.linspace(0, 1, 8), SpadConfig().bin_width_s, np.zeros((8, 3), np.float32))
    with pytest.raises(ValueError, match="bins per ray"):
        explorer.step(Observation(0.0, P, _ring_scan(1.0), spad=wrong))
    assert explorer.steps == 0 and not np.any(explorer.mapper.log_odds)
    command = explorer.step(Observation(0.0, P, _ring_scan(1.0)))  # the retry integrates the scan once
    once = _new()
    once.step(Observation(0.0, P, _ring_scan(1.0)))
    assert command.step == 0 and np.array_equal(explorer.mapper.log_odds, once.mapper.log_odds)


# 8. close() racing step()


def test_close_racing_step_raises_only_the_closed_error():
    failures = []
    for trial in range(12):
        explorer = _new(cfg=ExplorerConfig(prediction=PredictionSchedule("free")))
        explorer.step(Observation(0.0, P, _ring_scan(1.0)))
        start = threading.Barrier(2)

        def stepper():
            start.wait()
            for t in range(1, 30):
                try:
                    explorer.step(Observation(float(t), P, _ring_scan(1.0)))
                except RuntimeError as error:
                    if str(error) != "this explorer was closed":
                        failures.append(repr(error))
                    return
                except Exception as error:  # anything else leaks the race
                    failures.append(repr(error))
                    return

        thread = threading.Thread(target=stepper)
        thread.start()
        start.wait()
        explorer.close()
        thread.join(timeout=60)
        assert not thread.is_alive()
        with pytest.raises(RuntimeError, match="this explorer was closed"):
            explorer.step(Observation(99.0, P, _ring_scan(1.0)))
        explorer.close()  # twice is harmless
    assert not failures, failures


# 9. a frame too fine for the motion settings


def test_a_frame_too_fine_for_the_motion_settings_is_refused_at_construction():
    fine = ExplorerConfig(motion=MotionConfig(planning_cell_m=0.001))
    with pytest.raises(ValueError, match="MAX_WALL_REACH_CELLS"):
        _new(MapFrame((50, 50), 0.001), cfg=fine)
    # Planned on blocks of 0.1 m (the default), the same grid is not too fine.
    assert _new(MapFrame((50, 50), 0.001)).planning_grid.factor == 100


# 11. explorers dropped without close()


def test_an_explorer_dropped_without_close_stops_its_worker_at_once():
    gc.disable()
    try:
        before = threading.active_count()
        for _ in range(5):
            explorer = _new(cfg=ExplorerConfig(prediction=PredictionSchedule("free")))
            explorer.step(Observation(0.0, P, _ring_scan(1.0)))
            ref = weakref.ref(explorer)
            del explorer
            assert ref() is None  # no reference cycle: freed without the garbage collector
        assert threading.active_count() <= before
    finally:
        gc.enable()


# 12. stamps going backwards


def test_stamps_that_go_backwards_are_refused_before_anything_changes():
    explorer = _new()
    explorer.step(Observation(10.0, P, _ring_scan(1.0)))
    before = explorer.mapper.log_odds.copy()
    with pytest.raises(ValueError, match="must not go backwards"):
        explorer.step(Observation(5.0, P, _ring_scan(2.0)))
    assert explorer.steps == 1 and np.array_equal(explorer.mapper.log_odds, before)
    command = explorer.step(Observation(10.0, P, _ring_scan(1.0)))  # the same stamp again is fine
    assert command.prediction_age_s is None or command.prediction_age_s >= 0.0


# 13. pose covariances


def test_a_covariance_that_is_not_positive_semidefinite_is_refused():
    matrix = np.array([[1e-2, 0.0, 0.0], [0.0, 1e-2, 0.02], [0.0, 0.02, 1e-4]])
    assert np.linalg.eigvalsh(matrix)[0] < -0.01
    with pytest.raises(ValueError, match="positive semi-definite, got an eigenvalue of -0.0"):
        PoseCovariance(matrix)


def test_a_float32_computed_covariance_is_accepted_and_symmetrised():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3)).astype(np.float32) * np.float32(1e-2)
    matrix = (a @ a.T).astype(np.float64)
    matrix[0, 1] += 1e-11
    covariance = PoseCovariance(matrix)
    assert np.array_equal(covariance.matrix, covariance.matrix.T)


def test_a_nan_covariance_names_the_nan():
    matrix = np.eye(3) * 1e-4
    matrix[2, 2] = np.nan
    with pytest.raises(ValueError, match="must be finite, got .*nan"):
        PoseCovariance(matrix)
    with pytest.raises(ValueError, match="must be symmetric"):
        PoseCovariance(np.array([[1e-4, 1e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]]))


# 14. clockwise scanners


def test_a_clockwise_scan_is_the_same_rays_as_its_counter_clockwise_twin():
    rng = np.random.default_rng(3)
    ranges = rng.uniform(0.3, 3.0, 181).astype(np.float32)
    clockwise = LaserScan(np.pi / 2, -np.pi / 180, 0.05, 4.0, ranges, angle_max=-np.pi / 2)
    counter = LaserScan(-np.pi / 2, np.pi / 180, 0.05, 4.0, ranges[::-1].copy())
    assert clockwise.angle_increment > 0
    np.testing.assert_allclose(clockwise.angles(), counter.angles(), atol=1e-6)
    assert np.array_equal(clockwise.ranges, counter.ranges)
    maps = []
    for scan in (clockwise, counter):
        explorer = _new()
        explorer.step(Observation(0.0, P, scan))
        maps.append(explorer.observed)
    assert np.array_equal(*maps)
    with pytest.raises(ValueError, match="angle_increment must not be 0"):
        LaserScan(0.0, 0.0, 0.05, 4.0, ranges)


# finished on the observations' clock


def _closed_room() -> np.ndarray:
    room = np.full(FRAME.shape, -1, np.int8)
    room[30:50, 5:35] = 0
    room[30, 5:35] = room[49, 5:35] = room[30:50, 5] = room[30:50, 34] = 100
    return room


def test_finished_waits_for_finish_after_s_without_a_frontier_and_restarts_when_one_returns():
    explorer = _new(cfg=ExplorerConfig(finish_after_s=2.0))
    closed, open_ = _closed_room(), _slam()
    sequence = [(0.0, closed, False), (1.0, closed, False), (1.5, open_, False), (2.5, closed, False),
                (4.0, closed, False), (4.5, closed, True), (5.0, closed, True)]
    for stamp, grid, finished in sequence:
        command = _map_step(explorer, grid, stamp=stamp)
        assert command.finished is finished, stamp
        assert command.goal_rc is None or grid is open_


def test_by_default_finished_comes_five_seconds_after_the_last_frontier():
    explorer = _new()
    assert not _map_step(explorer, _closed_room(), stamp=0.0).finished
    assert not _map_step(explorer, _closed_room(), stamp=4.9).finished
    assert _map_step(explorer, _closed_room(), stamp=5.0).finished
    assert _map_step(_new(cfg=ExplorerConfig().for_simulation()), _closed_room()).finished  # the simulated rule
    with pytest.raises(ValueError, match="finish_after_s must be a finite number of seconds >= 0"):
        ExplorerConfig(finish_after_s=-1.0)
