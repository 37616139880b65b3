"""Bad inputs at every entry point (the explorer's step, the mapper's ranges, planner options, map files and frames,
recordings, stamps and headings): each gets one clear error where it enters, never a silent wrong result, a crash
deep inside, or a warning."""

import math
import struct
import threading
import warnings
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.maps import OccupancyGrid, load_map
from superex_deploy.messages import (MAX_ABS_YAW, MAX_MAP_CELLS, MAX_STAMP_S, Command, LaserScan, MapFrame,
                                     Observation, Pose2D, max_map_cells)
from superex_deploy.onboard import Explorer
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import Planner

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
RAYS = 72


def _observation(scan, stamp=0.0, pose=Pose2D(10.0, 10.0)) -> Observation:
    return Observation(stamp, pose, scan)


# A scan with no valid reading leaves the map untouched and never reports `finished`.

INVALID = st.one_of(st.just(math.nan), st.just(-math.inf), st.floats(-1e300, 0.0999, allow_nan=False))


@FUZZ
@given(ranges=st.lists(INVALID, min_size=RAYS, max_size=RAYS))
@example(ranges=[math.nan] * RAYS)
@example(ranges=[-math.inf] * RAYS)
@example(ranges=[0.05] * RAYS)
def test_a_scan_without_valid_readings_changes_nothing_and_is_not_finished(laser_scan, ranges):
    explorer = Explorer(MapFrame((200, 200), 0.1), make_planner("nearest"), ObservedAsPrediction())
    for step in range(3):
        command = explorer.step(_observation(laser_scan(ranges), stamp=float(step)))
        assert not command.finished and command.goal_rc is None and command.step == step
        assert not explorer.mapper.known().any()
    # The loop of the README goes on; the first valid scan (no return on any ray: free up to 5 m) gives a goal.
    command = explorer.step(_observation(laser_scan(np.full(RAYS, np.inf)), stamp=3.0))
    assert command.goal_rc is not None and not command.finished and explorer.mapper.known().any()


def test_finished_means_a_known_map_without_a_reachable_frontier():
    # A 2 m square frame seen whole by one dense scan of no returns: everything is known free, nothing is left.
    explorer = Explorer(MapFrame((20, 20), 0.1), make_planner("nearest"), ObservedAsPrediction())
    scan = LaserScan(0.0, 2 * math.pi / 1440, 0.1, 20.0, np.full(1440, np.inf, np.float32))
    command = explorer.step(Observation(0.0, Pose2D(1.0, 1.0), scan))
    assert not command.finished and command.goal_rc is None and explorer.mapper.known().all()  # 5 s to wait
    command = explorer.step(Observation(5.0, Pose2D(1.0, 1.0), scan))
    assert command.finished and command.goal_rc is None


