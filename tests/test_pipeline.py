"""``pipeline.build_explorer``, the one way to build an explorer: what each profile and predictor gives, the one
default profile every entry point agrees on, and the retired options' errors (a recording made before they were
retired: tests/test_recording_format.py)."""

import inspect
import json
from dataclasses import asdict

import pytest

from superex_deploy.evaluation.tasks import ScenarioTask, run_scenario
from superex_deploy.cli import main
from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.onboard import ExplorerConfig, SpadProcessing
from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.pipeline import DEFAULT_PROFILE, PROFILES, build_explorer, make_sensing
from superex_deploy.recording.convert import RETIRED
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.oracle import OraclePredictor

MAP = "50052750"
FRAME = MapFrame((60, 80), 0.1)


@pytest.mark.parametrize("profile", sorted(PROFILES))
@pytest.mark.parametrize("clock", ["robot", "simulated"])
def test_each_profile_gives_its_explorer_configuration_and_spad_processing(profile, clock):
    chosen = PROFILES[profile]
    with build_explorer(FRAME, "nearest", "observed", profile=profile, clock=clock, spad=True, seed=3) as explorer:
        assert explorer.cfg == chosen.explorer_config(clock)
        assert explorer.planner.name == "nearest" and isinstance(explorer.predictor, ObservedAsPrediction)
        assert isinstance(explorer.spad_processing, SpadProcessing)
        assert explorer.spad_processing.skips == chosen.nlos_skips
        assert explorer.spad_processing.bp_filter is None  # the Laplacian filter: observed reads no evidence
        assert explorer.frame == FRAME
    with build_explorer(FRAME, "nearest", "observed", profile=profile) as plain:
        assert plain.spad_processing is None


def test_the_predictors_that_need_no_models():
    grid = load_map(MAP)
    frame = MapFrame(grid.shape, grid.resolution_m)
    with build_explorer(frame, "superex", "oracle", grid=grid) as oracle:
        assert isinstance(oracle.predictor, OraclePredictor)
    with pytest.raises(ValueError, match="oracle"):
        build_explorer(frame, "superex", "oracle")  # the truth is a simulation's, given as the grid
    given = ObservedAsPrediction()
    with build_explorer(frame, make_planner("superex", gain="goal"), given) as explorer:
        assert explorer.predictor is given and explorer.planner.cfg.gain == "goal"
    with pytest.raises(ValueError, match="unknown predictor 'crystal_ball'"):
        build_explorer(frame, "nearest", "crystal_ball")
    with pytest.raises(ValueError, match="the evidence predictor reads the SPAD evidence"):
        build_explorer(frame, "nearest", "evidence")
    with pytest.raises(ValueError, match="unknown planner"):
        build_explorer(frame, "teleport", "observed")
    with pytest.raises(ValueError, match="unknown profile 'fast'"):
        build_explorer(frame, "nearest", "observed", profile="fast")
    with pytest.raises(ValueError, match="clock must be 'robot' or 'simulated'"):
        build_explorer(frame, "nearest", "observed", clock="wall")
    with pytest.raises(ValueError, match="spad must be True, False or a SpadProcessing"):
        build_explorer(frame, "nearest", "observed", spad="yes")


def test_a_learned_predictor_follows_the_profile_and_the_cores():
    with build_explorer(FRAME, "superex", "lama_los", cores=2) as explorer:  # the default: one member, a worker
        assert explorer.predictor.max_members == PROFILES[DEFAULT_PROFILE].max_members == 1
        assert explorer.cfg.prediction == PROFILES[DEFAULT_PROFILE].schedule and explorer.scheduled is not None
        assert (explorer.budget.cores, explorer.budget.worker_threads) == (2, 1)
    with build_explorer(FRAME, "superex", "lama_bp", profile="full", spad=True) as full:
        assert full.predictor.max_members is None and full.scheduled is None
        assert full.spad_processing.bp_filter is not None  # the Pix2Pix filter's evidence for lama_bp
    # A planner that reads the ensemble's variance gets the whole ensemble by default, and is refused one member.
    with build_explorer(FRAME, "mapex", "lama_los") as mapex:
        assert mapex.predictor.max_members is None and mapex.cfg == PROFILES["full"].explorer_config()
    with pytest.raises(ValueError, match="use --profile full"):
        build_explorer(FRAME, "mapex", "lama_los", profile="realtime")


