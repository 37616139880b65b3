"""What an operator running an exploration node asks for: a bounded region (frontiers outside ignored, coverage
inside reported, done when the region is), a return to the start, a status on every command (through the CLI, the
Gymnasium environment and recordings), and goals given up when the robot makes no progress or cannot reach them,
or replaced by a clearly better one.

Most cases run the explorer on hand-built SLAM maps of an 80 x 80 frame at 0.1 m: a corridor (rows 36-44, walls on
rows 35 and 45) from column 10 to column 70, unknown beyond both ends, so that it has a frontier at each end."""

import json
import re
from dataclasses import asdict

import numpy as np
import pytest

from superex_deploy.cli import main
from superex_deploy.messages import (DONE, EXPLORING, NO_REACHABLE_FRONTIER, RETURNING, STATUSES, WAITING_FOR_SCAN,
                                     LaserScan, MapFrame, Observation, OccupancyGridMessage, Pose2D)
from superex_deploy.onboard import Explorer, ExplorerConfig
from superex_deploy.onboard.planning.bounds import ExplorationBounds, clip_frontiers, parse_bounds
from superex_deploy.onboard.planning.goal_policy import GoalPolicy, GoalTracker
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.status import (ALL_BLACKLISTED, BACK_AT_START, NO_FRONTIER, NO_MEASUREMENT,
                                           NO_PROGRESS_HOME, OUTSIDE_BOUNDS, START_UNREACHABLE, Mission)
from superex_deploy.onboard.types import Frontier
from tests.test_cli_arguments import refused

FRAME = MapFrame((80, 80), 0.1, (0.0, 0.0))
MAP = "50045230"  # the smallest bundled map
# x from 2 m to 7.5 m, y from 3 m to 5 m: the corridor's east end (column 70, x = 7.05 m) inside, its west end
# (column 10, x = 1.05 m) outside.
EAST_ONLY = ((2.0, 3.0), (7.5, 3.0), (7.5, 5.0), (2.0, 5.0))


def _corridor(west_open: bool = True, closed_at=None) -> np.ndarray:
    slam = np.full(FRAME.shape, -1, np.int8)
    slam[36:45, 10:71] = 0
    slam[35, 9:72] = slam[45, 9:72] = 100
    if not west_open:
        slam[36:45, 10] = 100
    if closed_at is not None:
        slam[36:45, closed_at] = 100
    return slam


def _closed_room() -> np.ndarray:
    slam = np.full(FRAME.shape, -1, np.int8)
    slam[35:46, 9:72] = 100
    slam[36:45, 10:71] = 0
    return slam


def _step(explorer, slam, t, pose_rc=(40, 30)):
    x, y = FRAME.centre_xy(pose_rc)
    return explorer.step(Observation(float(t), Pose2D(x, y, 0.0), None,
                                     occupancy_grid=OccupancyGridMessage.from_frame_grid(FRAME, slam)))


def _explorer(planner="nearest", **cfg) -> Explorer:
    return Explorer(FRAME, make_planner(planner), ObservedAsPrediction(), cfg=ExplorerConfig(**cfg))


# Bounds


def test_frontiers_outside_the_bounds_are_not_chosen():
    # The west end is nearer (20 cells against 40): chosen without bounds, ignored with them.
    assert _step(_explorer(), _corridor(), 0).goal_rc[1] <= 12
    command = _step(_explorer(bounds=EAST_ONLY), _corridor(), 0)
    assert command.goal_rc[1] >= 68 and command.status == EXPLORING and command.reason == ""


def test_a_region_without_frontiers_inside_is_done_and_says_why():
    explorer = _explorer(bounds=((2.0, 3.0), (5.0, 3.0), (5.0, 5.0), (2.0, 5.0)))
    command = _step(explorer, _corridor(), 0)
    assert command.goal_rc is None and not command.finished  # the default finish delay, 5 s, first
    assert (command.status, command.reason) == (NO_REACHABLE_FRONTIER, OUTSIDE_BOUNDS)
    command = _step(explorer, _corridor(), 5.0)
    assert command.goal_rc is None and command.finished
    assert (command.status, command.reason) == (DONE, OUTSIDE_BOUNDS)


