"""The command line's bad arguments: every one gets one clear error that names its option before anything is created
(numbers, output folders, lists, --resume settings, option values and the configs they reach); a recording without a
step, cut short or being read says so; the Gymnasium environment keeps Gymnasium's contract. Signals are in
test_cli_signals.py."""

import argparse
import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.cli import main
from superex_deploy.commands.options import (name_list, non_negative_int, planner_options, positive_int,
                                             settings_differences)
from superex_deploy.messages import MapFrame

MAP = "50045230"  # the smallest bundled map
FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def refused(capsys, argv, *messages) -> str:
    """Run ``superex ARGV``, expect exit 2 and one error line holding every message; returns stderr."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    for message in messages:
        assert message in lines[0], err
    return err


# Option values and the configs they reach.

def test_the_literal_none_becomes_none_for_the_fields_that_take_it():
    from superex_deploy.onboard.planning.planners import make_planner

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
    from superex_deploy.onboard.planning.visibility import MAX_RAYS, VisibilityConfig

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
                              "step_m"]),
       value=st.one_of(st.floats(allow_nan=True), st.integers(-10, 10 ** 15), st.text(max_size=2), st.none()))
@example(field="wall_cost_range_m", value=1e300)
@example(field="wall_cost_range_m", value=10 ** 9)
def test_a_motion_config_is_bounded_or_refused_naming_the_field(field, value):
    from superex_deploy.onboard.planning.motion import MAX_WALL_REACH_M, MotionConfig, planning_map

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
    from superex_deploy.onboard.planning.motion import MAX_WALL_REACH_CELLS, MotionConfig, planning_map, wall_distance

    with pytest.raises(ValueError, match="MAX_WALL_REACH_CELLS"):
        planning_map(np.zeros((30, 30), np.int8), (15, 15), 0.001, MotionConfig(wall_cost_range_m=5.0))
    with pytest.raises(ValueError, match="reach_cells must lie in"):
        wall_distance(np.zeros((3, 3), bool), MAX_WALL_REACH_CELLS + 1)


# The Gymnasium environment follows Gymnasium's contract.

def test_the_environment_refuses_a_step_after_the_episode_ended_or_after_close():
    pytest.importorskip("gymnasium")
    from superex_deploy.gym_env import ExplorationEnv

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


# A recording without a step is not a successful replay.

def test_a_recording_without_steps_is_refused(write_recording, tmp_path, capsys):
    from superex_deploy.recording import read_recording

    empty = write_recording(tmp_path / "empty.mcap", steps=0)
    assert read_recording(empty).steps == [] and read_recording(empty).error is None
    out = tmp_path / "replay"
    refused(capsys, ["replay", str(empty), "--out", str(out)], "holds no step to replay")
    cut = tmp_path / "cut.mcap"
    data = write_recording(tmp_path / "three.mcap", steps=3).read_bytes()
    for size in range(0, len(data), 50):  # the first cut that keeps the metadata whole: no step left
        cut.write_bytes(data[:size])
        try:
            read_recording(cut)
            break
        except ValueError:
            continue
    refused(capsys, ["replay", str(cut), "--out", str(out)], "holds no step to replay", "truncated")
    assert not out.exists()


# A truncated recording says so, and where.

def test_a_truncated_recording_says_at_which_byte_and_after_which_step(write_recording, tmp_path):
    from superex_deploy.recording import read_recording

    data = write_recording(tmp_path / "full.mcap", steps=12, chunk_bytes=2048).read_bytes()
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


# Reading shows progress from the first message.

def test_reading_a_recording_shows_progress_over_its_messages(write_recording, tmp_path, capsys):
    from superex_deploy.recording import read_recording

    path = write_recording(tmp_path / "r.mcap", steps=6)
    read_recording(path)
    assert capsys.readouterr().err == ""
    recording = read_recording(path, progress=True)
    err = capsys.readouterr().err
    assert len(recording.steps) == 6 and "reading r.mcap" in err
    # A known total (the file's summary): 6 steps of /pose, /scan, /command and /plan, and the map of step 0.
    assert re.search(r"0/25 \[", err) and re.search(r"25/25 \[", err)


# Numbers are checked by their argparse type, which names the option.

@FUZZ
@given(value=st.one_of(st.integers(-10 ** 30, 10 ** 30), st.text(max_size=6)))
@example(value="-5")
@example(value="0")
@example(value=" 7 ")
@example(value="1e3")
def test_integer_options_take_integers_from_their_lower_bound(value):
    text = str(value)
    for convert, low in ((non_negative_int, 0), (positive_int, 1)):
        try:
            expected = int(text)
        except ValueError:
            expected = None
        if expected is None or expected < low:
            with pytest.raises(argparse.ArgumentTypeError, match=f"must be an integer >= {low}, got"):
                convert(text)
        else:
            assert convert(text) == expected


@pytest.mark.parametrize("argv, option", [
    (["explore", "--map", MAP, "--gif-every", "-1"], "--gif-every"),
    (["explore", "--map", MAP, "--gif-every", "x"], "--gif-every"),
    (["explore", "--map", MAP, "--seed", "-5"], "--seed"),
    (["explore", "--map", MAP, "--start", "-1"], "--start"),
    (["benchmark", "--maps", MAP, "--seed", "-5"], "--seed"),
    (["benchmark", "--maps", MAP, "--jobs", "0"], "--jobs"),
    (["scan", "--map", MAP, "--seed", "-5"], "--seed"),
    (["scan", "--map", MAP, "--secondary", "0"], "--secondary"),
])
def test_a_bad_number_is_refused_naming_its_option_before_anything_is_created(tmp_path, capsys, argv, option):
    out = tmp_path / "out"
    refused(capsys, argv + ["--out", str(out)], f"argument {option}: must be an integer >=")
    assert not out.exists()


def test_gif_every_zero_writes_no_gif(tmp_path, capsys):
    from superex_deploy.render import GifRecorder

    out = tmp_path / "run"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "5", "--gif-every", "0", "--out",
                 str(out)]) == 0
    assert (out / "metrics.json").exists() and not (out / "episode.gif").exists()
    assert "episode.gif" not in capsys.readouterr().out
    for every in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="every must be an integer >= 1"):
            GifRecorder(every=every)


# Output paths are checked before any work.

@pytest.mark.parametrize("argv", [
    ["explore", "--map", MAP, "--steps", "5"],
    ["scan", "--map", MAP],
    ["benchmark", "--maps", MAP, "--planners", "nearest", "--steps", "5"],
    ["benchmark", "--suite", "paper", "--maps", MAP, "--rows", "nearest", "--steps", "5"],
    ["replay", "no_such_recording.mcap"],  # the folder is refused before the recording is even read
])
@pytest.mark.parametrize("below", ["sub", "sub/deeper", ""])
def test_an_output_folder_below_a_file_is_refused_up_front(tmp_path, capsys, argv, below):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    out = a_file / below if below else a_file
    message = "exists and is not a folder" if not below else f"cannot be created: {a_file} is a file, not a folder"
    refused(capsys, argv + ["--out", str(out)], f"--out {out}", message)
    assert a_file.read_text() == "x" and sorted(tmp_path.iterdir()) == [a_file]


# The recording's folder is checked up front too; a map without start poses asks for --pose.

def test_a_record_path_in_a_missing_folder_leaves_nothing_behind(tmp_path, capsys):
    out = tmp_path / "run"
    refused(capsys, ["explore", "--map", MAP, "--steps", "5", "--out", str(out), "--record",
                      str(tmp_path / "nodir" / "x.mcap")], "--record", "the folder", "does not exist")
    refused(capsys, ["explore", "--map", MAP, "--steps", "5", "--out", str(out), "--record", str(tmp_path)],
             "is a folder, not a file")
    assert list(tmp_path.iterdir()) == []
    # A folder that --out creates is fine: the recording goes beside the run.
    new = tmp_path / "new"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "5", "--gif-every", "0", "--out",
                 str(new / "run"), "--record", str(new / "x.mcap")]) == 0
    assert (new / "x.mcap").exists() and (new / "run" / "metrics.json").exists()


@pytest.mark.parametrize("command", ["explore", "scan"])
def test_a_map_without_start_poses_starts_in_its_largest_free_region(tmp_path, capsys, command):
    from PIL import Image

    image = np.full((60, 80), 255, np.uint8)
    image[[0, -1], :] = image[:, [0, -1]] = 0
    image[:, 20] = 0  # a closed 18-column closet on the left, the hall on the right
    Image.fromarray(image).save(tmp_path / "small.png")
    extra = ["--steps", "2", "--gif-every", "0"] if command == "explore" else ["--secondary", "4"]
    starts = []
    for run in ("a", "b"):
        assert main([command, "--map", str(tmp_path / "small.png"), *extra, "--seed", "3",
                     "--out", str(tmp_path / run)]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines() if "has no start poses" in x)
        assert line.startswith(f"superex {command}: ") and "largest free region (seed 3)" in line
        row, col = (int(v) for v in line.rsplit("--pose ", 1)[1].split())
        starts.append((row, col))
        assert col > 20 + 5 and 5 <= row <= 54  # in the hall, 0.5 m (5 cells) from its walls
    assert starts[0] == starts[1]  # seeded
    assert main([command, "--map", str(tmp_path / "small.png"), "--pose", "30", "40", *extra,
                 "--out", str(tmp_path / "c")]) == 0


# Lists are never empty.

@FUZZ
@given(text=st.text(alphabet=", ab", max_size=8))
@example(text=",")
@example(text=" , ,")
@example(text="a,a")
@example(text="a,b,")
def test_a_name_list_is_one_or_more_distinct_names(text):
    try:
        names = name_list(text)
    except argparse.ArgumentTypeError as error:
        items = [item.strip() for item in text.split(",") if item.strip()]
        assert not items or len(set(items)) < len(items), error
        return
    assert names and len(set(names)) == len(names) and all(name and name == name.strip() for name in names)
    assert names == [item.strip() for item in text.split(",") if item.strip()]


@pytest.mark.parametrize("option, value", [("--planners", ","), ("--maps", ","), ("--maps", " , "),
                                           ("--planners", "nearest,nearest"), ("--rows", ",")])
def test_an_empty_or_repeating_list_is_refused_before_anything_is_written(tmp_path, capsys, option, value):
    out = tmp_path / "bench"
    argv = ["benchmark", *(["--suite", "paper"] if option == "--rows" else []), option, value, "--out", str(out)]
    refused(capsys, argv, f"argument {option}:")
    assert not out.exists()


def test_an_unknown_map_in_the_list_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "bench"
    refused(capsys, ["benchmark", "--maps", f"{MAP},nope", "--out", str(out)], "--maps: not an eval map: nope")
    refused(capsys, ["benchmark", "--suite", "paper", "--maps", "nope", "--out", str(out)], "not an eval map")
    assert not out.exists()


# --resume names the settings that differ.

def test_a_run_of_other_settings_names_the_fields_that_differ(tmp_path):
    from superex_deploy.commands.benchmark import prepare_output

    base = {"maps": ["a"], "planners": ["nearest"], "steps": 20, "seed": 0,
            "profile_settings": {"prediction": {"every_steps": 2}, "members": 1}}
    out = tmp_path / "bench"
    journal = prepare_output(out, base, resume=False)
    journal.write_text('{"key": "a/0/nearest", "result": 1}\n')
    other = {**base, "steps": 30, "seed": 2, "profile_settings": {"prediction": {"every_steps": 3}, "members": 1}}
    with pytest.raises(ValueError) as error:
        prepare_output(out, other, resume=True)
    message = str(error.value)
    assert "steps: recorded 20, now 30" in message and "seed: recorded 0, now 2" in message
    assert "profile_settings.prediction.every_steps: recorded 2, now 3" in message
    assert "maps" not in message and "members" not in message and len(message) < 300
    assert prepare_output(out, base, resume=True) == journal  # the same settings resume


def test_a_folder_whose_journal_holds_nothing_is_reused(tmp_path):
    # What an early failure or signal used to leave: settings and an empty journal refusing any later valid run.
    from superex_deploy.commands.benchmark import prepare_output

    out = tmp_path / "bench"
    out.mkdir()
    (out / "settings.json").write_text(json.dumps({"steps": 5, "seed": -5}))
    (out / "episodes.jsonl").write_text("")
    assert prepare_output(out, {"steps": 20, "seed": 0}, resume=False) == out / "episodes.jsonl"
    assert json.loads((out / "settings.json").read_text()) == {"steps": 20, "seed": 0}


@FUZZ
@given(recorded=st.dictionaries(st.sampled_from("abc"), st.one_of(st.integers(0, 2), st.dictionaries(
    st.sampled_from("xy"), st.integers(0, 2), max_size=2)), max_size=3),
       new=st.dictionaries(st.sampled_from("abc"), st.one_of(st.integers(0, 2), st.dictionaries(
           st.sampled_from("xy"), st.integers(0, 2), max_size=2)), max_size=3))
def test_settings_differ_exactly_where_a_field_is_named(recorded, new):
    differences = settings_differences(recorded, new)
    assert (differences == []) == (recorded == new)
    for key in set(recorded) | set(new):
        named = any(d.startswith(f"{key}:") or d.startswith(f"{key}.") for d in differences)
        assert named == (recorded.get(key, "absent") != new.get(key, "absent"))


# A replay names what its recording lacks.

@pytest.mark.parametrize("seed", [-1, True, 2.5])
def test_replay_names_a_bad_recorded_seed(seed):
    from superex_deploy.recording.metadata import explorer_arguments
    from tests.conftest import nearest_metadata

    with pytest.raises(ValueError, match="the recording's seed must be an integer >= 0"):
        explorer_arguments(nearest_metadata(seed=seed), MapFrame((10, 10), 0.1), None)


def test_replay_names_a_missing_configuration():
    from superex_deploy.recording.metadata import explorer_arguments
    from tests.conftest import nearest_metadata

    metadata = {key: value for key, value in nearest_metadata().items() if key != "explorer"}
    with pytest.raises(ValueError, match="the recording's metadata lacks 'explorer'"):
        explorer_arguments(metadata, MapFrame((10, 10), 0.1), None)
    with pytest.raises(ValueError, match="ExplorerConfig has no field 'no_such_field'"):
        explorer_arguments(nearest_metadata(explorer={"no_such_field": 1}), MapFrame((10, 10), 0.1), None)
