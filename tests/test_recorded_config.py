"""What a run records of its configuration outlives a change of the defaults: a recording holds its planner's whole
configuration and replays with it; one made before it did (the options given only) replays with the defaults of its
version; a benchmark folder of the defaults before refuses to be resumed with the new ones, naming what changed."""

import json
from dataclasses import asdict

import pytest

from superex_deploy.cli import main
from superex_deploy.onboard.planning.planners import SuperexConfig, make_planner
from superex_deploy.onboard.nlos import NlosConfig
from superex_deploy.pipeline import PROFILES
from superex_deploy.commands.recorded_config import (PREVIOUS_DEFAULTS, planner_settings,
                                                     previous_planner_options)
from superex_deploy.spad_types import SpadConfig

MAP = "50052750"
OLD_SUPEREX = {"gain": "path"}  # SuperexConfig's default before 0.2 (its transmittance, read by the expected gains
# only, was retired)


def test_the_previous_defaults_are_those_that_changed():
    assert PREVIOUS_DEFAULTS["planners"] == {"superex": OLD_SUPEREX}
    assert SuperexConfig().gain == "expected"
    assert SpadConfig().n_secondary == 256 and PREVIOUS_DEFAULTS["sensor"] == {"n_secondary": 64}
    assert NlosConfig().sector_margin_deg == 20.0 and PREVIOUS_DEFAULTS["nlos"] == {"sector_margin_deg": 35.0}
    assert previous_planner_options("superex", {}) == OLD_SUPEREX
    assert previous_planner_options("superex", {"gain": "goal"}) == {"gain": "goal"}
    assert previous_planner_options("mapex", {"gain": "expected"}) == {"gain": "expected"}


# Recordings.

def _replayed_goals(metadata, recording) -> list:
    from superex_deploy.commands.replay import explorer_arguments
    from superex_deploy.pipeline import build_explorer

    goals = []
    with build_explorer(**explorer_arguments(metadata, recording.frame)) as explorer:
        for recorded in recording.steps:
            command = explorer.step(recorded.observation)
            if command.new_goal:
                goals.append(list(command.goal_rc))
    return goals


def test_a_recording_made_with_the_defaults_before_replays_with_them(tmp_path, old_recording):
    from superex_deploy.commands.replay import explorer_arguments
    from superex_deploy.pipeline import build_explorer
    from superex_deploy.recording import read_recording

    path, goals = old_recording(tmp_path / "old.mcap", 2)  # from start 2 the new defaults choose another first goal
    recording = read_recording(path)
    assert "planner_config" not in recording.metadata and recording.metadata["planner_options"] == {}
    with build_explorer(**explorer_arguments(recording.metadata, recording.frame)) as explorer:
        assert explorer.planner.cfg == SuperexConfig(**OLD_SUPEREX)
    assert main(["replay", str(path), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["goals"]["cells"] == goals and goals
    # The recording tells the defaults apart: rebuilt with the new ones, the planner would choose other goals.
    now = {**recording.metadata, "planner_config": planner_settings(make_planner("superex"))}
    assert _replayed_goals(recording.metadata, recording) == goals != _replayed_goals(now, recording)


def test_the_planner_configuration_round_trips_through_a_recording(write_recording, tmp_path):
    from superex_deploy.commands.replay import explorer_arguments
    from superex_deploy.pipeline import build_explorer
    from superex_deploy.recording import read_recording

    planner = make_planner("superex", gain="goal", sense_every_m=1.2, drop_resolved_m=2.0)
    explorer_cfg = asdict(PROFILES["full"].episode_config(iou_every=0).explorer)
    metadata = {"planner": "superex", "planner_options": {}, "planner_config": planner_settings(planner),
                "predictor": "observed", "seed": 0, "explorer": explorer_cfg}
    recording = read_recording(write_recording(tmp_path / "r.mcap", metadata=metadata))
    assert recording.metadata["planner_config"] == json.loads(json.dumps(asdict(planner.cfg)))
    # The recorded configuration wins over the options given (none here) and over this version's defaults.
    with build_explorer(**explorer_arguments(recording.metadata, recording.frame)) as explorer:
        assert explorer.planner.cfg == planner.cfg and explorer.planner.cfg.sense_every_m == 1.2
    hector = make_planner("hector", visibility=None, info_gain_weight=50.0)
    metadata = {**metadata, "planner": "hector", "planner_config": planner_settings(hector)}
    recording = read_recording(write_recording(tmp_path / "h.mcap", metadata=metadata))
    with build_explorer(**explorer_arguments(recording.metadata, recording.frame)) as explorer:
        assert explorer.planner.cfg == hector.cfg


def test_explore_records_the_planners_whole_configuration_and_it_replays(tmp_path):
    from superex_deploy.recording import read_recording

    record = tmp_path / "new.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--start", "2", "--planner", "superex",
                 "--planner-option", "drop_resolved_m=0.5", "--steps", "8", "--gif-every", "0",
                 "--out", str(tmp_path / "run"), "--record", str(record)]) == 0
    metadata = read_recording(record).metadata
    assert metadata["planner_options"] == {"drop_resolved_m": 0.5}
    assert metadata["planner_config"] == json.loads(json.dumps(asdict(SuperexConfig(drop_resolved_m=0.5))))
    assert metadata["planner_config"]["gain"] == "expected" and metadata["sensor"] is None
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0
    assert json.loads((tmp_path / "replay" / "metrics.json").read_text())["goals_match"]


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


