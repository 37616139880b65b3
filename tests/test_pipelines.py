"""The named pipelines (``pipeline.PIPELINES``): every one builds its explorer and runs, the table agrees with the
profiles' rule and the paper's rows, ``superex explore`` without pipeline options runs ``superex``, the command
line's parts override the pipeline's, and every default profile is the one default profile."""

import inspect
import json
from dataclasses import replace

import pytest

from superex_deploy.cli import build_parser, main
from superex_deploy.commands.explore import chosen_pipeline
from superex_deploy.evaluation import run_benchmark_episode
from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.pipeline import (DEFAULT_PIPELINE, DEFAULT_PROFILE, EVIDENCE_PREDICTORS, PIPELINES, PROFILES,
                                     Pipeline, build_explorer, check_profile, make_predictor, make_sensing,
                                     resolve_profile)
from superex_deploy.recording import read_recording
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.exploration import ExplorationConfig

MAP = "50052750"


@pytest.mark.parametrize("name", list(PIPELINES))
def test_each_named_pipeline_builds_its_explorer_and_runs(name, corridor_rooms):
    """As a benchmark task builds it (``evaluation.tasks.run_scenario``): its profile's sensing, configuration and
    predictor, through ``build_explorer``, a few steps on a small floor."""
    pipeline = PIPELINES[name]
    grid = corridor_rooms()
    profile = PROFILES[pipeline.profile]
    sensing = make_sensing(pipeline.predictor, pipeline.spad, 0, profile=profile)
    if not pipeline.carving:
        sensing = replace(sensing, skips=replace(sensing.skips, carving=True))
    cfg = profile.episode_config(iou_every=0)
    explorer = build_explorer(MapFrame(grid.shape, grid.resolution_m), pipeline.planner, pipeline.predictor,
                              profile=pipeline.profile, spad=False if sensing is None else sensing.processing(),
                              cfg=cfg.explorer, grid=grid)
    assert explorer.planner.name == pipeline.planner
    assert (explorer.spad_processing is not None) == pipeline.spad
    if pipeline.predictor in ("lama_los", "lama_bp"):
        assert explorer.predictor.max_members == profile.max_members
    if pipeline.spad:
        assert (explorer.spad_processing.bp_filter is not None) == (pipeline.predictor in EVIDENCE_PREDICTORS)
    result = run_episode(grid, (40, 6), explorer=explorer, steps=4, seed=0, cfg=cfg, sensing=sensing)
    assert result.steps == 4 and result.planner == pipeline.planner
    if pipeline.spad and pipeline.carving:
        assert result.final_carved.any()
    elif pipeline.spad:
        assert not result.final_carved.any()  # the ablation without carving


def test_the_table_is_the_profiles_rule_and_the_papers_rows():
    from superex_deploy.commands.paper_benchmark import _rows
    from superex_deploy.evaluation.summary import REFERENCE_ROW

    assert DEFAULT_PIPELINE == "superex" and PIPELINES[DEFAULT_PIPELINE].profile == DEFAULT_PROFILE
    superex = PIPELINES["superex"]
    assert (superex.planner, superex.predictor, superex.spad, superex.carving) == ("superex", "lama_bp", True, True)
    assert (PIPELINES["nearest"].planner, PIPELINES["nearest"].predictor, PIPELINES["nearest"].spad) == \
        ("nearest", "observed", False)
    for name, pipeline in PIPELINES.items():
        assert pipeline.name == name
        planner = make_planner(pipeline.planner)
        # Each pipeline names the profile the rule gives its planner and predictor, and the profile fits them.
        assert pipeline.profile == resolve_profile(None, planner, pipeline.predictor), name
        assert check_profile(pipeline.profile, planner, pipeline.predictor) is PROFILES[pipeline.profile]
    assert {n for n, p in PIPELINES.items() if p.profile != DEFAULT_PROFILE} == {"upen_lama_los", "mapex_lama_los"}
    # The paper's table runs every named pipeline, in the table's order, paired against MapEx on LaMa-LOS.
    assert _rows(["all"]) == list(PIPELINES) and REFERENCE_ROW in PIPELINES
    with pytest.raises(ValueError, match="reads the SPAD evidence"):
        Pipeline("x", "superex", "lama_bp", False, DEFAULT_PROFILE, "x")
    with pytest.raises(ValueError, match="unknown profile"):
        Pipeline("x", "superex", "observed", False, "fast", "x")
    with pytest.raises(ValueError, match="carving=False"):
        Pipeline("x", "superex", "observed", False, DEFAULT_PROFILE, "x", carving=False)