def test_the_mask_holds_the_cells_whose_centre_lies_inside_and_follows_a_new_grid():
    bounds = ExplorationBounds(((0.5, 0.5), (1.5, 0.5), (1.5, 1.5), (0.5, 1.5)))
    small = MapFrame((20, 20), 0.1)
    mask = bounds.mask(small)
    assert mask.sum() == 100 and mask[5:15, 5:15].all()
    mission = Mission(ExplorerConfig(bounds=bounds))
    grown = MapFrame((40, 40), 0.1, (-1.0, -1.0))
    assert mission.inside(small).sum() == 100 and mission.inside(grown).shape == (40, 40)
    assert mission.inside(grown).sum() == 100 and mission.inside(grown)[15:25, 15:25].all()


def test_a_frontier_cut_by_the_bounds_keeps_its_cells_inside_and_a_goal_among_them():
    inside = np.zeros((3, 8), bool)
    inside[:, 3:] = True
    cut = Frontier((0, 2), np.array([[0, c] for c in range(5)], np.int32))
    whole = Frontier((1, 5), np.array([[1, 4], [1, 5], [1, 6]], np.int32))
    outside = Frontier((2, 1), np.array([[2, 0], [2, 1]], np.int32))
    kept = clip_frontiers((cut, whole, outside), inside)
    assert len(kept) == 2 and kept[1] is whole
    assert kept[0].cell_rc == (0, 3) and kept[0].cells.tolist() == [[0, 3], [0, 4]]