def _resume(out, planners, *more):
    return ["benchmark", "--maps", MAP, "--planners", ",".join(planners), "--profile", "full", "--steps", "5",
            "--jobs", "1", "--out", str(out), "--resume", *more]


def test_a_benchmark_of_the_superex_defaults_before_is_not_resumed_with_the_new_ones(tmp_path, capsys):
    out = _old_folder(tmp_path, ["superex"], {})
    assert main(_resume(out, ["superex"])) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    assert "planner_configs.superex.gain: recorded 'path', now 'expected'" in lines[0]
    assert "the defaults of the versions before 0.2" in lines[0]
    assert json.loads((out / "settings.json").read_text())["planner_options"] == {}  # left as it was
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 1


def test_a_benchmark_resumes_where_the_configurations_are_those_it_ran(tmp_path):
    from superex_deploy.commands.benchmark import prepare_output

    # The old defaults given as options: the configuration the folder's episodes ran.
    out = _old_folder(tmp_path, ["superex"], {})
    new = {"maps": [MAP], "planners": ["superex"], "planner_options": OLD_SUPEREX,
           "planner_configs": {"superex": planner_settings(make_planner("superex", **OLD_SUPEREX))},
           "predictor": "observed", "spad": False, "sensing": None, "steps": 5, "seed": 0, "profile": "full",
           "profile_settings": PROFILES["full"].to_json()}
    assert prepare_output(out, new, resume=True) == out / "episodes.jsonl"
    assert json.loads((out / "settings.json").read_text()) == json.loads(json.dumps(new))
    # Planners whose defaults did not change resume as they are.
    (tmp_path / "bench").rename(tmp_path / "first")
    out = _old_folder(tmp_path, ["nearest", "mapex"], {})
    same = {**new, "planners": ["nearest", "mapex"], "planner_options": {},
            "planner_configs": {"nearest": {}, "mapex": planner_settings(make_planner("mapex"))}}
    assert prepare_output(out, same, resume=True) == out / "episodes.jsonl"
    # But not with the SPAD sensing of before.
    (tmp_path / "bench").rename(tmp_path / "second")
    out = _old_folder(tmp_path, ["nearest"], {}, spad=True)
    from superex_deploy.commands.recorded_config import default_sensing_settings

    spad = {**same, "planners": ["nearest"], "planner_configs": {"nearest": {}}, "spad": True,
            "sensing": default_sensing_settings()}
    with pytest.raises(ValueError) as error:
        prepare_output(out, spad, resume=True)
    message = str(error.value)
    assert "sensing.sensor.n_secondary: recorded 64, now 256" in message
    assert "sensing.nlos.sector_margin_deg: recorded 35.0, now 20.0" in message
    assert "planner_configs" not in message


def test_a_benchmark_records_its_planners_and_sensing_configurations(tmp_path):
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--planner-option",
                 "wall_threshold=0.4", "--profile", "full", "--steps", "3", "--jobs", "1", "--out",
                 str(tmp_path / "b")]) == 0
    settings = json.loads((tmp_path / "b" / "settings.json").read_text())
    assert settings["planner_configs"] == {"superex": json.loads(json.dumps(asdict(SuperexConfig(
        wall_threshold=0.4))))}
    assert settings["sensing"] is None
    # The same configuration given otherwise resumes; another is refused.
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--planner-option",
                 "wall_threshold=0.4", "--planner-option", "gain=expected", "--profile", "full", "--steps", "3",
                 "--jobs", "1", "--out", str(tmp_path / "b"), "--resume"]) == 0
    assert main(["benchmark", "--maps", "50045230", "--planners", "superex", "--profile", "full",
                 "--steps", "3", "--jobs", "1", "--out", str(tmp_path / "b"), "--resume"]) == 2


def test_a_paper_row_finished_with_the_defaults_before_is_refused(tmp_path, capsys):
    from superex_deploy.commands import paper_benchmark

    rows = tmp_path / "p" / "rows"
    rows.mkdir(parents=True)
    setting = {"maps": [MAP], "steps": 5, "seed": 0, "iou": paper_benchmark.IOU_SCHEDULE}
    for name in ("superex_observed", "mapex_observed"):
        (rows / f"{name}.json").write_text(json.dumps({"row": name, "setting": setting, "episodes": []}))
    # A row whose configuration did not change counts as done; one whose did is refused, naming what changed.
    assert paper_benchmark._row_setting_as_now(setting, "mapex_observed") == \
        paper_benchmark._row_setting(setting, "mapex_observed")
    old = paper_benchmark._row_setting_as_now(setting, "superex_observed")
    assert old != paper_benchmark._row_setting(setting, "superex_observed")
    assert old["planner_config"]["gain"] == "path" and old["sensing"] is None
    assert main(["benchmark", "--suite", "paper", "--rows", "superex_observed", "--maps", MAP, "--steps", "5",
                 "--jobs", "1", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "planner_config.gain: recorded 'path', now 'expected'" in err and err.count("error:") == 1
