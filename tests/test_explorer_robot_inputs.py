"""A robot's inputs: a SLAM map in place of the scan (the explorer's own map given back as a SLAM map chooses the
same goals), the pose covariance (with one, paths cross only cells the line of sight holds free), and a recording
of both that replays with the same goals."""

import json

import numpy as np
import pytest

from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame, Observation, OccupancyGridMessage, Pose2D, PoseCovariance
from superex_deploy.onboard import Explorer, ExplorerConfig, SpadProcessing
from superex_deploy.onboard.planning.motion import MotionConfig
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.pipeline import PROFILES, make_sensing
from superex_deploy.recording import EpisodeRecorder, read_recording
from superex_deploy.recording.metadata import recording_metadata
from superex_deploy.sim.world import World, WorldConfig
from superex_deploy.spad_types import SpadConfig

MAP = "50052750"


def _as_slam_map(frame, observed):
    """The explorer's map as a ``nav_msgs/OccupancyGrid``: 0 free, 100 wall, -1 unknown."""
    percent = np.where(observed == OCCUPIED, 100, np.where(observed == FREE, 0, -1)).astype(np.int8)
    return OccupancyGridMessage.from_frame_grid(frame, percent)


def _drive(world, explorer, steps, observe=None, after=None):
    """Run ``steps`` steps; ``observe(observation) -> observation`` may change what the explorer gets; returns the
    commands' (goal, new_goal, finished, path)."""
    out = []
    for _ in range(steps):
        observation = world.observe()
        if observe is not None:
            observation = observe(observation)
        command = explorer.step(observation)
        if after is not None:
            after(observation, command, explorer)
        out.append((command.goal_rc, command.new_goal, command.finished, command.path_rc.tolist()))
        if command.finished:
            break
        world.apply(command)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("planner,spad", [("nearest", False), ("mapex", True)])
def test_a_slam_map_equal_to_the_explorers_own_map_gives_the_same_goals(planner, spad):
    grid = load_map(MAP)
    start = start_poses(MAP)[1]
    sensing = make_sensing("observed", spad, 0, profile=PROFILES["full"])
    world = World(grid, start, WorldConfig(spad=None if sensing is None else sensing.spad))
    own = Explorer(world.frame, make_planner(planner), ObservedAsPrediction(),
                   spad_processing=None if sensing is None else sensing.processing(), seed=4)
    recorded = []

    def keep(observation, command, explorer):
        # The line-of-sight map after this step's scan (carving is the SPAD processing's, redone below).
        recorded.append((observation, _as_slam_map(explorer.frame, explorer.mapper.observed(include_carved=False))))

    commands = _drive(world, own, 40 if spad else 80, after=keep)
    assert sum(c[1] for c in commands) >= 2  # several goals were chosen

    second_sensing = make_sensing("observed", spad, 0, profile=PROFILES["full"])
    fed = Explorer(world.frame, make_planner(planner), ObservedAsPrediction(),
                   spad_processing=None if second_sensing is None else second_sensing.processing(), seed=4)
    replayed = []
    for observation, slam in recorded:
        command = fed.step(Observation(observation.stamp_s, observation.pose, None, spad=observation.spad,
                                       occupancy_grid=slam))
        replayed.append((command.goal_rc, command.new_goal, command.finished, command.path_rc.tolist()))
    assert replayed == commands
    np.testing.assert_array_equal(fed.observed, own.observed)
    np.testing.assert_array_equal(fed.mapper.carved, own.mapper.carved)


