"""Issue #23, the command-line rows of the hostile pass: every bad argument gets one clear error that names its
option before anything is created, and every command stopped by a signal says so in one line, exits with the code a
shell reports (130 for SIGINT, 143 for SIGTERM) and keeps what it promised to keep."""

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.cli import COMMANDS, main
from superex_deploy.commands.options import (name_list, non_negative_int, planner_options, positive_int,
                                             settings_differences)
from superex_deploy.messages import Command, LaserScan, MapFrame, Observation, Pose2D
from superex_deploy.parallel import Interrupted, read_journal, signals_deferred, stop_signals

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
                              "step_cells"]),
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


# Rows 2, 16: numbers are checked by their argparse type, which names the option.

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
    _refused(capsys, argv + ["--out", str(out)], f"argument {option}: must be an integer >=")
    assert not out.exists()


def test_gif_every_zero_writes_no_gif(tmp_path, capsys):
    from superex_deploy.render import GifRecorder

    out = tmp_path / "run"
    assert main(["explore", "--map", MAP, "--steps", "5", "--gif-every", "0", "--out", str(out)]) == 0
    assert (out / "metrics.json").exists() and not (out / "episode.gif").exists()
    assert "episode.gif" not in capsys.readouterr().out
    for every in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="every must be an integer >= 1"):
            GifRecorder(every=every)


# Row 8: output paths are checked before any work.

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
    _refused(capsys, argv + ["--out", str(out)], f"--out {out}", message)
    assert a_file.read_text() == "x" and sorted(tmp_path.iterdir()) == [a_file]


# Row 19: the recording's folder is checked up front too; a map without start poses asks for --pose.

def test_a_record_path_in_a_missing_folder_leaves_nothing_behind(tmp_path, capsys):
    out = tmp_path / "run"
    _refused(capsys, ["explore", "--map", MAP, "--steps", "5", "--out", str(out), "--record",
                      str(tmp_path / "nodir" / "x.mcap")], "--record", "the folder", "does not exist")
    _refused(capsys, ["explore", "--map", MAP, "--steps", "5", "--out", str(out), "--record", str(tmp_path)],
             "is a folder, not a file")
    assert list(tmp_path.iterdir()) == []
    # A folder that --out creates is fine: the recording goes beside the run.
    new = tmp_path / "new"
    assert main(["explore", "--map", MAP, "--steps", "5", "--gif-every", "0", "--out", str(new / "run"),
                 "--record", str(new / "x.mcap")]) == 0
    assert (new / "x.mcap").exists() and (new / "run" / "metrics.json").exists()


@pytest.mark.parametrize("command", ["explore", "scan"])
def test_a_map_without_start_poses_asks_for_pose(tmp_path, capsys, command):
    from PIL import Image

    image = np.full((60, 80), 255, np.uint8)
    image[[0, -1], :] = image[:, [0, -1]] = 0
    Image.fromarray(image).save(tmp_path / "small.png")
    out = tmp_path / "out"
    _refused(capsys, [command, "--map", str(tmp_path / "small.png"), "--out", str(out)],
             "has no start poses", "--pose ROW COL")
    assert not out.exists()
    extra = ["--steps", "2", "--gif-every", "0"] if command == "explore" else ["--secondary", "4"]
    assert main([command, "--map", str(tmp_path / "small.png"), "--pose", "30", "40", *extra, "--out", str(out)]) == 0


# Row 13: lists are never empty.

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
    _refused(capsys, argv, f"argument {option}:")
    assert not out.exists()


def test_an_unknown_map_in_the_list_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "bench"
    _refused(capsys, ["benchmark", "--maps", f"{MAP},nope", "--out", str(out)], "--maps: not an eval map: nope")
    _refused(capsys, ["benchmark", "--suite", "paper", "--maps", "nope", "--out", str(out)], "not an eval map")
    assert not out.exists()


# Row 18: --resume names the settings that differ.

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


