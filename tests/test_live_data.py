"""``finished``, the return to the start, bounds and blacklisting on the data a running robot produces: a SLAM map
published every few seconds, a log-odds map whose wall faces flicker through the unknown band, a transient map, a
robot that does not move, a clock that stands still, a gmapping-style fixed map (issue 41's defects of 0.2.0; each
test here fails on 0.2.0).

"Left to explore" is judged against the truth: the largest part of the floor the robot could drive into from its
start (walls grown by its radius) that the explorer's map has not seen (:func:`unseen_reachable_m2`)."""

import warnings

import numpy as np
import pytest
from scipy import ndimage

from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import (DONE, EXPLORING, NO_REACHABLE_FRONTIER, Command, MapFrame, Observation,
                                     OccupancyGridMessage, Pose2D)
from superex_deploy.onboard import Explorer, ExplorerConfig, GoalPolicy
from superex_deploy.onboard.mapping.growth import MapGrowth
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.motion import MotionConfig, planning_map
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, OCCUPIED
from superex_deploy.sim.world import LidarConfig, World, WorldConfig

LEFT_M2 = 0.25  # a square of the finish frontier size (0.5 m): something is left to explore


def _rooms(rows: int = 80, cols: int = 80, door=(35, 45)) -> OccupancyGrid:
    """An 8 m x 8 m box at 0.1 m split by a wall at the middle column with a door (rows ``door``)."""
    walls = np.zeros((rows, cols), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:, cols // 2] = True
    walls[door[0]:door[1], cols // 2] = False
    return OccupancyGrid(walls, ~walls, 0.1, "two rooms")


def _reachable(grid: OccupancyGrid, start) -> np.ndarray:
    truth = np.where(grid.occupied, OCCUPIED, FREE).astype(np.int8)
    return np.isfinite(planning_map(truth, start, grid.resolution_m, MotionConfig()).travel_cost) & grid.valid


def unseen_reachable_m2(reachable: np.ndarray, known: np.ndarray, resolution_m: float) -> float:
    """The area of the largest 8-connected part of ``reachable`` that ``known`` does not hold (square metres)."""
    labels, count = ndimage.label(reachable & ~known, structure=np.ones((3, 3), bool))
    return 0.0 if count == 0 else float(np.bincount(labels.ravel())[1:].max()) * resolution_m ** 2


def _explorer(frame, **cfg) -> Explorer:
    return Explorer(frame, make_planner("nearest"), ObservedAsPrediction(), cfg=ExplorerConfig(**cfg))


def _l_corridor() -> OccupancyGrid:
    """A 1 m wide corridor 6 m east from the start, then 5 m south into a 3 m x 3 m room, at 0.1 m."""
    walls = np.ones((120, 100), bool)
    walls[5:15, 5:75] = False  # the corridor east
    walls[5:80, 65:75] = False  # south
    walls[80:110, 55:85] = False  # the room
    return OccupancyGrid(walls, ~walls, 0.1, "l-corridor")


def _slam_message(frame, slam: Mapper) -> OccupancyGridMessage:
    codes = slam.observed(include_carved=False)
    return OccupancyGridMessage.from_frame_grid(
        frame, np.where(codes == OCCUPIED, 100, np.where(codes == FREE, 0, -1)).astype(np.int8))


def test_a_stale_slam_map_does_not_end_the_run_while_something_is_left():
    # 0.2.0 (defaults): the goal at the corner was reached before the next map could show what lies round it, it
    # was given up, nothing else was offered, and the run said finished with the room unseen.
    grid = _l_corridor()
    world = World(grid, (10, 10), WorldConfig(lidar=LidarConfig(range_m=4.0)))
    reachable, slam = _reachable(grid, world.pose_rc), Mapper(grid.shape)
    explorer = _explorer(world.frame)
    message, finished_at, left = None, None, None
    for step in range(800):
        observation = world.observe()
        slam.integrate_scan(world.frame, world.pose, observation.scan)
        if step % 40 == 0:  # the SLAM map every 4 s; the same message is handed over until the next
            message = _slam_message(world.frame, slam)
        command = explorer.step(Observation(observation.stamp_s, observation.pose, None, occupancy_grid=message))
        left = unseen_reachable_m2(reachable, slam.known(include_carved=False), 0.1)
        if command.finished:
            finished_at = step
            break
        world.apply(command)
    assert finished_at is not None and left < LEFT_M2, (finished_at, left)


def test_a_wall_face_flickering_through_the_unknown_band_does_not_keep_a_run_alive():
    # 0.2.0 with a finish delay: a closed room whose one wall-face cell comes and goes (a log-odds cell near the
    # unknown band) made a one-cell frontier every other second, each restarting the timer: never finished.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    closed = np.full(frame.shape, -1, np.int8)
    closed[35:46, 9:72] = 100
    closed[36:45, 10:71] = 0
    flicker = closed.copy()
    flicker[35, 39:42] = -1  # three cells of the wall unknown again: the free cells below are a frontier
    maps = [OccupancyGridMessage.from_frame_grid(frame, grid) for grid in (closed, flicker)]
    explorer = _explorer(frame, finish_after_s=5.0)
    pose = Pose2D(*frame.centre_xy((40, 30)))
    finished = [explorer.step(Observation(0.1 * t, pose, None, occupancy_grid=maps[(t // 10) % 2])).finished
                for t in range(200)]
    assert not any(finished[:50]) and all(finished[50:60])  # 5 s after the last frontier worth the name


def test_a_robot_standing_near_a_doorway_it_has_not_seen_through_is_not_finished():
    # A robot's recording, open-loop: the robot stops 0.8 m from a doorway, at an angle from which it cannot see
    # the room behind. 0.2.0 took the goal as reached, gave its frontier up and said finished 5 s later.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    slam = np.full(frame.shape, -1, np.int8)
    slam[30:50, 10:40] = 0  # the room the robot is in
    slam[29, 9:41] = slam[50, 9:41] = slam[29:51, 9] = slam[29:51, 40] = 100
    slam[34:42, 40] = 0  # a 0.8 m doorway east, the room behind unknown
    message = OccupancyGridMessage.from_frame_grid(frame, slam)
    explorer = _explorer(frame, finish_after_s=5.0)
    far = explorer.step(Observation(0.0, Pose2D(*frame.centre_xy((44, 15))), None, occupancy_grid=message))
    assert far.goal_rc is not None and far.goal_rc[1] == 40  # the doorway, chosen from afar
    pose = Pose2D(*frame.centre_xy((45, 36)))  # then 0.9 m from its goal cell, south of the doorway
    commands = [explorer.step(Observation(0.1 * t, pose, None, occupancy_grid=message)) for t in range(1, 120)]
    assert not any(c.finished for c in commands)
    assert all(c.goal_rc == far.goal_rc for c in commands)  # driven onto, not given up


def test_the_return_runs_once_the_default_finish_delay_has_passed():
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.sim.exploration import ExplorationConfig

    cfg = ExplorationConfig(lidar=LidarConfig(range_m=10.0), explorer=ExplorerConfig(return_to_start=True),
                            iou_every=0)
    result = run_episode(_rooms(), (20, 10), make_planner("nearest"), ObservedAsPrediction(), steps=1000, cfg=cfg)
    assert result.finished and result.reason == "back at the start"
    assert np.hypot(*(result.poses[-1] - np.array((20, 10)))) <= 10



def test_a_clipped_frontier_keeps_a_reachable_goal_inside_the_bounds():
    # 0.2.0: the region cut to the two cells next to the wall took the one by the wall as its goal (inside the
    # robot's clearance: unreachable), dropped it, and the run said done with the corridor's end unseen.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    slam = np.full(frame.shape, -1, np.int8)
    slam[36:45, 10:71] = 0
    slam[35, 9:72] = slam[45, 9:72] = slam[36:45, 10] = 100
    bounds = ((5.5, 4.2), (7.5, 4.2), (7.5, 5.0), (5.5, 5.0))  # rows 36-37 of the corridor's open end, column 70
    explorer = _explorer(frame, bounds=bounds, finish_after_s=0.0)
    x, y = frame.centre_xy((37, 60))
    command = explorer.step(Observation(0.0, Pose2D(x, y), None,
                                        occupancy_grid=OccupancyGridMessage.from_frame_grid(frame, slam)))
    assert command.status == EXPLORING and command.goal_rc == (37, 70) and not command.finished


@pytest.mark.parametrize("side_m", [0.02, 0.3])
def test_a_polygon_smaller_than_the_robot_is_refused(side_m):
    # 0.2.0 accepted both, and the run ended at its first step.
    square = ((1.0, 1.0), (1.0 + side_m, 1.0), (1.0 + side_m, 1.0 + side_m), (1.0, 1.0 + side_m))
    with pytest.raises(ValueError, match="the exploration bounds are smaller than the robot"):
        ExplorerConfig(bounds=square)
    ExplorerConfig(bounds=((0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5)))  # a 0.5 m square holds it


def _corridor_map(frame, closed: bool) -> OccupancyGridMessage:
    slam = np.full(frame.shape, -1, np.int8)
    slam[36:45, 10:71] = 0
    slam[35, 9:72] = slam[45, 9:72] = 100
    if closed:
        slam[36:45, 9] = slam[36:45, 71] = 100
    return OccupancyGridMessage.from_frame_grid(frame, slam)


def test_a_goal_whose_frontier_is_gone_is_let_go_and_the_run_finishes_open_loop():
    # 0.2.0: open-loop (the robot never moves) the first map's goal was kept for the whole bag, with no frontier
    # left, and the run never said finished.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    explorer = _explorer(frame)
    pose = Pose2D(*frame.centre_xy((40, 30)))
    assert explorer.step(Observation(0.0, pose, None, occupancy_grid=_corridor_map(frame, False))).goal_rc is not None
    closed = _corridor_map(frame, True)
    commands = [explorer.step(Observation(t, pose, None, occupancy_grid=closed)) for t in (0.1, 2.0, 5.1)]
    assert commands[0].goal_rc is None and commands[0].status == NO_REACHABLE_FRONTIER
    assert [c.finished for c in commands] == [False, False, True]


def test_every_reachable_frontier_blacklisted_is_said_and_stored_once():
    # 0.2.0: "no frontier reachable" when a frontier walled off from the robot was never blacklisted.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    slam = np.full(frame.shape, -1, np.int8)
    slam[36:45, 10:71] = 0
    slam[35, 9:72] = slam[45, 9:72] = 100
    slam[36:45, 20] = 100  # the west end (column 10) walled off from the robot
    message = OccupancyGridMessage.from_frame_grid(frame, slam)
    explorer = _explorer(frame, goal_policy=GoalPolicy(no_progress_s=2.0))
    pose = Pose2D(*frame.centre_xy((40, 50)))
    commands = [explorer.step(Observation(float(t), pose, None, occupancy_grid=message)) for t in range(10)]
    assert commands[0].goal_rc[1] >= 68
    assert commands[3].goal_rc is None and commands[3].reason == "every frontier blacklisted"
    assert commands[9].finished and commands[9].reason == "every frontier blacklisted"
    assert len(explorer.mission.tracker.blacklist) == 1


def test_stamps_that_never_advance_are_warned_about():
    # 0.2.0: 300 steps with one stamp and a finish delay, no word.
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    explorer = _explorer(frame, finish_after_s=5.0)
    pose = Pose2D(*frame.centre_xy((40, 30)))
    message = _corridor_map(frame, True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(30):
            explorer.step(Observation(12.0, pose, None, occupancy_grid=message))
    said = [w for w in caught if issubclass(w.category, RuntimeWarning) and "have not advanced" in str(w.message)]
    assert len(said) == 1 and explorer.clock.stalled
    explorer.step(Observation(12.1, pose, None, occupancy_grid=message))
    assert not explorer.clock.stalled


def test_a_fixed_size_slam_map_grows_the_explorer_to_its_known_cells_only():
    # 0.2.0: a gmapping-style map (a fixed square, a few metres known) grew the explorer to the whole square.
    resolution, side = 0.05, 2000  # 100 m at 0.05 m
    slam = np.full((side, side), -1, np.int8)
    slam[980:1060, 980:1060] = 0  # 4 m x 4 m known around the robot
    message = OccupancyGridMessage.from_frame_grid(MapFrame((side, side), resolution, (-50.0, -50.0)), slam)
    frame = MapFrame.around(1.0, 1.0, resolution, size_m=4.0, lattice_xy=(-50.0, -50.0))
    explorer = _explorer(frame, growth=MapGrowth())
    explorer.step(Observation(0.0, Pose2D(1.0, 1.0), None, occupancy_grid=message))
    rows, cols = explorer.frame.shape
    assert rows * cols < 400 * 400  # 4 m known plus the growth's margin and chunk, not 100 m
