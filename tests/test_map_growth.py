"""A map that grows (:mod:`superex_deploy.onboard.mapping.growth`): an explorer started on a small frame keeps the
map an explorer on the whole floor builds from the same observations, its frontiers are never hidden by the grid's
edge, and every per-cell state (goal, path, predictions in progress, SPAD evidence) moves with the grid."""

import numpy as np
import pytest

from superex_deploy.maps import list_maps, load_map, random_start
from superex_deploy.messages import (LaserScan, MapFrame, Observation, OccupancyGridMessage, Pose2D,
                                     max_map_cells)
from superex_deploy.onboard import Explorer, ExplorerConfig, PredictionReuse, PredictionSchedule
from superex_deploy.onboard.mapping.growth import MapGrowth, embed, grown_frame, reach_of
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, UNKNOWN, Prediction
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.sim.world import World, WorldConfig

GROWTH = MapGrowth(margin_m=2.0, chunk_m=3.0)


def _explorer(frame, **cfg) -> Explorer:
    """The simulated benchmarks' explorer (finished at the first step without a goal)."""
    return Explorer(frame, make_planner("nearest"), ObservedAsPrediction(),
                    cfg=ExplorerConfig(**cfg).for_simulation())


def _in_frame(observed: np.ndarray, frame: MapFrame, target: MapFrame) -> np.ndarray:
    """``observed`` (on ``frame``) on the cells of ``target`` (same lattice), unknown where it has none."""
    shift_c = round((frame.origin_xy[0] - target.origin_xy[0]) / target.resolution_m)
    shift_r = round((target.origin_xy[1] + target.shape[0] * target.resolution_m
                     - frame.origin_xy[1] - frame.shape[0] * frame.resolution_m) / target.resolution_m)
    out = np.full(target.shape, UNKNOWN, np.int8)
    r0, c0 = max(shift_r, 0), max(shift_c, 0)
    r1, c1 = min(shift_r + frame.shape[0], target.shape[0]), min(shift_c + frame.shape[1], target.shape[1])
    out[r0:r1, c0:c1] = observed[r0 - shift_r:r1 - shift_r, c0 - shift_c:c1 - shift_c]
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_a_growing_map_is_the_whole_floors_map_of_the_same_observations(seed):
    rng = np.random.default_rng(seed)
    grid = load_map(list_maps("train")[seed * 7])
    world = World(grid, random_start(grid, rng, 0.5), WorldConfig())
    whole, observations = _explorer(world.frame), []
    run_episode(grid, world.pose_rc, steps=40, cfg=ExplorationConfig(iou_every=0), explorer=whole,
                on_observation=lambda observation, command, explorer: observations.append(observation))
    start = observations[0].pose
    growing = _explorer(MapFrame.around(start.x, start.y, grid.resolution_m, size_m=4.0), growth=GROWTH)
    for observation in observations:
        growing.step(observation)
    assert growing.frame.shape != (40, 40)  # it grew
    assert growing.frame.shape[0] * growing.frame.shape[1] < world.frame.shape[0] * world.frame.shape[1] * 4
    mine = _in_frame(growing.observed, growing.frame, world.frame)
    known = (mine != UNKNOWN) | (whole.observed != UNKNOWN)
    assert np.mean(mine[known] != whole.observed[known]) < 1e-3
    # Everything known keeps the margin to the grid's edge: no frontier is hidden by it.
    rows, cols = np.nonzero(growing.observed != UNKNOWN)
    margin = int(GROWTH.margin_m / grid.resolution_m) - 1
    assert rows.min() >= margin and cols.min() >= margin
    assert rows.max() < growing.frame.shape[0] - margin and cols.max() < growing.frame.shape[1] - margin


def test_a_slam_corridor_beyond_the_frame_is_not_finished():
    # A 30 m corridor in a SLAM map, the explorer's frame only 6 m of it (the explorer once said finished at the
    # frame's edge).
    slam_frame = MapFrame((40, 300), 0.1, (0.0, 0.0))
    corridor = np.full(slam_frame.shape, -1, np.int8)
    corridor[15:25, 0:250] = 0
    corridor[15, :250] = corridor[24, :250] = corridor[15:25, 0] = 100
    message = OccupancyGridMessage.from_frame_grid(slam_frame, corridor)
    pose = Pose2D(1.05, 2.05)
    fixed = _explorer(MapFrame((40, 60), 0.1, (0.0, 0.0)))
    assert fixed.step(Observation(0.0, pose, None, occupancy_grid=message)).finished  # the edge hides the rest
    growing = _explorer(MapFrame((40, 60), 0.1, (0.0, 0.0)), growth=GROWTH)
    command = growing.step(Observation(0.0, pose, None, occupancy_grid=message))
    assert not command.finished and command.goal_xy[0] > 20.0  # the corridor's open end, 25 m away
    assert growing.frame.shape[1] >= 250 + 20