# Row 9: signals. The rule first, then every command, then real processes.

def test_a_signal_inside_a_deferred_block_is_handled_when_it_ends():
    events = []
    with pytest.raises(Interrupted) as stop, stop_signals():
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            events.append("the block finished")
    assert events == ["the block finished"] and stop.value.exit_code == 143 and stop.value.signal_name == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # the handlers came back


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_stopped_by_a_signal_says_so_in_one_line(monkeypatch, capsys, tmp_path, command, signum):
    import importlib

    module = importlib.import_module(f"superex_deploy.commands.{command}")

    def interrupted_run(args):
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler raises long before
        raise AssertionError("the signal did not stop the command")

    monkeypatch.setattr(module, "run", interrupted_run)
    argv = {"scan": ["--map", MAP, "--out", str(tmp_path)], "explore": ["--map", MAP, "--out", str(tmp_path)],
            "benchmark": ["--out", str(tmp_path)], "replay": ["x.mcap", "--out", str(tmp_path)], "warmup": []}[command]
    assert main([command, *argv]) == CODES[signum]
    err = capsys.readouterr().err
    assert err == f"superex {command}: stopped by {signal.Signals(signum).name}\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_replay_stopped_midway_writes_nothing_and_says_so(tmp_path, capsys, monkeypatch):
    from superex_deploy.onboard import Explorer

    record = tmp_path / "ep.mcap"
    assert main(["explore", "--map", MAP, "--steps", "20", "--gif-every", "0", "--out", str(tmp_path / "run"),
                 "--record", str(record)]) == 0
    step = Explorer.step

    def step_then_sigint(self, observation):
        command = step(self, observation)
        if command.step == 7:
            os.kill(os.getpid(), signal.SIGINT)
        return command

    monkeypatch.setattr(Explorer, "step", step_then_sigint)
    capsys.readouterr()
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 130
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == "superex replay: stopped by SIGINT" and "Traceback" not in err
    assert not (tmp_path / "replay").exists()


def test_a_recorder_left_by_a_keyboard_interrupt_closes_a_valid_file(tmp_path):
    from superex_deploy.recording import EpisodeRecorder, read_recording

    path = tmp_path / "r.mcap"
    scan = LaserScan(0.0, 2 * math.pi / 72, 0.1, 5.0, np.full(72, 1.0))
    with pytest.raises(KeyboardInterrupt):
        with EpisodeRecorder(path, MapFrame((20, 20), 0.1), {}) as recorder:
            for step in range(5):
                recorder.write(Observation(float(step), Pose2D(1.0, 1.0), scan),
                               Command(float(step), None, None, np.zeros((0, 2)), np.zeros((0, 2), np.int64), False,
                                       False, step=step))
            raise KeyboardInterrupt
    recording = read_recording(path)
    assert recording.error is None and [s.step for s in recording.steps] == list(range(5))
    assert not (tmp_path / "r.mcap.part").exists()
    with pytest.raises(RuntimeError):
        with EpisodeRecorder(tmp_path / "failed.mcap", MapFrame((20, 20), 0.1), {}):
            raise RuntimeError("a failing episode")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.mcap"]


class _Superex:
    """``superex ARGV`` in a subprocess of its own session, its stderr read as it comes."""

    def __init__(self, argv, cwd):
        env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
        self.process = subprocess.Popen([sys.executable, "-m", "superex_deploy.cli", *argv], cwd=cwd, env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                        start_new_session=True)
        self.err = ""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for chunk in iter(lambda: self.process.stderr.read(1), ""):
            self.err += chunk

    def wait_for(self, condition, timeout=120.0):
        deadline = time.monotonic() + timeout
        while not condition():
            assert self.process.poll() is None, f"ended early:\n{self.err}"
            assert time.monotonic() < deadline, f"timed out:\n{self.err}"
            time.sleep(0.05)

    def stop(self, signum, group=False) -> str:
        """Send ``signum`` (to the whole process group, as Ctrl-C in a terminal does, with ``group``); returns
        stderr once the process has ended."""
        if group:
            os.killpg(self.process.pid, signum)
        else:
            self.process.send_signal(signum)
        self.process.wait(timeout=120)
        self._reader.join(10)
        return self.err