def test_explore_without_pipeline_options_runs_the_superex_pipeline(tmp_path):
    """What the run records (its metrics and its recording), not how it was built."""
    out, record = tmp_path / "run", tmp_path / "run.mcap"
    assert main(["explore", "--map", MAP, "--steps", "3", "--gif-every", "0", "--out", str(out),
                 "--record", str(record)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    superex = PIPELINES[DEFAULT_PIPELINE]
    assert (metrics["pipeline"], metrics["planner"], metrics["predictor"], metrics["spad"], metrics["profile"]) == \
        ("superex", superex.planner, superex.predictor, True, superex.profile)
    recording = read_recording(record)
    meta = recording.metadata
    assert (meta["planner"], meta["predictor"], meta["spad"], meta["profile"]) == \
        ("superex", "lama_bp", True, DEFAULT_PROFILE)
    assert meta["sensor"] is not None and meta["profile_settings"] == PROFILES[DEFAULT_PROFILE].to_json()
    assert all(step.observation.spad is not None for step in recording.steps)  # a SPAD frame every step


def test_the_command_lines_parts_override_the_pipelines():
    def chosen(*argv):
        args = build_parser().parse_args(["explore", "--map", MAP, "--out", "x", *argv])
        pipeline, planner = chosen_pipeline(args, {})
        assert planner.name == args.planner
        return pipeline.name, args.planner, args.predictor, args.spad, args.profile

    assert chosen() == ("superex", "superex", "lama_bp", True, "realtime")
    assert chosen("--pipeline", "nearest") == ("nearest", "nearest", "observed", False, "realtime")
    assert chosen("--pipeline", "mapex_lama_los") == ("mapex_lama_los", "mapex", "lama_los", False, "full")
    assert chosen("--pipeline", "nearest", "--spad") == ("nearest", "nearest", "observed", True, "realtime")
    assert chosen("--no-spad", "--predictor", "lama_los") == ("superex", "superex", "lama_los", False, "realtime")
    # Another planner or predictor: the profile the rule gives them (MapEx reads the ensemble's variance).
    assert chosen("--planner", "mapex", "--predictor", "lama_los") == \
        ("superex", "mapex", "lama_los", True, "full")
    assert chosen("--planner", "mapex", "--profile", "realtime")[-1] == "realtime"
    assert chosen("--pipeline", "mapex_lama_los", "--profile", "realtime")[-1] == "realtime"


def test_a_pipeline_without_carving_is_not_recorded(tmp_path, capsys):
    assert main(["explore", "--map", MAP, "--pipeline", "no_carving", "--steps", "2", "--out", str(tmp_path / "r"),
                 "--record", str(tmp_path / "r.mcap")]) == 2
    assert "turns the carving off" in capsys.readouterr().err


def test_the_defaults_are_the_one_default_profile():
    default = PROFILES[DEFAULT_PROFILE]
    ensemble = make_predictor("lama_los")
    try:
        assert ensemble.max_members == default.max_members == 1
    finally:
        getattr(ensemble, "close", lambda: None)()
    assert make_sensing("observed", True, 0).skips == default.nlos_skips
    for function in (make_predictor, make_sensing, run_benchmark_episode):
        assert inspect.signature(function).parameters["profile"].default is None
    assert "superex" in build_parser().parse_args(["benchmark", "--out", "x"]).planners
    assert build_parser().parse_args(["explore", "--map", MAP, "--out", "x"]).pipeline == DEFAULT_PIPELINE
    # The ROS 2 node's parameters sit below the pipeline's layer and spell the default out: they must agree.
    from superex_deploy.ros.params import NodeParams
    node = NodeParams()
    assert (node.planner, node.profile) == (PIPELINES[DEFAULT_PIPELINE].planner, DEFAULT_PROFILE)


def test_a_benchmark_episode_defaults_to_the_default_profile_and_full_is_the_old_default():
    grid = load_map(MAP)
    start = start_poses(MAP)[0]

    def coverage(**settings):
        run = run_benchmark_episode(grid, start, "nearest", ObservedAsPrediction(), steps=25, seed=0, **settings)
        return run.result.to_json()["coverage"], run.result.to_json()["config"]

    default = PROFILES[DEFAULT_PROFILE]
    assert coverage() == coverage(profile=default, cfg=default.episode_config())
    # The unskipped pipeline, what the default was before the table: ExplorationConfig()'s episode.
    assert PROFILES["full"].episode_config() == ExplorationConfig()
    assert coverage(profile=PROFILES["full"]) == coverage(profile=PROFILES["full"], cfg=ExplorationConfig())