def test_goal_path_and_predictions_in_progress_move_with_the_grid():
    frame = MapFrame((100, 100), 0.1, (0.0, 0.0))
    explorer = Explorer(frame, make_planner("nearest"), ObservedAsPrediction(),
                        cfg=ExplorerConfig(growth=GROWTH, prediction=PredictionSchedule("free"),
                                           reuse=PredictionReuse(crop_margin_m=1.0)))
    open_scan = LaserScan(0.0, 2 * np.pi / 360, 0.05, 2.0, np.full(360, np.inf, np.float32))
    with explorer:
        first = explorer.step(Observation(0.0, Pose2D(5.05, 5.05), open_scan))
        assert explorer.frame.shape == (100, 100) and first.goal_xy is not None
        # A step 2.5 m to the west: the grid grows to the left, by at least the chunk.
        second = explorer.step(Observation(0.1, Pose2D(2.55, 5.05), open_scan))
        assert explorer.frame.shape == (100, 100 + 15 + 30) and explorer.frame.origin_xy[0] == pytest.approx(-4.5)
        assert second.goal_rc is not None and explorer.frame.centre_xy(second.goal_rc) == pytest.approx(
            second.goal_xy)
        assert second.path_xy[0] == pytest.approx(explorer.frame.centre_xy(explorer.frame.cell_of(2.55, 5.05)))
        assert second.prediction is None or second.prediction.mean.shape == explorer.frame.shape
        for t in range(2, 6):
            command = explorer.step(Observation(0.1 * t, Pose2D(2.55, 5.05), open_scan))
            assert command.prediction is None or command.prediction.mean.shape == explorer.frame.shape
        assert explorer.reusing.runs >= 1


def test_growth_past_the_map_size_limit_is_refused_before_anything_changes():
    explorer = _explorer(MapFrame((100, 100), 0.1, (0.0, 0.0)), growth=GROWTH)
    scan = LaserScan(0.0, 2 * np.pi / 8, 0.05, 2.0, np.full(8, np.inf, np.float32))
    explorer.step(Observation(0.0, Pose2D(5.05, 5.05), scan))
    before = explorer.mapper.log_odds.copy()
    far = (max_map_cells() ** 0.5) * 0.1 * 2
    with pytest.raises(ValueError, match="growing map"):
        explorer.step(Observation(1.0, Pose2D(far, far), scan))
    assert explorer.frame.shape == (100, 100) and np.array_equal(explorer.mapper.log_odds, before)
    # a garbage pose (an uninitialised localiser's 1e300 m): the same ValueError, not an OverflowError
    with pytest.raises(ValueError, match="growing map"):
        explorer.step(Observation(1.0, Pose2D(1e300, -1e300), scan))
    with pytest.raises(ValueError, match="growing map"):
        grown_frame(explorer.frame, (0.0, 0.0, 1.0, 1.0), MapGrowth(margin_m=1e308))
    assert explorer.frame.shape == (100, 100) and np.array_equal(explorer.mapper.log_odds, before)


def test_grown_frame_and_embed_on_hand_made_cases():
    frame = MapFrame((10, 20), 0.5, (1.0, 2.0))  # x 1..11 m, y 2..7 m
    assert grown_frame(frame, (3.0, 3.5, 8.0, 5.0), MapGrowth(margin_m=1.0, chunk_m=0.0)) is None
    regrid = grown_frame(frame, (0.4, 3.5, 8.0, 5.0), MapGrowth(margin_m=1.0, chunk_m=1.0))
    # needs x >= -0.6: 4 columns (to x = -1.0), plus 2 for the chunk; no other side grows
    assert (regrid.top, regrid.left) == (0, 6) and regrid.frame.shape == (10, 26)
    assert regrid.frame.origin_xy == pytest.approx((-2.0, 2.0))
    assert regrid.frame.centre_xy(regrid.cell((3, 4))) == pytest.approx(frame.centre_xy((3, 4)))
    up = grown_frame(frame, (3.0, 3.5, 8.0, 7.2), MapGrowth(margin_m=0.0, chunk_m=0.0))
    assert (up.top, up.left, up.frame.shape) == (1, 0, (11, 20)) and up.frame.origin_xy == frame.origin_xy
    array = np.arange(6, dtype=np.float32).reshape(2, 3)
    out = embed(array, (4, 5), 1, 2, -1.0)
    assert out.dtype == np.float32 and np.array_equal(out[1:3, 2:5], array) and (out == -1).sum() == 14
    with pytest.raises(ValueError, match="does not fit"):
        embed(array, (2, 3), 1, 0, 0.0)
    scan = LaserScan(0.0, np.pi / 2, 0.1, 3.0, np.array([1.0, np.inf, np.nan, 0.05], np.float32))
    x0, y0, x1, y1 = reach_of(Observation(0.0, Pose2D(5.0, 5.0), scan))
    assert (x0, y0, x1, y1) == pytest.approx((5.0, 5.0, 6.0, 8.0))  # east return, north no-return to range_max
    with pytest.raises(ValueError, match="MapGrowth.margin_m must be a finite number"):
        MapGrowth(margin_m=-1.0)


