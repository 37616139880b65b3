"""The prediction schedule's modes: the free-running mode never waits for an unfinished prediction, the
simulated clock's episodes are reproducible, the commands carry the prediction's age, a replay follows a free run's recorded predictions exactly, and the explorer's thread budget."""

import threading

import numba
import numpy as np
import pytest

from superex_deploy.onboard.explorer import Explorer, ExplorerConfig, PredictionSchedule
from superex_deploy.onboard.prediction.inference import ThreadBudget, available_cores
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.reuse import PredictionReuse
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import UNKNOWN, Prediction
from superex_deploy.evaluation.episodes import make_world_and_explorer
from superex_deploy.sim.exploration import ExplorationConfig


class _SizeDependent(ObservedAsPrediction):
    """Unknown cells get a wall probability that depends on the map's size (a crop differs from the whole map) and
    on the number of calls so far (the order of the calls shows): any difference in what is predicted, on which
    map, in which order, changes the output."""

    name = "size-dependent"

    def __init__(self):
        self.calls = 0
        self.lock = threading.Lock()

    def predict(self, observed, extra=None):
        with self.lock:
            self.calls += 1
            calls = self.calls
        base = super().predict(observed, extra)
        value = np.float32(0.2 + 0.3 * observed.shape[0] / 80 + 1e-3 * (calls % 7))
        mean = np.where(observed == UNKNOWN, value, base.mean).astype(np.float32)
        return Prediction(mean=mean, variance=np.full(observed.shape, 0.1, np.float32))


def _explorer(grid, schedule, predictor, reuse=PredictionReuse(crop_margin_m=1.0), cores=None):
    cfg = ExplorationConfig(iou_every=0, explorer=ExplorerConfig(prediction=schedule, reuse=reuse))
    world, explorer = make_world_and_explorer(grid, (40, 6), make_planner("mapex"), predictor, cfg=cfg)
    if cores is not None:
        explorer = Explorer(explorer.frame, explorer.planner, predictor, cfg=cfg.explorer, cores=cores)
    return world, explorer


def _episode(grid, schedule, steps=70, predictor=None, follow=None, observations=None):
    """(commands, observations) of one episode on ``grid`` from (40, 6); ``observations`` given: those are fed
    instead of the world's."""
    world, explorer = _explorer(grid, schedule, predictor or _SizeDependent())
    commands, seen = [], []
    with explorer:
        if follow is not None:
            explorer.follow_recorded_predictions(follow)
        for t in range(steps if observations is None else len(observations)):
            observation = world.observe() if observations is None else observations[t]
            seen.append(observation)
            commands.append(explorer.step(observation))
            if commands[-1].finished:
                break
            world.apply(commands[-1])
    return commands, seen


def _same_commands(first, second):
    assert len(first) == len(second)
    for a, b in zip(first, second):
        assert (a.goal_rc, a.new_goal, a.finished, a.prediction_step, a.prediction_age_steps, a.prediction_age_s) == \
               (b.goal_rc, b.new_goal, b.finished, b.prediction_step, b.prediction_age_steps, b.prediction_age_s), a.step
        np.testing.assert_array_equal(a.path_rc, b.path_rc)
        assert (a.prediction is None) == (b.prediction is None)
        if a.prediction is not None:
            assert a.prediction.mean.tobytes() == b.prediction.mean.tobytes()
            assert a.prediction.variance.tobytes() == b.prediction.variance.tobytes()


@pytest.mark.parametrize("every,after,wait_first", [(2, 2, True), (5, 3, False), (1, 1, False)])
def test_the_simulated_clock_gives_the_same_episode_bit_for_bit(corridor_rooms, every, after, wait_first):
    first, _ = _episode(corridor_rooms(), PredictionSchedule("simulated", every, after, wait_first))
    simulated, _ = _episode(corridor_rooms(), PredictionSchedule("simulated", every, after, wait_first))
    _same_commands(first, simulated)
    assert sum(c.new_goal for c in simulated) >= 3 and sum(c.prediction is not None for c in simulated) >= 40