@pytest.mark.parametrize("points, message", [
    (((0, 0), (1, 0)), "bounds must have at least 3 points (x, y), got 2"),
    (((0, 0), (float("nan"), 0.0), (1, 1)), "bounds point 1 must be a pair (x, y) of finite numbers in metres, got "
                                            "(nan, 0.0)"),
    (((0, 0), (1, 0), "ab"), "bounds point 2 must be a pair (x, y) of finite numbers in metres, got 'ab'"),
    (((0, 0), (1, 1), (1, 0), (0, 1)), "bounds polygon crosses itself: edge 0 (0.0, 0.0)-(1.0, 1.0) meets edge 2 "
                                       "(1.0, 0.0)-(0.0, 1.0)"),
    (((0, 0), (1, 0), (1, 0), (0, 1)), "bounds polygon repeats point 1 (1.0, 0.0) at point 2: it must not touch "
                                       "itself"),
    (((0, 0), (1, 0), (2, 0)), "bounds polygon has zero area"),
])
def test_a_bad_polygon_is_refused_with_one_clear_error(points, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        ExplorationBounds(points)
    with pytest.raises(ValueError, match=re.escape(message)):
        ExplorerConfig(bounds=points)


def test_bounds_that_do_not_contain_the_robot_are_refused_at_the_first_step():
    explorer = _explorer(bounds=((5.0, 3.0), (7.5, 3.0), (7.5, 5.0), (5.0, 5.0)))
    with pytest.raises(ValueError, match=re.escape("the exploration bounds must contain the robot's start pose: "
                                                   "(x, y) = (3.050, 3.950) m lies outside")):
        _step(explorer, _corridor(), 0)
    assert explorer.steps == 0


def test_bounds_survive_a_recorded_configuration():
    cfg = ExplorerConfig(bounds=EAST_ONLY, return_to_start=True, goal_policy=GoalPolicy(commit_margin=0.1))
    recorded = json.loads(json.dumps(asdict(cfg)))  # as a recording's metadata holds it
    again = ExplorerConfig(bounds=recorded["bounds"], return_to_start=recorded["return_to_start"],
                           goal_policy=recorded["goal_policy"])
    assert again == cfg and again.bounds.points == tuple((float(x), float(y)) for x, y in EAST_ONLY)


def test_an_episode_in_bounds_reports_coverage_inside_them_and_ends_when_they_are_explored(two_rooms):
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.sim.exploration import ExplorationConfig

    grid = two_rooms()  # the left room: columns 1-19, x up to 2 m
    left = ((0.05, 0.05), (1.95, 0.05), (1.95, 2.95), (0.05, 2.95))
    free = run_episode(grid, (5, 5), make_planner("nearest"), ObservedAsPrediction(), steps=300,
                       cfg=ExplorationConfig(iou_every=0))
    bounded = run_episode(grid, (5, 5), make_planner("nearest"), ObservedAsPrediction(), steps=300,
                          cfg=ExplorationConfig(explorer=ExplorerConfig(bounds=left).for_simulation(), iou_every=0))
    assert free.coverage_in_bounds is None and "coverage_in_bounds" not in free.to_json()
    assert bounded.finished and bounded.status == DONE and bounded.reason == OUTSIDE_BOUNDS
    assert bounded.steps < free.steps and bounded.coverage[-1] < free.coverage[-1]
    assert bounded.coverage_in_bounds[-1] > 0.95 > bounded.coverage[-1]
    assert bounded.to_json()["final_coverage_in_bounds"] == bounded.coverage_in_bounds[-1]
    with pytest.raises(ValueError, match="must contain the robot's start pose"):
        run_episode(grid, (5, 30), make_planner("nearest"), ObservedAsPrediction(), steps=3,
                    cfg=ExplorationConfig(explorer=ExplorerConfig(bounds=left), iou_every=0))


# Return to start and the status


def test_the_robot_returns_to_its_start_and_says_so(two_rooms):
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.sim.exploration import ExplorationConfig

    statuses = []
    start = (5, 5)
    cfg = ExplorationConfig(explorer=ExplorerConfig(return_to_start=True).for_simulation(), iou_every=0)
    result = run_episode(two_rooms(), start, make_planner("nearest"), ObservedAsPrediction(), steps=500, cfg=cfg,
                         on_observation=lambda obs, command, explorer: statuses.append(
                             (command.status, command.finished)))
    phases = [s for i, (s, _) in enumerate(statuses) if i == 0 or s != statuses[i - 1][0]]
    assert phases == [EXPLORING, RETURNING, DONE]
    assert [finished for _, finished in statuses] == [False] * (len(statuses) - 1) + [True]
    reach = cfg.explorer.motion.goal_reached_m / 0.1
    assert np.hypot(*(result.poses[-1] - np.array(start))) <= reach
    assert result.finished and result.reason == BACK_AT_START
    # Without the return, the episode ends where the last frontier was, away from the start.
    away = run_episode(two_rooms(), start, make_planner("nearest"), ObservedAsPrediction(), steps=500,
                       cfg=ExplorationConfig(iou_every=0))
    assert np.hypot(*(away.poses[-1] - np.array(start))) > reach and away.steps < result.steps


def test_a_start_cut_off_is_tried_again_and_given_up_only_after_the_progress_timeout():
    # 0.2.0 ended the mission for good at the first map that cut the start off (a SLAM map restarting).
    explorer = _explorer(return_to_start=True, finish_after_s=0.0, goal_policy=GoalPolicy(no_progress_s=5.0))
    assert _step(explorer, _corridor(), 0, pose_rc=(40, 20)).status == EXPLORING
    walled = _closed_room()
    walled[36:45, 30] = 100  # the start (column 20) cut off from the robot (column 60)
    command = _step(explorer, walled, 1, pose_rc=(40, 60))
    assert (command.status, command.reason, command.finished, command.goal_rc) == (RETURNING, START_UNREACHABLE,
                                                                                     False, None)
    command = _step(explorer, _closed_room(), 2, pose_rc=(40, 60))  # the next map: reachable again
    assert (command.status, command.reason, command.finished) == (RETURNING, "", False)
    assert command.goal_rc == FRAME.cell_of(*FRAME.centre_xy((40, 20)))
    for t in (3, 7):  # cut off from t = 3 on: given up 5 s later
        command = _step(explorer, walled, t, pose_rc=(40, 60))
    assert (command.status, command.reason, command.finished) == (RETURNING, START_UNREACHABLE, False)
    command = _step(explorer, walled, 8, pose_rc=(40, 60))
    assert (command.status, command.reason, command.finished, command.goal_rc) == (DONE, START_UNREACHABLE, True,
                                                                                     None)


def test_a_return_without_progress_is_given_up():
    # 0.2.0: a robot that makes no progress while returning stayed `returning` for ever.
    explorer = _explorer(return_to_start=True, finish_after_s=0.0, goal_policy=GoalPolicy(no_progress_s=5.0))
    _step(explorer, _corridor(), 0, pose_rc=(40, 20))
    statuses = [_step(explorer, _closed_room(), t, pose_rc=(40, 60)) for t in range(1, 8)]
    assert [c.status for c in statuses[:5]] == [RETURNING] * 5 and statuses[0].goal_rc is not None
    assert (statuses[5].status, statuses[5].reason, statuses[5].finished) == (DONE, NO_PROGRESS_HOME, True)


def test_the_status_goes_from_waiting_for_a_scan_to_exploring_to_done():
    explorer = _explorer(finish_after_s=0.0)
    pose = Pose2D(*FRAME.centre_xy((40, 30)), 0.0)
    invalid = LaserScan(0.0, 2 * np.pi / 90, 0.1, 4.0, np.full(90, np.nan))
    command = explorer.step(Observation(0.0, pose, invalid))
    assert (command.status, command.reason, command.finished) == (WAITING_FOR_SCAN, NO_MEASUREMENT, False)
    open_all_round = LaserScan(0.0, 2 * np.pi / 90, 0.1, 2.0, np.full(90, np.inf))
    command = explorer.step(Observation(0.1, pose, open_all_round))
    assert (command.status, command.reason) == (EXPLORING, "") and command.goal_rc is not None
    command = _step(explorer, _closed_room(), 0.2)
    assert (command.status, command.reason, command.finished) == (DONE, NO_FRONTIER, True)
    assert set(STATUSES) == {WAITING_FOR_SCAN, EXPLORING, NO_REACHABLE_FRONTIER, RETURNING, DONE}


def test_no_reachable_frontier_is_said_until_the_finish_timeout_elapses():
    explorer = _explorer(finish_after_s=2.0)
    for t, status in ((0.0, NO_REACHABLE_FRONTIER), (1.0, NO_REACHABLE_FRONTIER), (2.0, DONE)):
        command = _step(explorer, _closed_room(), t)
        assert (command.status, command.reason, command.finished) == (status, NO_FRONTIER, status == DONE), t


# Blacklisting and commitment


def test_a_goal_without_progress_is_blacklisted_after_the_timeout_and_another_is_chosen():
    # The robot does not move (a controller that cannot follow the path): the west goal is given up after 5 s.
    explorer = _explorer(goal_policy=GoalPolicy(no_progress_s=5.0))
    patient = _explorer()  # the default 30 s
    goals, patient_goals = [], []
    for t in range(8):
        goals.append(_step(explorer, _corridor(), t).goal_rc)
        patient_goals.append(_step(patient, _corridor(), t).goal_rc)
    assert goals[0][1] <= 12 and goals[4] == goals[0]
    assert all(goal[1] >= 68 for goal in goals[5:])
    assert patient_goals == [patient_goals[0]] * 8
    assert len(explorer.mission.tracker.blacklist) == 1
    x, y, stamp = explorer.mission.tracker.blacklist[0]
    assert stamp == 5.0 and (x, y) == FRAME.centre_xy(goals[0])


def test_every_frontier_blacklisted_is_said():
    explorer = _explorer(bounds=EAST_ONLY, goal_policy=GoalPolicy(no_progress_s=2.0))
    commands = [_step(explorer, _corridor(), t) for t in range(8)]  # blacklisted at t = 2, done 5 s later
    assert commands[0].goal_rc[1] >= 68 and commands[2].goal_rc is None
    assert (commands[2].status, commands[2].reason) == (NO_REACHABLE_FRONTIER, ALL_BLACKLISTED)
    assert (commands[6].status, commands[7].status, commands[7].reason) == (NO_REACHABLE_FRONTIER, DONE, ALL_BLACKLISTED)
    assert len(explorer.mission.tracker.blacklist) == 1


@pytest.mark.parametrize("blacklist_unreachable", [False, True])
def test_a_goal_cut_off_mid_episode_is_blacklisted_when_asked(blacklist_unreachable):
    # The robot at column 50: the east end (column 70) is nearer. A wall at column 60 cuts it off, then opens again.
    explorer = _explorer(goal_policy=GoalPolicy(blacklist_unreachable=blacklist_unreachable))
    pose = (40, 50)
    assert _step(explorer, _corridor(), 0, pose).goal_rc[1] >= 68
    assert _step(explorer, _corridor(closed_at=60), 1, pose).goal_rc[1] <= 12
    assert len(explorer.mission.tracker.blacklist) == int(blacklist_unreachable)
    explorer.drop_goal()
    goal = _step(explorer, _corridor(), 2, pose).goal_rc
    assert (goal[1] <= 12) == blacklist_unreachable


def test_a_blacklisted_goal_comes_back_after_it_expires():
    tracker = GoalTracker(GoalPolicy(blacklist_radius_m=0.5, blacklist_expire_s=10.0))
    tracker.add((1.0, 1.0), 5.0)
    points = [(1.0, 1.4), (1.0, 1.6)]
    assert tracker.forbidden(points, 14.9).tolist() == [True, False]
    assert tracker.forbidden(points, 15.0).tolist() == [False, False] and not tracker.blacklist


@pytest.mark.parametrize("margin, switches", [(None, False), (0.5, True), (3.0, False)])
def test_a_better_goal_replaces_the_kept_one_only_beyond_the_commit_margin(margin, switches):
    # The west end opens while the robot drives to the east one: twice as near, its score (1 / cost) twice as high.
    explorer = _explorer(goal_policy=GoalPolicy(commit_margin=margin))
    first = _step(explorer, _corridor(west_open=False), 0)
    assert first.goal_rc[1] >= 68
    command = _step(explorer, _corridor(), 1)
    assert (command.goal_rc[1] <= 12) == switches and command.new_goal == switches


@pytest.mark.parametrize("fields, message", [
    ({"no_progress_s": 0.0}, "no_progress_s must be"),
    ({"progress_m": -1.0}, "progress_m must be"),
    ({"blacklist_radius_m": float("inf")}, "blacklist_radius_m must be"),
    ({"blacklist_unreachable": 1}, "blacklist_unreachable must be true or false, got 1"),
    ({"commit_margin": -0.1}, "commit_margin must be"),
])
def test_a_bad_goal_policy_is_refused(fields, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        GoalPolicy(**fields)


# The command line, the Gymnasium environment, recordings


@pytest.mark.parametrize("text, message", [
    ("0,0 1,1", "bounds must have at least 3 points (x, y), got 2"),
    ("0,0 1,0 1;1", "--bounds point 2 must be 'x,y' (two numbers in metres, no space), got '1;1'"),
    ("0,0 1,0,2 1,1", "--bounds point 1 must be 'x,y'"),
    ("0,0 1,1 1,0 0,1", "bounds polygon crosses itself"),
    ("0,0 nan,0 1,1", "bounds point 1 must be a pair (x, y) of finite numbers"),
])
def test_bad_bounds_on_the_command_line_are_refused_before_anything_is_written(tmp_path, capsys, text, message):
    out = tmp_path / "out"
    refused(capsys, ["explore", "--map", MAP, "--bounds", text, "--out", str(out)], "--bounds", message)
    assert not out.exists()


def test_bounds_away_from_the_start_are_refused_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "out"
    refused(capsys, ["explore", "--pipeline", "nearest", "--map", MAP, "--bounds", "1000,1000 1001,1000 1001,1001",
                     "--out", str(out)], "must contain the robot's start pose")
    assert not (out / "metrics.json").exists()


def test_the_command_line_ends_with_a_status_line_and_records_the_status(tmp_path, capsys):
    from superex_deploy.recording import read_recording

    out, record = tmp_path / "out", tmp_path / "run.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "12", "--gif-every", "0",
                 "--return-to-start", "--bounds", "-1,-1 1000,-1 1000,1000 -1,1000", "--record", str(record),
                 "--out", str(out)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(r"status exploring: 12 steps, coverage \d+\.\d%, coverage inside the bounds \d+\.\d%", last)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == EXPLORING and "final_coverage_in_bounds" in metrics
    recording = read_recording(record)
    assert recording.metadata["explorer"]["return_to_start"] is True
    assert [step.status for step in recording.steps] == [EXPLORING] * 12
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["status"] == EXPLORING


def test_a_recording_written_before_commands_had_a_status_still_replays(tmp_path, monkeypatch):
    from superex_deploy.recording import read_recording, schemas

    name, text = schemas.SCHEMAS["/command"]
    old = "".join(line for line in text.splitlines(keepends=True)
                  if not line.startswith(("string status", "string reason")))
    assert old != text
    monkeypatch.setitem(schemas.SCHEMAS, "/command", (name, old))
    out, record = tmp_path / "out", tmp_path / "old.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "8", "--gif-every", "0", "--record",
                 str(record), "--out", str(out)]) == 0
    monkeypatch.undo()
    recording = read_recording(record)
    assert recording.error is None and [step.status for step in recording.steps] == [None] * 8
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0
    assert json.loads((tmp_path / "replay" / "metrics.json").read_text())["goals_match"]


def test_the_gymnasium_info_carries_the_status():
    pytest.importorskip("gymnasium")
    from superex_deploy.gym_env import ExplorationEnv

    env = ExplorationEnv(map=MAP, steps_per_action=2, max_steps=4)
    _, info = env.reset(seed=0)
    assert info["status"] == EXPLORING and info["reason"] == ""
    _, _, _, _, info = env.step(0)
    assert info["status"] in STATUSES and isinstance(info["reason"], str)
    env.close()


def test_parse_bounds_reads_metres():
    assert parse_bounds(" 0,0  2.5,0 2.5,-1.5 ").points == ((0.0, 0.0), (2.5, 0.0), (2.5, -1.5))