class _ShapeDependentPredictor:
    """A predictor whose every cell depends on the grid it is asked on (LaMa's output does, through its context)."""

    name = "shape_dependent"

    def predict(self, observed, extra=None):
        mean = np.full(observed.shape, 1.0 / observed.shape[1], np.float32)
        return Prediction(mean=mean, variance=np.zeros_like(mean))


def _westward_observations():
    open_scan = LaserScan(0.0, 2 * np.pi / 360, 0.05, 2.0, np.full(360, np.inf, np.float32))
    poses = [Pose2D(5.05 - 0.6 * t, 5.05 + 0.4 * (t % 3), 0.0) for t in range(12)]  # westwards: grows on the left
    return [Observation(0.1 * t, pose, open_scan) for t, pose in enumerate(poses)]


def _run(cfg, observations, recorded_steps=None):
    frame = MapFrame((100, 100), 0.1, (0.0, 0.0))
    with Explorer(frame, make_planner("nearest"), _ShapeDependentPredictor(), cfg=cfg) as explorer:
        if recorded_steps is not None:
            explorer.follow_recorded_predictions(recorded_steps)
        commands = [explorer.step(observation) for observation in observations]
    assert explorer.frame.shape[1] > 100 and any(c.prediction_step >= 0 for c in commands)
    return commands


def test_a_growing_free_run_with_predictions_in_flight_replays_exactly():
    # The recorded run's worker predicted each map on the grid it had then; a replay that predicted the kept map
    # after embedding it in the grown grid got other predictions (and, with LaMa, other goals).
    cfg = ExplorerConfig(growth=GROWTH, prediction=PredictionSchedule("free"))
    observations = _westward_observations()
    recorded = _run(cfg, observations)
    replayed = _run(cfg, observations, [c.prediction_step for c in recorded])
    for command, again in zip(recorded, replayed):
        assert again.prediction_step == command.prediction_step
        if command.prediction is not None:
            assert np.array_equal(again.prediction.mean, command.prediction.mean), again.step


def test_the_simulated_schedule_keeps_its_steps_while_the_grid_grows():
    # A prediction in progress at a growth is computed then, on the smaller grid it was asked on (as a worker in
    # progress would have finished it): the predictions are still of the maps of steps 3 k, never older than
    # N + L - 1 = 5 steps, and the run is reproducible.
    observations = _westward_observations()
    cfg = ExplorerConfig(growth=GROWTH, prediction=PredictionSchedule("simulated", every_steps=3, apply_after_steps=3))
    runs = [_run(cfg, observations) for _ in range(2)]
    assert any(c.prediction is not None for c in runs[0])
    for first, again in zip(*runs):
        assert first.prediction_step == again.prediction_step, first.step
        assert first.prediction_step == -1 or (first.prediction_step % 3 == 0
                                               and first.step - first.prediction_step <= 5), first.step
        if first.prediction is not None:
            assert np.array_equal(first.prediction.mean, again.prediction.mean), first.step


