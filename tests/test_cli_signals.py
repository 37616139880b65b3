"""Every command stopped by a signal (SIGINT, SIGTERM) says so in one line, exits with the code a shell reports (130
for SIGINT, 143 for SIGTERM) and keeps what it promised to keep: the rule for a signal inside a deferred block, every
command in-process, then real ``superex`` processes (an explore recording that replays, a benchmark that leaks no
worker and keeps its journal)."""

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

from superex_deploy.cli import COMMANDS, main
from superex_deploy.messages import Command, LaserScan, MapFrame, Observation, Pose2D
from superex_deploy.parallel import Interrupted, read_journal, signals_deferred, stop_signals

ROOT = Path(__file__).resolve().parents[1]
MAP = "50045230"  # the smallest bundled map
CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


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

    module = importlib.import_module(f"superex_deploy.commands.{command.replace('-', '_')}")

    def interrupted_run(args):
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler raises long before
        raise AssertionError("the signal did not stop the command")

    monkeypatch.setattr(module, "run", interrupted_run)
    argv = {"scan": ["--map", MAP, "--out", str(tmp_path)], "explore": ["--map", MAP, "--out", str(tmp_path)],
            "benchmark": ["--out", str(tmp_path)], "replay": ["x.mcap", "--out", str(tmp_path)], "warmup": [],
            "convert-recording": ["x.mcap", "y.mcap"],
            "offline": ["x.bag", "--out", str(tmp_path)], "node": [], "robot-sim": ["--map", MAP]}[command]
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert main([command, *argv]) == CODES[signum]
    err = capsys.readouterr().err
    assert err == f"superex {command}: stopped by {signal.Signals(signum).name}\n"
    # The caller's handlers came back (Python's default_int_handler, or SIG_IGN in a shell's background job).
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers


def test_a_replay_stopped_midway_writes_nothing_and_says_so(tmp_path, capsys, monkeypatch):
    from superex_deploy.onboard import Explorer

    record = tmp_path / "ep.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "20", "--gif-every", "0", "--out",
                 str(tmp_path / "run"), "--record", str(record)]) == 0
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


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_explore_recording_stopped_by_a_signal_is_valid_and_replays(tmp_path, capsys, signum):
    from superex_deploy.recording import read_recording

    record, out = tmp_path / "ep.mcap", tmp_path / "run"
    # Compile the kernels first (a fresh clone's cache is cold): a signal that lands inside numba's compiler is not
    # the case under test, and the stop must come mid-episode.
    subprocess.run([sys.executable, "-m", "superex_deploy.cli", "explore", "--pipeline", "nearest", "--map", MAP,
                    "--steps", "30", "--spad", "--predictor", "observed", "--gif-every", "0",
                    "--out", str(tmp_path / "warm")], cwd=tmp_path,
                   env={**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}, capture_output=True,
                   timeout=600, check=True)
    run = _Superex(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "400", "--spad", "--predictor",
                    "observed", "--gif-every", "0", "--out", str(out), "--record", str(record)], tmp_path)
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


@pytest.mark.slow
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
    """A signal before the first whole step must not leave a 'replayable' file that replay
    then refuses; the recording is removed and the one line says so."""
    from superex_deploy.commands.explore import _StepsDone, _keep_interrupted
    from superex_deploy.maps import load_map
    from superex_deploy.messages import MapFrame
    from superex_deploy.recording import EpisodeRecorder

    grid = load_map("50052750")
    path = tmp_path / "early.mcap"
    record = EpisodeRecorder(path, MapFrame(grid.shape, grid.resolution_m),
                             {"planner": "nearest", "predictor": "observed", "seed": 0, "explorer": {}})
    args = argparse.Namespace(record=path, out=tmp_path, pipeline="nearest", planner="nearest", predictor="observed",
                              spad=False, seed=0, profile="full")
    kept = _keep_interrupted(args, grid, (0, 0), _StepsDone(), record, "SIGINT")
    assert "no whole step was recorded" in kept
    assert not path.exists() and not path.with_name(path.name + ".part").exists()
    assert json.loads((tmp_path / "metrics.json").read_text())["interrupted"] == "SIGINT"


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
    import superex_deploy.evaluation.episodes as episode
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
    code = main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "40", "--predictor", "observed",
                 "--gif-every", "0", "--out", str(out), "--record", str(record)])
    err = capsys.readouterr().err
    assert code == 143
    assert _one_stop_line(err, "explore", signal.SIGTERM).endswith("marked interrupted")
    assert [s.step for s in read_recording(record).steps] == list(range(12))
    assert json.loads((out / "metrics.json").read_text())["interrupted"] == "SIGTERM"
