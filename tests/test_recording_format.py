"""A recording carries its format version and every configuration its run used, as their ``to_json`` writes them:
a fresh recording replays bit for bit; a recording of the earlier format is refused with one error naming
``superex convert-recording``, and once converted replays the goals its run chose; the converter refuses what it
cannot convert. A benchmark folder records its planners' and sensing's configurations, and one written before it
did is refused."""

import json
from dataclasses import asdict

import numpy as np
import pytest

from superex_deploy.cli import main
from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.planning.planners import SuperexConfig, make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.pipeline import PROFILES, build_explorer
from superex_deploy.recording import FORMAT_VERSION, EpisodeRecorder, read_recording
from superex_deploy.recording.convert import PREVIOUS_DEFAULTS, convert_metadata, convert_recording
from superex_deploy.recording.metadata import explorer_arguments, planner_settings, recording_metadata
from superex_deploy.spad_types import SpadConfig
from tests.conftest import OLD_SUPEREX, nearest_metadata

MAP = "50052750"


def _replayed_goals(metadata, recording) -> list:
    goals = []
    with build_explorer(**explorer_arguments(metadata, recording.frame)) as explorer:
        for recorded in recording.steps:
            command = explorer.step(recorded.observation)
            if command.new_goal:
                goals.append(list(command.goal_rc))
    return goals


def _replay(tmp_path, path, name="replay") -> dict:
    assert main(["replay", str(path), "--out", str(tmp_path / name)]) == 0
    return json.loads((tmp_path / name / "metrics.json").read_text())


# This format.

def test_a_fresh_recording_replays_bit_for_bit(tmp_path):
    from superex_deploy.evaluation.episodes import make_world_and_explorer

    grid = load_map(MAP)
    cfg = PROFILES["full"].episode_config(iou_every=0)
    planner = make_planner("superex", gain="goal", sense_every_m=1.2, drop_resolved_m=2.0)
    world, explorer = make_world_and_explorer(grid, start_poses(MAP)[2], planner, ObservedAsPrediction(), 0, cfg)
    metadata = recording_metadata(map_name=MAP, planner_name="superex", planner=planner,
                                  planner_options={"gain": "goal"}, predictor="observed", seed=0, sensor=None,
                                  nlos_cfg=None, explorer_cfg=cfg.explorer, profile="full")
    path, commands = tmp_path / "run.mcap", []
    with EpisodeRecorder(path, world.frame, metadata) as recorder, explorer:
        for _ in range(15):
            observation = world.observe()
            commands.append(explorer.step(observation))
            recorder.write(observation, commands[-1], explorer.observed)
            world.apply(commands[-1])
        final = explorer.observed.copy()
    recording = read_recording(path)
    assert recording.metadata["format_version"] == FORMAT_VERSION == "2"
    assert recording.metadata["planner_config"] == planner.cfg.to_json()
    assert recording.metadata["explorer"] == cfg.explorer.to_json()
    with build_explorer(**explorer_arguments(recording.metadata, recording.frame)) as again:
        assert again.planner.cfg == planner.cfg and again.cfg == cfg.explorer
        replayed = [again.step(recorded.observation) for recorded in recording.steps]
        np.testing.assert_array_equal(again.observed, final)
    assert len(replayed) == len(commands) == 15 and any(c.new_goal for c in commands)
    for made, again in zip(commands, replayed):
        assert (again.goal_rc, again.new_goal, again.finished, again.status, again.reason) == (
            made.goal_rc, made.new_goal, made.finished, made.status, made.reason)
        np.testing.assert_array_equal(again.path_rc, made.path_rc)
        np.testing.assert_array_equal(again.path_xy, made.path_xy)