def test_every_entry_point_defaults_to_the_one_default_profile(tmp_path):
    """The CLI, build_explorer, a benchmark task and the Gymnasium environment: each left to its default runs
    DEFAULT_PROFILE (a test that fails when one of them drifts)."""
    gym_env = pytest.importorskip("superex_deploy.gym_env")
    assert DEFAULT_PROFILE in PROFILES
    with build_explorer(FRAME, "nearest", "observed") as explorer:
        assert explorer.cfg == PROFILES[DEFAULT_PROFILE].explorer_config()

    out = tmp_path / "explore"
    assert main(["explore", "--map", MAP, "--steps", "2", "--gif-every", "0", "--out", str(out)]) == 0
    explored = json.loads((out / "metrics.json").read_text())
    assert explored["profile"] == DEFAULT_PROFILE
    assert explored["config"]["explorer"] == json.loads(json.dumps(asdict(
        PROFILES[DEFAULT_PROFILE].explorer_config().for_simulation())))

    task = ScenarioTask(map_name=MAP, start_index=0, start_rc=start_poses(MAP)[0], planner="nearest",
                        predictor="observed", spad=False, steps=2, seed=0, iou_every=0)
    summary = run_scenario(task)
    assert summary["profile"] == DEFAULT_PROFILE
    assert summary["config"]["explorer"] == json.loads(json.dumps(
        asdict(PROFILES[DEFAULT_PROFILE].explorer_config("simulated").for_simulation())))

    env = gym_env.ExplorationEnv(map=MAP, max_steps=5)
    try:
        env.reset(seed=0)
        assert env.profile == DEFAULT_PROFILE
        assert env._explorer.cfg == PROFILES[DEFAULT_PROFILE].explorer_config("simulated").for_simulation()
    finally:
        env.close()
    # The paper suite names the profile its table was measured with.
    from superex_deploy.commands import paper_benchmark

    assert '"full"' in inspect.getsource(paper_benchmark._run_row)


def test_a_benchmark_task_naming_full_is_the_committed_pipeline():
    grid = load_map(MAP)
    start = start_poses(MAP)[0]
    task = ScenarioTask(map_name=MAP, start_index=0, start_rc=start, planner="superex", predictor="oracle",
                        spad=False, steps=12, seed=0, iou_every=0, profile="full")
    summary = run_scenario(task)
    direct = run_episode(grid, start, make_planner("superex"), OraclePredictor(grid), steps=12, seed=0,
                         cfg=PROFILES["full"].episode_config(iou_every=0))
    assert summary["profile"] == "full" and summary["coverage"] == direct.to_json()["coverage"]
    assert summary["goals"] == direct.to_json()["goals"]


def test_an_episode_takes_a_built_explorer_only_when_it_matches():
    grid = load_map(MAP)
    frame = MapFrame(grid.shape, grid.resolution_m)
    start = start_poses(MAP)[0]
    cfg = PROFILES["full"].episode_config(iou_every=0)
    other = build_explorer(frame, "nearest", "observed", profile="realtime")
    with pytest.raises(ValueError, match="configuration is not cfg.explorer"):
        run_episode(grid, start, explorer=other, steps=2, cfg=cfg)
    assert other._closed  # the episode closed the explorer it refused
    with pytest.raises(ValueError, match="either an explorer or a planner and a predictor"):
        run_episode(grid, start, make_planner("nearest"), steps=2, cfg=cfg)
    sensing = make_sensing("observed", True, 0, profile=PROFILES["full"])
    unrelated = build_explorer(frame, "nearest", "observed", profile="full", spad=True, cfg=cfg.explorer)
    with pytest.raises(ValueError, match="SPAD processing must be the sensing's"):
        run_episode(grid, start, explorer=unrelated, steps=2, cfg=cfg, sensing=sensing)


@pytest.mark.parametrize("field", sorted(RETIRED["superex"][1]))
def test_a_retired_planner_option_is_refused_by_name(field, tmp_path, capsys):
    value = RETIRED["superex"][1][field]
    with pytest.raises(ValueError, match=f"bad configuration for planner 'superex': .*'{field}'"):
        make_planner("superex", **{field: value})
    if field == "choice":
        out = tmp_path / "run"
        assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--planner", "superex", "--planner-option",
                     "choice=rollout", "--steps", "2", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "'choice'" in err and err.count("\n") == 1
        assert not out.exists()


@pytest.mark.parametrize("field", ["match_sigma_cells", "match_sigma_deg", "start_after_scans"])
def test_a_retired_scan_matching_option_is_refused_by_name(field):
    assert field in RETIRED["scan_matching"][1]
    with pytest.raises(TypeError, match=field):
        ScanMatchingConfig(**{field: 1})
    with pytest.raises(ValueError, match=f"ScanMatchingConfig has no field '{field}'"):
        ExplorerConfig.from_json({"scan_matching": {field: RETIRED["scan_matching"][1][field]}})
    assert not hasattr(ScanMatchingConfig(), field)


def test_the_ablation_without_carving_counts_no_carved_cell_and_keeps_the_rest_of_the_sensing():
    kw = dict(map_name=MAP, start_index=0, start_rc=start_poses(MAP)[0], planner="nearest", predictor="observed",
              spad=True, steps=15, seed=0, iou_every=0, profile="full")
    carving = run_scenario(ScenarioTask(**kw))
    ablated = run_scenario(ScenarioTask(**kw, carving=False))
    assert carving["coverage_with_carving"][-1] > carving["coverage"][-1]  # carving adds cells on this floor
    assert ablated["coverage_with_carving"] == ablated["coverage"]
    # The nearest planner reads no carved cell while the pose is exact only through the map: the line-of-sight
    # coverage of the first steps is the same with and without carving.
    assert ablated["coverage"][:3] == carving["coverage"][:3]