def test_the_simulated_clock_runs_no_thread(corridor_rooms):
    calls = []

    class Where(_SizeDependent):
        def predict(self, observed, extra=None):
            calls.append(threading.current_thread() is threading.main_thread())
            return super().predict(observed, extra)

    _episode(corridor_rooms(), PredictionSchedule("simulated", 2, 2, True), steps=20, predictor=Where())
    assert calls and all(calls)


class _Blocking(ObservedAsPrediction):
    """Call number ``block_at`` blocks until ``release`` is set (or 60 s pass), telling when it started and when
    it finished; the others answer at once."""

    name = "blocking"

    def __init__(self, block_at):
        self.calls, self.block_at = 0, block_at
        self.started, self.release, self.finished = threading.Event(), threading.Event(), threading.Event()

    def predict(self, observed, extra=None):
        self.calls += 1
        if self.calls == self.block_at:
            self.started.set()
            self.release.wait(60)
            self.finished.set()
        return super().predict(observed, extra)


@pytest.mark.parametrize("wait_first", [True, False])
def test_the_free_mode_never_waits_for_an_unfinished_prediction(corridor_rooms, wait_first):
    """While the worker is stuck in a prediction, every step after the first returns without it (a step that
    waited could only return after the 60 s the predictor blocks for, which sets ``finished`` first); once it is
    released, the next step after it finished applies it."""
    predictor = _Blocking(block_at=2 if wait_first else 1)  # the first prediction the worker runs alone
    world, explorer = _explorer(corridor_rooms(), PredictionSchedule("free", wait_first=wait_first), predictor)
    with explorer:
        first = explorer.step(world.observe())
        assert (first.prediction_step, first.prediction_age_steps) == ((0, 0) if wait_first else (-1, None))
        world.apply(first)
        for t in range(1, 25):
            command = explorer.step(world.observe())
            assert predictor.started.wait(60) and not predictor.finished.is_set(), t
            # wait_first: step 0's prediction landed at step 0, the blocked one is step 1's map;
            # without it step 0's map is the blocked one and nothing has landed.
            assert command.prediction_step == (0 if wait_first else -1), t
            if wait_first:
                assert command.prediction_age_steps == t and command.prediction_age_s == pytest.approx(0.1 * t)
            else:
                assert command.prediction is None and command.prediction_age_s is None
            world.apply(command)
        assert predictor.calls == predictor.block_at  # no other prediction was started while the worker was busy
        predictor.release.set()
        assert predictor.finished.wait(60)
        while explorer.scheduled._pending is not None and not explorer.scheduled._pending.done():
            predictor.finished.wait(0.01)  # the future completes just after predict returns
        command = explorer.step(world.observe())
        assert command.prediction_step == (1 if wait_first else 0) and command.step == 25
        assert explorer.scheduled.blocking_waits <= (1 if wait_first else 0)  # at most step 0's own


def test_a_free_run_replays_exactly_when_its_recorded_predictions_are_followed(corridor_rooms):
    """A free run's predictions land when its worker finished them; an explorer that follows the recorded
    ``prediction_step`` of each command, predicting inline, makes the same commands and the same predictions."""
    import time

    class Jittery(_SizeDependent):
        def predict(self, observed, extra=None):
            time.sleep(0.001 * (self.calls % 5))  # landing steps that no fixed schedule gives
            return super().predict(observed, extra)

    free, observations = _episode(corridor_rooms(), PredictionSchedule("free", wait_first=True), steps=60,
                                  predictor=Jittery())
    landed = [c.prediction_step for c in free]
    replayed, _ = _episode(corridor_rooms(), PredictionSchedule("free", wait_first=True), predictor=_SizeDependent(),
                           follow=landed, observations=observations)
    _same_commands(free, replayed)
    with pytest.raises(ValueError, match="must lie in -1..step"):
        _explorer(corridor_rooms(), PredictionSchedule("free"), _SizeDependent())[1].follow_recorded_predictions([0, 2])
    with pytest.raises(ValueError, match="an inline schedule predicts each step's own map"):
        _explorer(corridor_rooms(), PredictionSchedule(), _SizeDependent())[1].follow_recorded_predictions([0])