def test_explore_records_every_configuration_and_it_replays(tmp_path):
    from superex_deploy.onboard.nlos import NlosConfig

    record = tmp_path / "new.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--start", "2", "--planner", "superex",
                 "--planner-option", "sense_every_m=1.5", "--spad", "--steps", "6", "--gif-every", "0",
                 "--out", str(tmp_path / "run"), "--record", str(record)]) == 0
    metadata = read_recording(record).metadata
    assert metadata["planner_options"] == {"sense_every_m": 1.5}
    assert metadata["planner_config"] == SuperexConfig(sense_every_m=1.5).to_json()
    assert metadata["planner_config"]["gain"] == "expected" and metadata["spad"] is True
    assert SpadConfig.from_json(metadata["sensor"]) == SpadConfig() and metadata["nlos"] == NlosConfig().to_json()
    replay = _replay(tmp_path, record)
    assert replay["goals_match"] and replay["steps"] == 6


def test_a_recording_naming_a_field_this_version_lacks_is_refused_by_name(write_recording, tmp_path, capsys):
    metadata = nearest_metadata()
    metadata["explorer"]["motion"]["step_cells"] = 3
    path = write_recording(tmp_path / "r.mcap", metadata=metadata)
    assert main(["replay", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "the recording's configuration cannot be rebuilt: MotionConfig has no " \
                                        "field 'step_cells'" in err
    without = {key: value for key, value in nearest_metadata().items() if key not in ("planner_config", "nlos")}
    with pytest.raises(ValueError, match="the recording's metadata lacks 'planner_config', 'nlos'"):
        explorer_arguments(without, read_recording(path).frame)


# The earlier format.

def test_an_old_recording_is_refused_naming_the_converter(tmp_path, old_recording, capsys):
    path, _ = old_recording(tmp_path / "old.mcap", 2)
    expected = (f"{path} has recording format '1', this package reads '2': an older version of superex_deploy wrote "
                f"it; convert it with `superex convert-recording {path} NEW.mcap` and replay NEW.mcap")
    with pytest.raises(ValueError) as raised:
        read_recording(path)
    assert str(raised.value) == expected
    assert main(["replay", str(path), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == f"superex replay: error: {expected}"
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_a_converted_old_recording_replays_the_goals_of_its_run(tmp_path, old_recording, capsys):
    path, goals = old_recording(tmp_path / "old.mcap", 2)  # from start 2 the new defaults choose another first goal
    new = tmp_path / "new.mcap"
    assert main(["convert-recording", str(path), str(new)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {new}: {path} in recording format '2'" in out
    recording = read_recording(new)
    assert recording.metadata["format_version"] == "2" and len(recording.steps) == 15
    # The options given were none: the planner ran the defaults of then, which the converter fills in.
    assert PREVIOUS_DEFAULTS == {"superex": OLD_SUPEREX}
    assert recording.metadata["planner_config"] == SuperexConfig(gain=OLD_SUPEREX["gain"]).to_json()
    replay = _replay(tmp_path, new)
    assert replay["goals_match"] and replay["goals"]["cells"] == goals and goals
    # The recording tells the defaults apart: rebuilt with the new ones, the planner would choose other goals.
    now = {**recording.metadata, "planner_config": planner_settings(make_planner("superex"))}
    assert _replayed_goals(recording.metadata, recording) == goals != _replayed_goals(now, recording)


def test_the_converter_refuses_what_it_cannot_convert(tmp_path, write_recording, old_recording, capsys):
    current = write_recording(tmp_path / "current.mcap")
    with pytest.raises(ValueError) as raised:
        convert_recording(current, tmp_path / "x.mcap")
    assert str(raised.value) == f"{current} is already of recording format '2': nothing to convert (replay it as " \
                                f"it is)"
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording")
    assert main(["convert-recording", str(text), str(tmp_path / "y.mcap")]) == 2
    assert capsys.readouterr().err.strip() == (f"superex convert-recording: error: {text} is not a SuperEx "
                                               f"recording: no readable 'superex.episode' metadata record")
    newer = write_recording(tmp_path / "newer.mcap", metadata={"format_version": "3"})
    with pytest.raises(ValueError, match=r"has recording format '3': this version converts '1' to '2'"):
        convert_recording(newer, tmp_path / "z.mcap")
    path, _ = old_recording(tmp_path / "old.mcap", 1)
    with pytest.raises(ValueError, match="must go to another file than"):
        convert_recording(path, path)
    with pytest.raises(ValueError, match="the folder .* does not exist"):
        convert_recording(path, tmp_path / "nowhere" / "new.mcap")
    assert not any(p.name.startswith(("x.", "y.", "z.")) for p in tmp_path.iterdir())


def test_an_old_recording_of_a_cut_run_converts_its_whole_steps(tmp_path, old_recording, capsys):
    path, _ = old_recording(tmp_path / "old.mcap", 1)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:len(path.read_bytes()) * 2 // 3])
    new = tmp_path / "new.mcap"
    assert main(["convert-recording", str(cut), str(new)]) == 0
    assert "warning:" in capsys.readouterr().out
    recording = read_recording(new)
    assert 0 < len(recording.steps) < 15 and recording.error is None


def test_the_converter_rewrites_every_old_form():
    frame = {"shape": [40, 40], "resolution_m": 0.05, "origin_xy": [0.0, 0.0]}
    explorer = asdict(PROFILES["full"].explorer_config())
    explorer["frontier_min_cells"] = explorer.pop("frontier_min_m") / 0.05
    explorer["motion"]["step_cells"] = 6
    del explorer["motion"]["step_m"]
    explorer["prediction"] = {"asynchronous": True, "every_steps": 2, "apply_after_steps": 2, "wait_first": False}
    for name in ("finish_frontier_m", "goal_policy"):
        del explorer[name]
    settings = {key: value for key, value in PROFILES["full"].to_json().items() if key != "simulated_schedule"}
    settings["reuse"] = {**settings["reuse"], "min_changed_cells": 0}
    del settings["reuse"]["min_changed_m2"]
    old = {"format_version": "1", "frame": frame, "planner": "upen", "planner_options": {"expand_cells": 10},
           "predictor": "observed", "seed": 3, "spad": True, "models": None,
           "sensor": asdict(SpadConfig()),
           "nlos": {"window_m": 6.0, "wall_strip_cells": 3, "retired_option": 1}, "explorer": explorer,
           "profile_settings": settings}
    new = convert_metadata(old)
    assert new["format_version"] == "2" and new["profile"] == "full" and new["seed"] == 3
    assert new["planner_config"]["expand_m"] == 0.5 and "expand_cells" not in new["planner_config"]
    assert new["explorer"]["frontier_min_m"] == 1.0 and new["explorer"]["motion"]["step_m"] == 0.3
    assert new["explorer"]["prediction"]["mode"] == "simulated" and new["explorer"]["finish_frontier_m"] == 0.0
    assert new["explorer"]["goal_policy"]["drop_resolved_m"] is None
    assert new["nlos"]["window_m"] == 6.0 and new["nlos"]["wall_strip_m"] == pytest.approx(0.15)
    assert "retired_option" not in new["nlos"]
    assert new["profile_settings"] == PROFILES["full"].to_json()
    with build_explorer(**explorer_arguments(new, MapFrame((40, 40), 0.05))) as rebuilt:
        assert rebuilt.cfg.frontier_min_cells(0.05) == 20 and rebuilt.cfg.motion.cells_per_step(0.05) == 6
        assert rebuilt.spad_processing.nlos_cfg.in_cells(0.05).wall_strip == 3.0
    with pytest.raises(ValueError, match="both 'step_cells' and its new name 'step_m'"):
        convert_metadata({**old, "explorer": {**explorer, "motion": {"step_cells": 3, "step_m": 0.3}}})


@pytest.mark.parametrize("scan_matching, options, named", [
    ({"match_sigma_cells": 0.3}, {}, "scan_matching: the option 'match_sigma_cells' was retired"),
    ({}, {"choice": "rollout"}, "superex: the option 'choice' was retired"),
])
def test_an_old_recording_with_a_retired_option_in_use_is_refused_by_name(tmp_path, capsys, old_recording,
                                                                         scan_matching, options, named):
    path, _ = old_recording(tmp_path / "old.mcap", 1, options, scan_matching)
    assert main(["convert-recording", str(path), str(tmp_path / "new.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and named in err and "cannot be converted" in err
    assert "this version cannot reproduce a run that used it" in err
    assert not (tmp_path / "new.mcap").exists()


def test_an_old_recording_made_before_the_retirement_replays_once_converted(tmp_path, old_recording):
    from superex_deploy.recording.convert import RETIRED

    old_defaults = dict(RETIRED["scan_matching"][1])
    path, goals = old_recording(tmp_path / "old.mcap", 1, {"choice": "greedy", "candidates": 5, "n_rays": 250},
                                old_defaults)
    new = tmp_path / "new.mcap"
    convert_recording(path, new)
    replay = _replay(tmp_path, new)
    assert replay["goals_match"] and replay["goals"]["cells"] == goals and goals


# Benchmark folders.

def _old_folder(tmp_path, planners, options, spad=False):
    """A benchmark folder as a version before 0.2 wrote it: settings without the planners' and the sensing's
    configurations, one finished episode."""
    out = tmp_path / "bench"
    out.mkdir()
    settings = {"maps": [MAP], "planners": planners, "planner_options": options, "predictor": "observed",
                "spad": spad, "steps": 5, "seed": 0, "profile": "full", "profile_settings": PROFILES["full"].to_json()}
    (out / "settings.json").write_text(json.dumps(settings))
    (out / "episodes.jsonl").write_text(json.dumps({"key": f"{MAP}/0/{planners[0]}", "result": {}}) + "\n")
    return out


def test_a_benchmark_folder_of_a_version_before_0_2_is_not_resumed(tmp_path, capsys):
    out = _old_folder(tmp_path, ["nearest"], {})
    assert main(["benchmark", "--maps", MAP, "--planners", "nearest", "--profile", "full", "--steps", "5",
                 "--jobs", "1", "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    assert "planner_configs" in lines[0] and "written by a version before 0.2" in lines[0]
    assert json.loads((out / "settings.json").read_text())["planner_options"] == {}  # left as it was
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 1


def test_a_benchmark_records_its_planners_and_sensing_configurations(tmp_path):
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--planner-option",
                 "wall_threshold=0.4", "--profile", "full", "--steps", "3", "--jobs", "1", "--out",
                 str(tmp_path / "b")]) == 0
    settings = json.loads((tmp_path / "b" / "settings.json").read_text())
    assert settings["planner_configs"] == {"superex": SuperexConfig(wall_threshold=0.4).to_json()}
    assert settings["sensing"] is None
    # The same configuration given otherwise resumes; another is refused.
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--planner-option",
                 "wall_threshold=0.4", "--planner-option", "gain=expected", "--profile", "full", "--steps", "3",
                 "--jobs", "1", "--out", str(tmp_path / "b"), "--resume"]) == 0
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--profile", "full",
                 "--steps", "3", "--jobs", "1", "--out", str(tmp_path / "b"), "--resume"]) == 2


def test_a_paper_row_of_a_version_before_0_2_is_refused(tmp_path, capsys):
    from superex_deploy.commands import paper_benchmark

    rows = tmp_path / "p" / "rows"
    rows.mkdir(parents=True)
    setting = {"maps": [MAP], "steps": 5, "seed": 0, "iou": paper_benchmark.IOU_SCHEDULE}
    (rows / "mapex_observed.json").write_text(json.dumps({"row": "mapex_observed", "setting": setting,
                                                          "episodes": []}))
    row = paper_benchmark._row_setting(setting, "mapex_observed")
    assert row["planner_config"] == planner_settings(make_planner("mapex")) and row["sensing"] is None
    assert main(["benchmark", "--suite", "paper", "--rows", "mapex_observed", "--maps", MAP, "--steps", "5",
                 "--jobs", "1", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "planner_config" in err and err.count("error:") == 1
