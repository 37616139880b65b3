"""The real-time profiles: the default the CLI runs, its checks, and the reproducibility of its deterministic
asynchronous mode end to end."""

import json

import pytest

from superex_deploy.cli import main
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.pipeline import (DEFAULT_PROFILE, PROFILES, RealtimeProfile, check_profile, make_predictor,
                                     resolve_profile)


def test_the_default_profile_is_the_measured_realtime_one():
    assert DEFAULT_PROFILE == "realtime" and PROFILES["full"] == type(PROFILES["full"])()
    realtime = PROFILES["realtime"]
    # On the robot it never waits; in simulated benchmarks it runs the simulated clock (reproducible anywhere).
    assert realtime.schedule.mode == "free" and realtime.explorer_config().prediction is realtime.schedule
    simulated = realtime.episode_config().explorer.prediction
    assert simulated.mode == "simulated" and (simulated.every_steps, simulated.apply_after_steps) == (2, 2)
    assert PROFILES["full"].episode_config().explorer.prediction.mode == "inline"
    assert realtime.max_members == 1 and realtime.reuse.crop_margin_m == 6.4
    ensemble = make_predictor("lama_bp", profile=realtime)
    assert ensemble.max_members == 1 and make_predictor("lama_bp", profile=PROFILES["full"]).max_members is None


def test_a_profile_gives_the_explorer_and_episode_configurations():
    realtime = PROFILES["realtime"]
    explorer = realtime.explorer_config()
    assert explorer.prediction is realtime.schedule and explorer.reuse is realtime.reuse
    assert explorer.motion == type(explorer)().motion
    episode = realtime.episode_config(iou_every=10, iou_dense_until=0.35)
    assert episode.explorer == realtime.explorer_config("simulated").for_simulation()
    assert episode.explorer.reuse is realtime.reuse
    assert (episode.iou_every, episode.iou_dense_until) == (10, 0.35)
    assert realtime.episode_config(clock="robot").explorer == explorer.for_simulation()
    with pytest.raises(ValueError, match="clock must be 'robot' or 'simulated', got 'wall'"):
        realtime.explorer_config("wall")


def test_a_one_member_profile_refuses_planners_that_read_the_variance():
    assert check_profile("realtime", make_planner("superex"), "lama_bp") is PROFILES["realtime"]
    assert check_profile("realtime", make_planner("mapex"), "observed") is PROFILES["realtime"]
    assert check_profile("full", make_planner("mapex"), "lama_los") is PROFILES["full"]
    for planner in ("mapex", "upen"):
        with pytest.raises(ValueError, match=f"the realtime profile runs one LaMa member, so the variance the "
                                             f"{planner} planner reads would be zero everywhere: use --profile full"):
            check_profile("realtime", make_planner(planner), "lama_los")
    with pytest.raises(ValueError, match="unknown profile 'fast'; choose one of full, realtime"):
        check_profile("fast", make_planner("nearest"), "observed")
    with pytest.raises(ValueError, match="max_members must be an integer >= 1 or None, got 0"):
        RealtimeProfile(max_members=0)
    with pytest.raises(ValueError, match="schedule must be a PredictionSchedule, got dict"):
        RealtimeProfile(schedule={})


def test_explore_refuses_a_profile_the_planner_cannot_use_and_defaults_around_it(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["explore", "--pipeline", "nearest", "--map", "50052750", "--planner", "mapex", "--predictor", "lama_los",
            "--steps", "3", "--gif-every", "10"]
    assert main(argv + ["--profile", "realtime", "--out", str(out)]) == 2
    assert "use --profile full" in capsys.readouterr().err
    assert not out.exists()
    assert main(argv + ["--out", str(out)]) == 0
    assert json.loads((out / "metrics.json").read_text())["profile"] == "full"
    assert resolve_profile(None, make_planner("superex"), "lama_bp") == DEFAULT_PROFILE
    assert resolve_profile(None, make_planner("upen"), "lama_los") == "full"
    assert resolve_profile(None, make_planner("upen"), "observed") == DEFAULT_PROFILE
    assert resolve_profile("full", make_planner("superex"), "lama_bp") == "full"


@pytest.mark.slow
def test_the_realtime_pipeline_replays_and_its_benchmark_episodes_are_reproducible(tmp_path):
    """``superex explore`` runs the default on the robot's clock (a step never waits for the predictor, so where
    predictions land depends on the machine): its recording keeps where they landed and a replay follows it to the
    same goals. Simulated benchmark episodes of the default run the simulated clock: two give the same goals."""
    from superex_deploy.maps import load_map, start_poses
    from superex_deploy.pipeline import make_sensing
    from superex_deploy.recording import read_recording
    from superex_deploy.evaluation.episodes import run_episode

    argv = ["explore", "--map", "50052750", "--start", "1", "--planner", "superex", "--predictor", "lama_bp", "--spad",
            "--steps", "40", "--gif-every", "100"]
    assert main(argv + ["--out", str(tmp_path / "a"), "--record", str(tmp_path / "a.mcap")]) == 0
    first = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert first["profile"] == "realtime" and first["config"]["explorer"]["prediction"]["mode"] == "free"
    steps = read_recording(tmp_path / "a.mcap").steps
    assert steps[0].prediction_step == 0 and all(s.prediction_step >= 0 for s in steps)  # wait_first
    assert all(s.prediction_age_s == pytest.approx(0.1 * (s.step - s.prediction_step)) for s in steps)
    assert main(["replay", str(tmp_path / "a.mcap"), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["goals"] == first["goals"] and len(first["goals"]["cells"]) >= 2

    profile = PROFILES["realtime"]
    grid = load_map("50052750")

    def episode():
        return run_episode(grid, start_poses("50052750")[1], make_planner("superex"),
                           make_predictor("lama_bp", grid, profile=profile), steps=30, seed=0,
                           cfg=profile.episode_config(iou_every=0), sensing=make_sensing("lama_bp", True, 0,
                                                                                        profile=profile))

    one, two = episode(), episode()
    assert one.goals == two.goals and one.coverage_with_carving.tolist() == two.coverage_with_carving.tolist()


def test_a_replay_refuses_a_profile_defined_differently_since(tmp_path, monkeypatch, capsys):
    from dataclasses import replace

    record = tmp_path / "a.mcap"
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--planner", "nearest", "--steps", "5",
                 "--gif-every", "10", "--out", str(tmp_path / "run"), "--record", str(record)]) == 0
    monkeypatch.setitem(PROFILES, "realtime", replace(PROFILES["realtime"], max_members=2))
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 2
    assert "the recording's profile 'realtime' was defined differently" in capsys.readouterr().err
    assert not (tmp_path / "replay" / "metrics.json").exists()


@pytest.mark.slow
def test_a_benchmark_runs_every_planner_on_one_profile(tmp_path):
    """MapEx cannot use the one-member default with a LaMa predictor, so the whole run falls back to full: the
    planners are compared on the same pipeline."""
    out = tmp_path / "bench"
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest,mapex", "--predictor", "lama_los",
                 "--steps", "6", "--jobs", "2", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert {e["profile"] for e in results["episodes"]} == {"full"}
    assert json.loads((out / "settings.json").read_text())["profile"] == "full"