def test_the_command_carries_the_prediction_age(corridor_rooms):
    inline, _ = _episode(corridor_rooms(), PredictionSchedule(), steps=30)
    for command in inline:
        if command.prediction is None:
            assert command.prediction_age_steps is None and command.prediction_age_s is None
        else:
            assert command.prediction_age_steps == command.step - command.prediction_step >= 0
            assert command.prediction_age_s == pytest.approx(0.1 * command.prediction_age_steps)
    assert any(c.prediction_age_steps == 0 for c in inline) and any(c.prediction_age_steps > 0 for c in inline)
    simulated, _ = _episode(corridor_rooms(), PredictionSchedule("simulated", 4, 3), steps=30)
    assert [c.prediction_age_steps for c in simulated[:3]] == [None] * 3
    assert all(3 <= c.prediction_age_steps <= 6 for c in simulated[3:])
    assert all(c.prediction_age_s == pytest.approx(0.1 * c.prediction_age_steps) for c in simulated[3:])


def test_schedules_are_checked_and_older_ones_are_converted():
    from superex_deploy.recording.convert import schedule_in_modes

    def older(fields):
        return PredictionSchedule.from_json(schedule_in_modes(fields))

    assert older({"asynchronous": False, "every_steps": 10, "apply_after_steps": 1}) == PredictionSchedule()
    assert older({"asynchronous": True, "every_steps": 2, "apply_after_steps": 2, "wait_first": True}) == \
        PredictionSchedule("simulated", 2, 2, True)
    assert older({"asynchronous": True, "every_steps": 0}).mode == "free"
    assert PredictionSchedule.from_json({"mode": "free"}) == PredictionSchedule("free")
    with pytest.raises(ValueError, match="PredictionSchedule has no field 'asynchronous'"):
        PredictionSchedule.from_json({"asynchronous": False})
    with pytest.raises(ValueError, match="mode must be one of inline, free, simulated, got True"):
        PredictionSchedule(True, 2, 2)
    with pytest.raises(ValueError, match="mode must be one of inline, free, simulated, got 'thread'"):
        PredictionSchedule.from_json({"mode": "thread"})  # the retired mode
    with pytest.raises(ValueError, match="every_steps must be >= 1 in simulated mode"):
        PredictionSchedule("simulated", 0)
    with pytest.raises(ValueError, match="either mode or the older asynchronous"):
        schedule_in_modes({"mode": "free", "asynchronous": True})
    with pytest.raises(ValueError, match="PredictionSchedule has no field 'every'"):
        PredictionSchedule.from_json({"every": 2})
    assert [PredictionSchedule(m, 2, 1).threaded for m in ("inline", "free", "simulated")] == [False, True, False]


def test_the_thread_budget_splits_the_cores_between_loop_and_worker():
    assert (ThreadBudget(2, True).control_threads, ThreadBudget(2, True).worker_threads) == (1, 1)
    assert (ThreadBudget(4, True).control_threads, ThreadBudget(4, True).worker_threads) == (2, 2)
    assert (ThreadBudget(1, True).control_threads, ThreadBudget(1, True).worker_threads) == (1, 1)
    assert (ThreadBudget(3, False).control_threads, ThreadBudget(3, False).worker_threads) == (3, 0)
    assert ThreadBudget.for_cores(None, False).cores == available_cores() >= 1
    with pytest.raises(ValueError, match="cores must be an integer >= 1, got 0"):
        ThreadBudget(0, True)


class _ThreadCounts(ObservedAsPrediction):
    """Records numba's thread count in the thread that predicts."""

    name = "thread-counts"

    def __init__(self):
        self.seen = []

    def predict(self, observed, extra=None):
        self.seen.append((threading.current_thread() is threading.main_thread(), numba.get_num_threads()))
        return super().predict(observed, extra)