@FUZZ
@given(value=ANY_FLOAT)
@example(value=1e300)
@example(value=-1e300)
@example(value=3.4e38)
@example(value=5.0)  # exactly range_max: no return
@example(value=4.999)
def test_every_range_is_a_return_no_return_or_skipped_without_warnings(laser_scan, value):
    """REP 117: [range_min, range_max) a return; +inf, or range_max and above (how drivers and Gazebo report no
    return), no return (free up to range_max); NaN, -inf or below range_min invalid (skipped). float64 ranges beyond
    float32 become +-inf, without a warning."""
    frame, pose = MapFrame((120, 120), 0.1), Pose2D(6.0, 6.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scan = laser_scan(np.full(RAYS, value), range_min=0.1, range_max=5.0)
        mapper = Mapper(frame.shape)
        mapper.integrate_scan(frame, pose, scan)
    stored = float(scan.ranges[0])
    if math.isnan(stored) or stored < scan.range_min:
        assert not mapper.known().any()
        return
    returned = stored < scan.range_max
    equivalent = Mapper(frame.shape)
    equivalent.integrate_scan(frame, pose, laser_scan(np.full(RAYS, stored if returned else np.inf)))
    assert np.array_equal(mapper.known(), equivalent.known()) and mapper.known().any()
    assert mapper.seen_wall.any() == returned


# One caller at a time.

class _BlockingPlanner(Planner):
    """The nearest-frontier choice, held inside the step until the test lets it go."""

    name = "blocking"

    def __init__(self):
        self.entered, self.release = threading.Event(), threading.Event()

    def choose_goal(self, ctx):
        self.entered.set()
        assert self.release.wait(30), "the test never released the step"
        return make_planner("nearest").choose_goal(ctx)


def test_a_second_concurrent_step_raises_instead_of_repeating_a_step_number(laser_scan):
    planner = _BlockingPlanner()
    explorer = Explorer(MapFrame((200, 200), 0.1), planner, ObservedAsPrediction())
    results: list = []
    blind = laser_scan(np.full(RAYS, np.inf))
    first = threading.Thread(target=lambda: results.append(explorer.step(_observation(blind))))
    first.start()
    try:
        assert planner.entered.wait(60)  # the first step is inside the planner now
        with pytest.raises(RuntimeError, match="one caller at a time"):
            explorer.step(_observation(laser_scan(np.full(RAYS, np.inf)), stamp=1.0))
    finally:
        planner.release.set()
        first.join(60)
    assert [c.step for c in results] == [0] and explorer.steps == 1
    assert explorer.step(_observation(laser_scan(np.full(RAYS, np.inf)), stamp=2.0)).step == 1  # the lock was released


def test_a_step_that_raises_releases_the_lock(laser_scan):
    explorer = Explorer(MapFrame((200, 200), 0.1), make_planner("nearest"), ObservedAsPrediction())
    with pytest.raises(ValueError, match="outside the map"):
        explorer.step(_observation(laser_scan(np.full(RAYS, np.inf)), pose=Pose2D(100.0, 100.0)))
    assert explorer.step(_observation(laser_scan(np.full(RAYS, np.inf)))).step == 0


# Planner options are checked when the planner is built.

@pytest.mark.parametrize("planner, field, value", [
    ("mapex", "visibility", 3), ("hector", "visibility", "none"), ("upen", "rrt_samples", math.inf),
    ("superex", "n_rays", math.inf), ("hector", "wall_threshold", -3), ("hector", "wall_threshold", math.nan),
    ("hector", "wall_threshold", "x"), ("mapex", "min_distance_m", math.inf),
    ("upen", "min_goal_distance_m", math.inf), ("upen", "rrt_samples", 10 ** 400), ("upen", "expand_m", "x"),
    ("hector", "info_gain_weight", None), ("superex", "range_m", math.inf), ("superex", "gain", ["path"]),
    ("mapex", "distance", 3), ("superex", "n_rays", True), ("upen", "reach_horizon", 2.5),
])
def test_a_bad_planner_option_is_refused_when_the_planner_is_built(planner, field, value):
    with pytest.raises(ValueError, match=f"bad configuration for planner '{planner}': {field}"):
        make_planner(planner, **{field: value})


NUMERIC_FIELDS = [("hector", "info_gain_weight"), ("hector", "wall_threshold"), ("mapex", "min_distance_m"),
                  ("upen", "rrt_samples"), ("upen", "expand_m"), ("upen", "reach_horizon"),
                  ("upen", "min_goal_distance_m"), ("superex", "wall_threshold"), ("superex", "sense_every_m"),
                  ("superex", "range_m"), ("superex", "n_rays"), ("superex", "drop_resolved_m")]
OPTION_VALUE = st.one_of(ANY_FLOAT, st.integers(-10 ** 20, 10 ** 20), st.booleans(), st.none(), st.text(max_size=5),
                         st.lists(st.integers(), max_size=2))


@FUZZ
@given(case=st.sampled_from(NUMERIC_FIELDS), value=OPTION_VALUE)
def test_numeric_planner_options_are_finite_numbers_of_their_type_or_refused(case, value):
    planner_name, field = case
    try:
        planner = make_planner(planner_name, **{field: value})
    except ValueError as error:
        assert field in str(error)
        return
    stored = getattr(planner.cfg, field)
    if stored is None:
        assert field == "drop_resolved_m" and value is None
        return
    assert type(stored) in (int, float) and math.isfinite(stored) and float(stored) == float(value)


@pytest.mark.parametrize("text", ["x", "nan", "inf", "-inf", "none", "1e400"])
@pytest.mark.parametrize("planner, field", [("hector", "wall_threshold"), ("mapex", "min_distance_m"),
                                            ("upen", "rrt_samples"), ("superex", "n_rays"),
                                            ("mapex", "visibility")])
def test_command_line_option_strings_give_one_clear_error(planner, field, text):
    from superex_deploy.commands.explore import planner_options

    with pytest.raises(ValueError, match=f"{field} must"):
        make_planner(planner, **planner_options([f"{field}={text}"]))


def test_a_planner_refuses_a_config_of_another_planner():
    from superex_deploy.onboard.planning.planners import MapexConfig, UpenPlanner

    with pytest.raises(ValueError, match="cfg must be a UpenConfig"):
        UpenPlanner(MapexConfig())


# One limit on map size, checked before anything is allocated.

def _png_header(width: int, height: int) -> bytes:
    """A grey 8-bit PNG that declares ``width`` x ``height`` pixels and holds one short row of data: only a reader
    that decodes the pixels finds out."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00" * 16)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("side", [8000, 10000, 14000])  # below PIL's warning, between warning and error, above
def test_a_huge_map_image_is_refused_from_its_header(tmp_path, side):
    path = tmp_path / "huge.png"
    path.write_bytes(_png_header(side, side))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="SUPEREX_MAX_MAP_CELLS"):
            load_map(path)


def test_the_map_size_limit_is_one_setting(tmp_path, monkeypatch):
    from PIL import Image

    Image.fromarray(np.full((30, 40), 255, np.uint8)).save(tmp_path / "room.png")
    assert max_map_cells() == MAX_MAP_CELLS
    monkeypatch.setenv("SUPEREX_MAX_MAP_CELLS", "1000")
    with pytest.raises(ValueError, match="30 x 40 = 1,200 cells, more than the limit of 1,000"):
        load_map(tmp_path / "room.png")
    with pytest.raises(ValueError, match="limit of 1,000"):
        MapFrame((30, 40), 0.1)
    with pytest.raises(ValueError, match="limit of 1,000"):
        OccupancyGrid(np.zeros((30, 40), bool), np.ones((30, 40), bool), 0.1, "room")
    monkeypatch.setenv("SUPEREX_MAX_MAP_CELLS", "1200")
    assert load_map(tmp_path / "room.png").shape == (30, 40)
    monkeypatch.setenv("SUPEREX_MAX_MAP_CELLS", "lots")
    with pytest.raises(ValueError, match="SUPEREX_MAX_MAP_CELLS must be a positive integer"):
        MapFrame((3, 4), 0.1)


def test_a_map_yaml_finer_than_a_millimetre_is_refused(tmp_path):
    import yaml
    from PIL import Image

    Image.fromarray(np.full((40, 50), 255, np.uint8)).save(tmp_path / "ok.png")
    (tmp_path / "map.yaml").write_text(yaml.safe_dump({"image": "ok.png", "resolution": 1e-4}))
    with pytest.raises(ValueError, match="map YAML .* resolution of 0.0001 m per cell, finer than the limit"):
        load_map(tmp_path / "map.yaml")
    with pytest.raises(ValueError, match="finer than the limit"):
        MapFrame((40, 50), 1e-4)


@FUZZ
@given(rows=st.one_of(st.integers(-5, 10 ** 7), st.floats()), cols=st.one_of(st.integers(-5, 10 ** 7), st.floats()))
@example(rows=200000, cols=200000)
@example(rows=math.inf, cols=3)
def test_a_map_frame_of_any_shape_is_built_or_refused(rows, cols):
    try:
        frame = MapFrame((rows, cols), 0.1)
    except ValueError:
        return
    assert frame.shape[0] * frame.shape[1] <= max_map_cells()


def test_a_recording_with_a_huge_map_frame_is_refused(write_recording, tmp_path):
    from superex_deploy.recording import read_recording

    path = tmp_path / "huge.mcap"
    write_recording(path, yaw=7.0,
                    metadata={"frame": {"shape": [200000, 200000], "resolution_m": 0.1, "origin_xy": [0.0, 0.0]}})
    with pytest.raises(ValueError, match="map frame .* more than the limit of"):
        read_recording(path)


# The metadata of a recording has fixed types.

@pytest.mark.parametrize("key, value", [("planner_options", [1, 2]), ("planner_options", "x"), ("seed", "3"),
                                        ("seed", True), ("planner", 3), ("explorer", []), ("frame", None),
                                        ("planner_config", None), ("planner_config", "path")])
def test_recording_metadata_of_the_wrong_type_is_refused(write_recording, tmp_path, monkeypatch, key, value, capsys):
    import superex_deploy.recording.writer as writer
    from superex_deploy.cli import main
    from superex_deploy.recording import read_recording

    path = tmp_path / "bad.mcap"
    with pytest.raises(ValueError, match=f"metadata value '{key}' must be"):
        write_recording(path, yaw=7.0, metadata={key: value})  # the writer refuses it
    monkeypatch.setattr(writer, "check_metadata", lambda metadata, where: metadata)
    write_recording(path, yaw=7.0,
                    metadata={"planner": "nearest", "predictor": "observed", "seed": 0, "explorer": {}, key: value})
    monkeypatch.undo()
    with pytest.raises(ValueError, match=f"metadata value '{key}' must be"):
        read_recording(path)
    assert main(["replay", str(path), "--out", str(tmp_path / "out")]) == 2
    assert f"metadata value '{key}' must be" in capsys.readouterr().err


# Stamps and headings, one rule for the messages, the recorder and the mapper.

@FUZZ
@given(stamp=st.one_of(ANY_FLOAT, st.integers(-10, 2 ** 40)))
@example(stamp=-1.0)
@example(stamp=1e12)
@example(stamp=MAX_STAMP_S)
@example(stamp=0.0)
def test_a_stamp_is_a_ros_time_or_refused_and_every_accepted_one_records(laser_scan, tmp_path, stamp):
    from superex_deploy.recording import read_recording

    try:
        observation = Observation(stamp, Pose2D(1.0, 1.0), laser_scan(np.full(RAYS, 1.0)))
    except ValueError as error:
        assert "stamp_s must" in str(error)
        assert not (isinstance(stamp, (int, float)) and 0 <= stamp <= MAX_STAMP_S and math.isfinite(stamp))
        return
    assert 0.0 <= observation.stamp_s <= MAX_STAMP_S
    from superex_deploy.recording import EpisodeRecorder

    path = tmp_path / "stamp.mcap"
    with EpisodeRecorder(path, MapFrame((20, 20), 0.1), {}) as recorder:
        recorder.write(observation, Command(observation.stamp_s, None, None, np.zeros((0, 2)),
                                            np.zeros((0, 2), np.int64), False, False), np.zeros((20, 20), np.int8))
    recording = read_recording(path)
    assert recording.error is None and abs(recording.steps[0].observation.stamp_s - observation.stamp_s) < 1e-6


def test_the_recorder_refuses_a_bad_map_stamp(tmp_path):
    from superex_deploy.recording import EpisodeRecorder

    with EpisodeRecorder(tmp_path / "x.mcap", MapFrame((20, 20), 0.1), {}) as recorder:
        with pytest.raises(ValueError, match="stamp_s must lie in"):
            recorder.write_map(np.zeros((20, 20), np.int8), -1.0, 0)


@FUZZ
@given(yaw=ANY_FLOAT)
@example(yaw=1e18)
@example(yaw=-math.pi)
@example(yaw=math.pi)
@example(yaw=3 * math.pi)
@example(yaw=MAX_ABS_YAW)
def test_a_yaw_is_normalised_or_refused(yaw):
    try:
        pose = Pose2D(0.0, 0.0, yaw)
    except ValueError as error:
        assert "pose.yaw must" in str(error) and not (math.isfinite(yaw) and abs(yaw) <= MAX_ABS_YAW)
        return
    assert -math.pi < pose.yaw <= math.pi
    if -math.pi < yaw <= math.pi:
        assert pose.yaw == yaw  # kept bit for bit
    # The same direction, to the precision the input carried.
    tolerance = 1e-15 * max(1.0, abs(yaw)) * 4
    assert abs(math.cos(pose.yaw) - math.cos(yaw)) <= tolerance and abs(math.sin(pose.yaw) - math.sin(yaw)) <= tolerance


def test_a_normalised_yaw_is_what_is_recorded_and_replayed(write_recording, tmp_path):
    from superex_deploy.recording import read_recording

    path = tmp_path / "yaw.mcap"
    write_recording(path, yaw=7.0, metadata={})
    observation = read_recording(path).steps[0].observation
    assert observation.pose.yaw == Pose2D(0.0, 0.0, 7.0).yaw == math.remainder(7.0, math.tau)
