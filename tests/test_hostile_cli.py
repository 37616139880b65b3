"""Issue #23, the command-line rows of the hostile pass: every bad argument gets one clear error that names its
option before anything is created, and every command stopped by a signal says so in one line, exits with the code a
shell reports (130 for SIGINT, 143 for SIGTERM) and keeps what it promised to keep."""

import math
import re
import signal
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.cli import main
from superex_deploy.commands._options import planner_options
from superex_deploy.messages import Command, LaserScan, MapFrame, Observation, Pose2D

ROOT = Path(__file__).resolve().parents[1]
MAP = "50045230"  # the smallest bundled map
FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


def _refused(capsys, argv, *messages) -> str:
    """Run ``superex ARGV``, expect exit 2 and one error line holding every message; returns stderr."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    for message in messages:
        assert message in lines[0], err
    return err


def _record(path, steps=3, frame=MapFrame((20, 20), 0.1), chunk_bytes=256 * 1024):
    """A small recording of ``steps`` steps of a nearest-frontier explorer that sees no wall."""
    from superex_deploy.recording import EpisodeRecorder

    scan = LaserScan(0.0, 2 * math.pi / 72, 0.1, 5.0, np.full(72, 1.0))
    metadata = {"planner": "nearest", "predictor": "observed", "seed": 0, "explorer": {}}
    with EpisodeRecorder(path, frame, metadata, chunk_bytes=chunk_bytes) as recorder:
        for step in range(steps):
            recorder.write(Observation(float(step), Pose2D(1.0, 1.0), scan),
                           Command(float(step), None, None, np.zeros((0, 2)), np.zeros((0, 2), np.int64), False,
                                   False, step=step), np.zeros(frame.shape, np.int8))
    return path


# Also from the previous pass: option values and the configs they reach.

def test_the_literal_none_becomes_none_for_the_fields_that_take_it():
    from superex_deploy.onboard.planners import make_planner

    assert planner_options(["visibility=none", "x=None", "y=NONE"]) == {"visibility": None, "x": None, "y": None}
    assert make_planner("hector", **planner_options(["visibility=none"])).cfg.visibility is None
    with pytest.raises(ValueError, match="visibility must be a VisibilityConfig, got NoneType"):
        make_planner("mapex", **planner_options(["visibility=none"]))


VISIBILITY = {"n_rays": st.one_of(st.integers(-5, 10 ** 12), st.floats(allow_nan=True), st.text(max_size=2)),
              "range_m": st.one_of(st.floats(allow_nan=True), st.integers(-5, 50), st.none()),
              "hit_threshold": st.one_of(st.floats(-1, 2), st.just(math.nan), st.booleans()),
              "accumulate": st.one_of(st.booleans(), st.integers(0, 1), st.none())}


@FUZZ
@given(field=st.sampled_from(sorted(VISIBILITY)), data=st.data())
@example(field="n_rays", data=None)
def test_a_visibility_config_holds_checked_values_or_names_the_bad_field(field, data):
    from superex_deploy.onboard.visibility import MAX_RAYS, VisibilityConfig

    value = math.inf if data is None else data.draw(VISIBILITY[field])
    try:
        cfg = VisibilityConfig(**{field: value})
    except ValueError as error:
        assert str(error).startswith(f"{field} must")
        return
    stored = getattr(cfg, field)
    if field == "n_rays":
        assert type(stored) is int and 3 <= stored <= MAX_RAYS
    elif field == "accumulate":
        assert type(stored) is bool
    else:
        assert type(stored) is float and math.isfinite(stored) and stored > 0 and (field == "range_m" or stored <= 1)


@FUZZ
@given(field=st.sampled_from(["robot_radius_m", "wall_cost_weight", "wall_cost_range_m", "goal_reached_m",
                              "step_cells"]),
       value=st.one_of(st.floats(allow_nan=True), st.integers(-10, 10 ** 15), st.text(max_size=2), st.none()))
@example(field="wall_cost_range_m", value=1e300)
@example(field="wall_cost_range_m", value=10 ** 9)
def test_a_motion_config_is_bounded_or_refused_naming_the_field(field, value):
    from superex_deploy.onboard.motion import MAX_WALL_REACH_M, MotionConfig, planning_map

    try:
        cfg = MotionConfig(**{field: value})
    except ValueError as error:
        assert str(error).startswith(f"MotionConfig: {field} must")
        return
    stored = getattr(cfg, field)
    assert math.isfinite(stored) and stored >= 0
    if field in ("robot_radius_m", "wall_cost_range_m"):
        assert stored <= MAX_WALL_REACH_M
    observed = np.zeros((30, 30), np.int8)
    observed[0, :] = 1
    planning_map(observed, (15, 15), 0.1, cfg)  # bounded work and memory


def test_a_wall_reach_too_wide_for_the_resolution_is_refused_before_any_allocation():
    from superex_deploy.onboard.motion import MAX_WALL_REACH_CELLS, MotionConfig, planning_map, wall_distance

    with pytest.raises(ValueError, match="MAX_WALL_REACH_CELLS"):
        planning_map(np.zeros((30, 30), np.int8), (15, 15), 0.001, MotionConfig(wall_cost_range_m=5.0))
    with pytest.raises(ValueError, match="reach_cells must lie in"):
        wall_distance(np.zeros((3, 3), bool), MAX_WALL_REACH_CELLS + 1)


# Row 20: the Gymnasium environment follows Gymnasium's contract.

def test_the_environment_refuses_a_step_after_the_episode_ended_or_after_close():
    pytest.importorskip("gymnasium")
    from superex_deploy.sim.gym_env import ExplorationEnv

    env = ExplorationEnv(map=MAP, steps_per_action=2, max_steps=3)
    with pytest.raises(RuntimeError, match="reset\\(\\) has not been called"):
        env.step(0)
    _, info = env.reset(seed=1)
    ended = False
    while not ended:
        _, _, terminated, truncated, info = env.step(0)
        ended = terminated or truncated
    steps = info["steps"]
    with pytest.raises(RuntimeError, match="the episode has been truncated; call reset"):
        env.step(0)
    assert env._world.steps == steps  # the refused step did not move the simulation
    env.reset(seed=1)
    env.step(0)
    env.close()
    with pytest.raises(RuntimeError, match="the environment is closed; call reset"):
        env.step(0)
    env.reset(seed=2)  # a reset starts afresh
    env.step(0)
    env.close()


# Row 14: a recording without a step is not a successful replay.

def test_a_recording_without_steps_is_refused(tmp_path, capsys):
    from superex_deploy.recording import read_recording

    empty = _record(tmp_path / "empty.mcap", steps=0)
    assert read_recording(empty).steps == [] and read_recording(empty).error is None
    out = tmp_path / "replay"
    _refused(capsys, ["replay", str(empty), "--out", str(out)], "holds no step to replay")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(_record(tmp_path / "three.mcap").read_bytes()[:900])  # the metadata, then cut
    _refused(capsys, ["replay", str(cut), "--out", str(out)], "holds no step to replay", "truncated")
    assert not out.exists()


# Row 19: a truncated recording says so, and where.

def test_a_truncated_recording_says_at_which_byte_and_after_which_step(tmp_path):
    from superex_deploy.recording import read_recording

    data = _record(tmp_path / "full.mcap", steps=12, chunk_bytes=2048).read_bytes()
    seen = set()
    for size in range(0, len(data), max(1, len(data) // 60)):
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:size])
        try:
            recording = read_recording(cut)
        except ValueError as error:  # cut before the metadata: nothing is usable
            assert "is not a SuperEx recording" in str(error)
            continue
        assert recording.error is not None
        assert f"the file is truncated: it ends at byte {size:,}, inside a record" in recording.error
        steps = len(recording.steps)
        where = f"after step {steps - 1}" if steps else "before the first step"
        assert where in recording.error or "topic /" in recording.error
        assert recording.error.endswith(f"kept the {steps} complete steps before it")
        assert "EndOfFile: ;" not in recording.error
        seen.add(steps)
    assert len(seen) >= 4 and 0 in seen and 12 in seen  # cuts before, among and after the steps


# Row 20: reading shows progress from the first message.

def test_reading_a_recording_shows_progress_over_its_messages(tmp_path, capsys):
    from superex_deploy.recording import read_recording

    path = _record(tmp_path / "r.mcap", steps=6)
    read_recording(path)
    assert capsys.readouterr().err == ""
    recording = read_recording(path, progress=True)
    err = capsys.readouterr().err
    assert len(recording.steps) == 6 and "reading r.mcap" in err
    # A known total (the file's summary): 6 steps of /pose, /scan, /command and /plan, and the map of step 0.
    assert re.search(r"0/25 \[", err) and re.search(r"25/25 \[", err)