@pytest.mark.parametrize("mode,cores", [("free", 2), ("simulated", 2), ("free", 1)])
def test_the_explorer_sets_numba_threads_in_its_loop_and_its_worker(corridor_rooms, mode, cores):
    launched = numba.config.NUMBA_NUM_THREADS
    predictor = _ThreadCounts()
    world, explorer = _explorer(corridor_rooms(), PredictionSchedule(mode, 2, 1, wait_first=True), predictor,
                                cores=cores)
    budget = explorer.budget
    assert budget == ThreadBudget(cores, mode != "simulated")
    inside = []
    planner_choose = explorer.planner.choose_goal

    def choose(context):  # the control loop's thread count, read inside the step
        inside.append(numba.get_num_threads())
        return planner_choose(context)

    explorer.planner.choose_goal = choose
    callers = numba.get_num_threads()
    with explorer:
        for _ in range(12):
            command = explorer.step(world.observe())
            assert numba.get_num_threads() == callers  # the caller's own count is restored
            world.apply(command)
    assert inside and set(inside) == {min(budget.control_threads, launched)}
    worker = {n for main, n in predictor.seen if not main}
    control = {n for main, n in predictor.seen if main}
    if mode == "simulated":
        assert not worker and control == {min(budget.control_threads, launched)}
    else:
        assert not control and worker == {min(budget.worker_threads, launched)}


def test_the_profile_gives_the_sessions_the_workers_share_of_the_cores():
    from superex_deploy.pipeline import PROFILES, make_predictor

    realtime, full = PROFILES["realtime"], PROFILES["full"]
    assert realtime.session_config(4).intra_op_threads == 2 and realtime.session_config(2).intra_op_threads == 1
    assert realtime.session_config(None) == realtime.session  # the benchmarks: fixed, the same on any machine
    assert full.session_config(8) == full.session  # inline: the full profile is kept as it is
    ensemble = make_predictor("lama_los", profile=realtime, cores=4)
    options = [member.session.get_session_options() for member in ensemble._members]
    assert options and {o.intra_op_num_threads for o in options} == {2}
    ensemble = make_predictor("lama_los", profile=realtime, cores=2)
    assert {m.session.get_session_options().intra_op_num_threads for m in ensemble._members} == {1}


def test_a_recording_made_before_the_schedule_modes_converts_and_replays(tmp_path, monkeypatch):
    """A recording of the version before: its command schema lacks ``prediction_age_s``, its metadata holds the
    schedule as ``asynchronous`` and the profile without ``simulated_schedule`` (format "1"): converted, it
    replays."""
    import json

    from superex_deploy.cli import main
    from superex_deploy.recording import read_recording
    from superex_deploy.recording import metadata as recorded
    from superex_deploy.recording import schemas

    old_command = schemas.EXPLORER_COMMAND_MSG.replace(
        "float64 prediction_age_s # seconds from that step's stamp to this one's; NaN for none (absent in older "
        "files)\n", "")
    assert old_command != schemas.EXPLORER_COMMAND_MSG
    monkeypatch.setitem(schemas.SCHEMAS, "/command", ("superex_msgs/msg/ExplorerCommand", old_command))
    old_schedule = {"asynchronous": False, "every_steps": 10, "apply_after_steps": 1, "wait_first": False}
    written = recorded.recording_metadata

    def old_metadata(**kwargs):
        metadata = written(**kwargs)
        metadata["format_version"] = "1"
        metadata["explorer"]["prediction"] = dict(old_schedule)
        metadata["profile_settings"]["schedule"] = dict(old_schedule)
        del metadata["profile_settings"]["simulated_schedule"]
        return metadata

    monkeypatch.setattr(recorded, "recording_metadata", old_metadata)
    record = tmp_path / "old.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--planner", "mapex", "--profile", "full",
                 "--steps", "12", "--gif-every", "0", "--out", str(tmp_path / "run"), "--record", str(record)]) == 0
    monkeypatch.undo()
    assert main(["convert-recording", str(record), str(tmp_path / "new.mcap")]) == 0
    recording = read_recording(tmp_path / "new.mcap")
    assert recording.metadata["explorer"]["prediction"] == {"mode": "inline", "every_steps": 10,
                                                            "apply_after_steps": 1, "wait_first": False}
    assert len(recording.steps) == 12 and all(s.prediction_age_s is None for s in recording.steps)
    assert any(s.prediction_step >= 0 for s in recording.steps)  # MapEx asked: the new schema would hold ages
    assert main(["replay", str(tmp_path / "new.mcap"), "--out", str(tmp_path / "replay")]) == 0
    assert json.loads((tmp_path / "replay" / "metrics.json").read_text())["goals_match"]