def test_a_slam_map_of_another_resolution_is_resampled_and_may_cover_another_area():
    grid = load_map(MAP)
    world = World(grid, start_poses(MAP)[0])
    explorer = Explorer(world.frame, make_planner("nearest"), ObservedAsPrediction())
    observation = world.observe()
    data = np.zeros(100, np.int8)
    # The floor's own map at 0.05 m (each cell a 2 x 2 block), on an explorer at 0.1 m with a frame smaller than
    # it: the explorer's map is the floor's where the frame reaches.
    fine = np.kron(np.where(grid.occupied, 100, 0).astype(np.int8), np.ones((2, 2), np.int8))
    slam = OccupancyGridMessage(resolution_m=float(np.float32(0.05)), width=fine.shape[1], height=fine.shape[0],
                                origin_xy=(0.0, 0.0), data=np.ascontiguousarray(fine[::-1]).reshape(-1))
    small = Explorer(MapFrame((grid.shape[0] // 2, grid.shape[1] // 2), 0.1, (0.0, 0.0)), make_planner("nearest"),
                     ObservedAsPrediction())
    pose = Pose2D(0.1 * (grid.shape[1] // 4) + 0.05, 0.1 * (grid.shape[0] // 4) + 0.05, 0.0)  # inside the small frame
    small.step(Observation(0.0, pose, None, occupancy_grid=slam))
    lower_left = grid.occupied[grid.shape[0] - grid.shape[0] // 2:, :grid.shape[1] // 2]
    walls = small.observed == OCCUPIED
    assert np.count_nonzero(walls != lower_left) <= 9  # the robot's footprint, cleared whatever the map says
    # A SLAM map covering only a 10 x 10 patch around the robot: the rest of the explorer's frame is unknown.
    x, y = observation.pose.x, observation.pose.y
    patch = OccupancyGridMessage(resolution_m=0.1, width=10, height=10, origin_xy=(round(x - 0.55, 1),
                                                                                   round(y - 0.55, 1)), data=data)
    command = explorer.step(Observation(0.0, observation.pose, None, occupancy_grid=patch))
    assert np.count_nonzero(explorer.observed == FREE) == 100 and np.count_nonzero(explorer.observed != UNKNOWN) == 100
    assert command.goal_rc is not None


@pytest.mark.slow
def test_a_recording_with_a_slam_map_and_a_covariance_replays_with_the_same_goals(tmp_path):
    from superex_deploy.cli import main

    grid = load_map(MAP)
    sensing = make_sensing("observed", True, 0, profile=PROFILES["full"])
    world = World(grid, start_poses(MAP)[2], WorldConfig(spad=sensing.spad))
    # This world moves cell to cell and wants each path from the robot's cell: the belief stays within that cell,
    # and the scan matcher's correction (exercised, recorded and replayed) brings it back towards the true pose.
    cfg = ExplorerConfig(scan_matching=ScanMatchingConfig())
    own = Explorer(world.frame, make_planner("nearest"), ObservedAsPrediction(), spad_processing=sensing.processing(),
                   cfg=cfg, seed=1)
    rng = np.random.default_rng(5)
    covariance = PoseCovariance.from_sigmas(0.02, np.deg2rad(0.5))
    slam = {"map": None}

    def noisy(observation):
        # A belief a little off the truth (within the robot's cell), with its covariance; every other step the
        # explorer reads the SLAM map (its own map of the step before) instead of the scan.
        pose = observation.pose
        belief = Pose2D(pose.x + rng.uniform(-0.02, 0.02), pose.y + rng.uniform(-0.02, 0.02),
                        rng.normal(0.0, np.deg2rad(0.5)))
        use_map = slam["map"] is not None and world.steps % 2 == 0
        return Observation(observation.stamp_s, belief, None if use_map else observation.scan, spad=observation.spad,
                           pose_covariance=covariance, occupancy_grid=slam["map"] if use_map else None)

    record_path = tmp_path / "robot.mcap"
    metadata = recording_metadata(map_name=MAP, planner_name="nearest", planner=make_planner("nearest"),
                                  planner_options={}, predictor="observed", seed=1, sensor=sensing.spad,
                                  nlos_cfg=sensing.nlos_cfg, explorer_cfg=cfg, profile="full")
    matched = []
    with EpisodeRecorder(record_path, world.frame, metadata) as recorder:
        def record(observation, command, explorer):
            recorder.write(observation, command, explorer.observed)
            matched.append(explorer.scan_match is not None and explorer.scan_match.accepted)
            slam["map"] = _as_slam_map(explorer.frame, explorer.mapper.observed(include_carved=False))

        commands = _drive(world, own, 20, observe=noisy, after=record)
    assert any(matched)  # the replay below repeats scan-matched steps
    recording = read_recording(record_path)
    assert recording.error is None and len(recording.steps) == len(commands)
    with_map = [s.observation for s in recording.steps if s.observation.occupancy_grid is not None]
    assert with_map and all(o.scan is None for o in with_map)
    assert all(s.observation.pose_covariance is not None for s in recording.steps)
    np.testing.assert_allclose(recording.steps[0].observation.pose_covariance.matrix, covariance.matrix)
    assert main(["replay", str(record_path), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["steps"] == len(commands)
    assert replay["goals"]["cells"] == [list(c[0]) for c in commands if c[1]]


class _CarveAcrossTheDoor(SpadProcessing):
    """A stand-in for the SPAD processing: carves a block through the door into the hidden room at every frame."""

    def __init__(self, shape, sensor):
        super().__init__(sensor=sensor)
        self.block = np.zeros(shape, bool)
        self.block[8:22, 12:32] = True

    def __call__(self, frame, map_frame, pose, known, pose_covariance=None, map_walls=None):
        assert map_walls is None  # the default carving does not read the map's walls: the explorer derives none
        self._evidence = np.zeros(map_frame.shape, np.float32)
        return self.block & ~known, self._evidence


@pytest.mark.parametrize("drive_carved", [None, True])
def test_with_a_pose_covariance_paths_cross_only_cells_the_line_of_sight_holds_free(two_rooms, drive_carved):
    grid = two_rooms()
    sensor = SpadConfig(n_rays=100, range_m=3.0)
    world = World(grid, (5, 5), WorldConfig(spad=sensor))
    cfg = ExplorerConfig(motion=MotionConfig(drive_carved=drive_carved))
    explorer = Explorer(world.frame, make_planner("nearest"), ObservedAsPrediction(),
                        spad_processing=_CarveAcrossTheDoor(grid.shape, sensor), cfg=cfg)
    covariance = PoseCovariance.from_sigmas(0.01, 0.001)
    crossed_carved = 0
    for _ in range(300):
        observation = world.observe()
        command = explorer.step(Observation(observation.stamp_s, observation.pose, observation.scan,
                                            spad=observation.spad, pose_covariance=covariance))
        path = command.path_rc[1:]
        crossed_carved += int(np.count_nonzero(~explorer.mapper.seen_free[path[:, 0], path[:, 1]]))
        if command.finished:
            break
        world.apply(command)
    assert command.finished and world.coverage(explorer.mapper.known(include_carved=False)) > 0.95
    assert world.collisions == 0
    if drive_carved is None:  # the default with a covariance: never through carved-only cells
        assert crossed_carved == 0
    else:  # allowed: the planner takes the carved shortcut
        assert crossed_carved > 0