def _one_stop_line(err: str, command: str, signum) -> str:
    assert "Traceback" not in err and "Warning" not in err and "leaked" not in err, err
    # The notice of a cold numba cache (a fresh clone's first run) is not the stop line.
    lines = [line for line in err.replace("\r", "\n").splitlines()
             if line.startswith("superex") and "first run here" not in line]
    assert len(lines) == 1 and lines[0].startswith(f"superex {command}: stopped by {signal.Signals(signum).name}"), err
    return lines[0]


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_explore_recording_stopped_by_a_signal_is_valid_and_replays(tmp_path, capsys, signum):
    from superex_deploy.recording import read_recording

    record, out = tmp_path / "ep.mcap", tmp_path / "run"
    # Compile the kernels first (a fresh clone's cache is cold): a signal that lands inside numba's compiler is not
    # the case under test, and the stop must come mid-episode.
    subprocess.run([sys.executable, "-m", "superex_deploy.cli", "explore", "--map", MAP, "--steps", "30", "--spad",
                    "--predictor", "observed", "--gif-every", "0", "--out", str(tmp_path / "warm")], cwd=tmp_path,
                   env={**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}, capture_output=True,
                   timeout=600, check=True)
    run = _Superex(["explore", "--map", MAP, "--steps", "400", "--spad", "--predictor", "observed", "--gif-every", "0",
                    "--out", str(out), "--record", str(record)], tmp_path)
    run.wait_for(lambda: any(int(n) >= 12 for n in re.findall(r"(\d+)/400", run.err)))
    err = run.stop(signum, group=signum == signal.SIGINT)
    assert run.process.returncode == CODES[signum]
    line = _one_stop_line(err, "explore", signum)
    recording = read_recording(record)
    steps = len(recording.steps)
    assert recording.error is None and 12 <= steps < 400 and not Path(f"{record}.part").exists()
    assert [s.step for s in recording.steps] == list(range(steps))
    assert f"{record} holds the {steps} whole steps recorded" in line
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] == signal.Signals(signum).name and not metrics["finished"]
    assert metrics["steps"] in (steps - 1, steps)  # a step is recorded before its metrics are logged
    assert len(metrics["coverage"]) == len(metrics["poses"]) == metrics["steps"]
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["steps"] == steps
    # The partial metrics hold the goals of the steps done: those the replay finds in them.
    assert [s for s in replay["goals"]["steps"] if s < metrics["steps"]] == metrics["goals"]["steps"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_benchmark_stopped_by_a_signal_leaks_nothing_and_keeps_its_journal(tmp_path, signum):
    out = tmp_path / "bench"
    run = _Superex(["benchmark", "--maps", MAP, "--planners", "nearest,hector", "--steps", "400", "--jobs", "2",
                    "--out", str(out)], tmp_path)
    run.wait_for(lambda: len(read_journal(out / "episodes.jsonl")) >= 1)
    err = run.stop(signum, group=signum == signal.SIGINT)
    assert run.process.returncode == CODES[signum]
    line = _one_stop_line(err, "benchmark", signum)
    held = len(read_journal(out / "episodes.jsonl"))
    assert 1 <= held < 8 and f"{held} of 8 episodes are in" in line and "rerun with --resume" in line
    assert not (out / "results.json").exists()


def test_a_recording_stopped_before_its_first_step_leaves_no_file(tmp_path):
    """Second hostile pass: a signal before the first whole step must not leave a 'replayable' file that replay
    then refuses; the recording is removed and the one line says so."""
    from superex_deploy.commands.explore import _StepsDone, _keep_interrupted
    from superex_deploy.maps import load_map
    from superex_deploy.messages import MapFrame
    from superex_deploy.recording import EpisodeRecorder

    grid = load_map("50052750")
    path = tmp_path / "early.mcap"
    record = EpisodeRecorder(path, MapFrame(grid.shape, grid.resolution_m),
                             {"planner": "nearest", "predictor": "observed", "seed": 0, "explorer": {}})
    args = argparse.Namespace(record=path, out=tmp_path, planner="nearest", predictor="observed", seed=0,
                              profile="full")
    kept = _keep_interrupted(args, grid, (0, 0), _StepsDone(), record, "SIGINT")
    assert "no whole step was recorded" in kept
    assert not path.exists() and not path.with_name(path.name + ".part").exists()
    assert json.loads((tmp_path / "metrics.json").read_text())["interrupted"] == "SIGINT"


@pytest.mark.parametrize("seed", [-1, True, 2.5])
def test_replay_names_a_bad_recorded_seed(seed):
    from superex_deploy.commands.replay import build_explorer
    from superex_deploy.messages import MapFrame

    metadata = {"planner": "nearest", "predictor": "observed", "seed": seed, "explorer": {}}
    with pytest.raises(ValueError, match="the recording's seed must be an integer >= 0"):
        build_explorer(metadata, MapFrame((10, 10), 0.1), None)


def test_replay_names_a_missing_configuration_field():
    from superex_deploy.commands.replay import build_explorer
    from superex_deploy.messages import MapFrame

    metadata = {"planner": "nearest", "predictor": "observed", "seed": 0, "explorer": {}}
    with pytest.raises(ValueError, match="cannot be rebuilt: it lacks the field 'motion'"):
        build_explorer(metadata, MapFrame((10, 10), 0.1), None)


def test_interruption_in_finds_a_signal_wrapped_by_a_c_callback():
    from superex_deploy.parallel import interruption_in

    stop = Interrupted(signal.SIGTERM)
    try:
        try:
            raise stop
        except Interrupted as inner:  # as numba's _numba_unpickle reports a handler's exception
            raise SystemError("returned a result with an exception set") from inner
    except SystemError as wrapped:
        assert interruption_in(wrapped) is stop
    assert interruption_in(stop) is stop
    assert interruption_in(ValueError("bad")) is None
    looped = ValueError("a")
    looped.__context__ = ValueError("b")
    looped.__context__.__context__ = looped  # a cycle ends the walk
    assert interruption_in(looped) is None


def test_explore_stopped_by_a_wrapped_signal_keeps_its_steps_like_the_signal(tmp_path, monkeypatch, capsys):
    """A SIGTERM that a C callback turned into a SystemError (seen under load in CI) ends the run as the signal
    does: exit 143, one stop line, the recording closed on its whole steps and replayable."""
    import superex_deploy.sim.episode as episode
    from superex_deploy.recording import read_recording

    real = episode.run_episode

    def stopped_at_step_12(*args, on_observation=None, **kwargs):
        def observe(observation, command, explorer):
            on_observation(observation, command, explorer)
            if explorer.steps >= 12:
                try:
                    raise Interrupted(signal.SIGTERM)
                except Interrupted as stop:
                    raise SystemError("<function _numba_unpickle> returned a result with an exception set") from stop
        return real(*args, on_observation=observe, **kwargs)

    monkeypatch.setattr(episode, "run_episode", stopped_at_step_12)
    record, out = tmp_path / "ep.mcap", tmp_path / "run"
    code = main(["explore", "--map", MAP, "--steps", "40", "--predictor", "observed", "--gif-every", "0",
                 "--out", str(out), "--record", str(record)])
    err = capsys.readouterr().err
    assert code == 143
    assert _one_stop_line(err, "explore", signal.SIGTERM).endswith("marked interrupted")
    assert [s.step for s in read_recording(record).steps] == list(range(12))
    assert json.loads((out / "metrics.json").read_text())["interrupted"] == "SIGTERM"