def test_a_recording_of_a_growing_run_holds_each_maps_own_frame_and_replays(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from superex_deploy.pipeline import build_explorer
    from superex_deploy.recording import EpisodeRecorder, read_recording
    from superex_deploy.recording.metadata import explorer_arguments
    from tests.conftest import nearest_metadata

    cfg = ExplorerConfig(growth=GROWTH)
    frame = MapFrame((100, 100), 0.1, (0.0, 0.0))
    metadata = nearest_metadata(explorer=cfg.to_json())
    path = tmp_path / "growing.mcap"
    frames = []
    with Explorer(frame, make_planner("nearest"), ObservedAsPrediction(), cfg=cfg) as explorer, \
            EpisodeRecorder(path, frame, metadata, map_every=1) as recorder:
        for observation in _westward_observations():
            command = explorer.step(observation)
            recorder.write(observation, command, explorer.observed, explorer.frame)
            frames.append(explorer.frame)
        with pytest.raises(ValueError, match="pass the explorer's frame"):  # the recording's frame: refused
            recorder.write_map(explorer.observed)
    assert frames[-1] != frame
    with open(path, "rb") as file:
        maps = [message for _, _, _, message in make_reader(file, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=["/map"])]
    assert len(maps) == len(frames)
    for message, step_frame in zip(maps, frames):  # each map a well-formed grid on the step's own frame
        info = message.info
        assert (info.height, info.width) == step_frame.shape and len(message.data) == info.width * info.height
        assert (info.origin.position.x, info.origin.position.y) == pytest.approx(step_frame.origin_xy)
    recording = read_recording(path)
    with build_explorer(**explorer_arguments(recording.metadata, recording.frame)) as replay:
        assert replay.cfg.growth == GROWTH
        for recorded in recording.steps:
            command = replay.step(recorded.observation)
            assert (command.goal_rc, command.new_goal, command.finished) == (recorded.goal_rc, recorded.new_goal,
                                                                             recorded.finished)
    assert replay.frame == frames[-1]
    # superex replay: the same goals, and the final map with the frame it lies on (the recording's is the first)
    from superex_deploy.cli import main

    assert main(["replay", str(path), "--out", str(tmp_path / "replay")]) == 0
    saved = np.load(tmp_path / "replay" / "map.npz")
    assert tuple(saved["shape"]) == frames[-1].shape == saved["observed"].shape
    assert tuple(saved["origin_xy"]) == pytest.approx(frames[-1].origin_xy) and saved["resolution_m"] == 0.1


@pytest.mark.parametrize("origin_xy, resolution_m", [((-5.03, -5.0), 0.1), ((-5.0, -5.0), 0.05),
                                                     ((-5.0, -5.0), 0.2)])
def test_a_slam_map_off_the_lattice_or_of_another_resolution_grows_the_grid_and_is_resampled(origin_xy, resolution_m):
    explorer = _explorer(MapFrame((40, 40), 0.1, (0.0, 0.0)), growth=GROWTH)
    scan = LaserScan(0.0, 2 * np.pi / 8, 0.05, 1.0, np.full(8, np.inf, np.float32))
    explorer.step(Observation(0.0, Pose2D(2.05, 2.05), scan))
    cells = round(10.0 / resolution_m)
    message = OccupancyGridMessage(resolution_m, cells, cells, origin_xy, np.zeros(cells * cells, np.int8))
    explorer.step(Observation(1.0, Pose2D(2.05, 2.05), None, occupancy_grid=message))
    frame = explorer.frame  # grown on its own lattice to hold the whole 10 m x 10 m map
    assert frame.resolution_m == 0.1 and frame.origin_xy[0] <= origin_xy[0] and frame.origin_xy[1] <= -5.0
    assert frame.origin_xy[0] + frame.shape[1] * 0.1 >= origin_xy[0] + 10.0 - 1e-9
    free = np.count_nonzero(explorer.observed == FREE)
    assert abs(free - 100 * 100) <= 2 * 100  # the map's 100 m^2 in 0.1 m cells (an edge may fall either way)
    explorer.step(Observation(2.0, Pose2D(2.05, 2.05), scan))  # and it goes on


class _SlowPredictor(_ShapeDependentPredictor):
    def predict(self, observed, extra=None):
        import time

        time.sleep(1.0)
        return super().predict(observed, extra)


def test_a_growth_that_waits_for_the_prediction_in_progress_says_so_in_the_steps_timings():
    # The free schedule's step waited for the worker at a growth, and neither timings_s nor blocking_waits said so.
    observations = _westward_observations()
    with Explorer(MapFrame((100, 100), 0.1, (0.0, 0.0)), make_planner("nearest"), _SlowPredictor(),
                  cfg=ExplorerConfig(growth=GROWTH, prediction=PredictionSchedule("free"))) as explorer:
        explorer.step(observations[0])  # submits the prediction of map 0 (1 s)
        explorer.step(observations[1])  # it is in progress: the step goes on without it
        assert explorer.frame.shape == (100, 100) and explorer.scheduled.blocking_waits == 0
        third = explorer.step(observations[2])  # grows at once: waits for it
    assert explorer.frame.shape[1] > 100 and third.prediction_step == 0
    assert third.timings_s["prediction"] >= 0.2 and explorer.scheduled.blocking_waits == 1
