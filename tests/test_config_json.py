"""Every configuration writes itself as JSON and reads itself back (``superex_deploy.configs``): the classes are
found by importing every module of the package, so a new configuration joins these tests by itself; and a
recording says its format version, which a replay checks."""

import dataclasses
import importlib
import inspect
import json
import pkgutil
import re

import numpy as np
import pytest

import superex_deploy
from superex_deploy.configs import JsonConfig, from_json, to_json


def _config_classes() -> dict:
    """Name -> class of every dataclass of ``superex_deploy`` with both ``to_json`` and ``from_json`` (a module
    that needs an extra not installed, e.g. the ROS 2 wire without cyclonedds, is left out)."""
    found = {}
    for module_info in pkgutil.walk_packages(superex_deploy.__path__, "superex_deploy."):
        try:
            module = importlib.import_module(module_info.name)
        except ModuleNotFoundError as error:
            if (error.name or "").startswith("superex_deploy"):
                raise
            continue
        for obj in vars(module).values():
            if (inspect.isclass(obj) and dataclasses.is_dataclass(obj) and obj.__module__ == module.__name__
                    and callable(getattr(obj, "to_json", None)) and callable(getattr(obj, "from_json", None))):
                found[obj.__name__] = obj
    return found


CONFIGS = _config_classes()

MINIMUM = {
    # onboard: the explorer and what it is built of
    "ExplorerConfig", "MotionConfig", "OccupancyConfig", "ScanMatchingConfig", "MapGrowth", "ExplorationBounds",
    "GoalPolicy", "PredictionSchedule", "PredictionReuse", "SessionConfig", "ThreadBudget",
    # the planners
    "SuperexConfig", "MapexConfig", "HectorConfig", "UpenConfig", "VisibilityConfig", "ExpectedVisibility",
    # NLOS and the SPAD sensor model
    "NlosConfig", "NlosSkips", "SpadConfig", "SpadNoise", "PhotonBudget",
    # the pipeline
    "RealtimeProfile", "Pipeline",
    # the simulator
    "ExplorationConfig", "WorldConfig", "LidarConfig", "PoseNoise", "LidarNoise", "SimNoise", "AlterationConfig", "FloorLayout",
    "RobotSimConfig",
    # the ROS 2 node
    "NodeParams",
}
"""The configurations checked by hand to be found: a class that drops out of the walk (a lost base class) fails."""

OWN_FORMAT = {"PredictionSchedule"}
"""Classes whose ``from_json`` is their own (it also reads an older form) with its own error for an unknown field."""


def _samples() -> dict:
    """Class name -> instances to round-trip: the default one where the class has defaults, and non-default ones
    for the classes that nest configurations, tuples or enums."""
    from superex_deploy.onboard import ExplorerConfig, PredictionReuse, PredictionSchedule
    from superex_deploy.onboard.mapping.growth import MapGrowth
    from superex_deploy.onboard.mapping.log_odds import OccupancyConfig
    from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
    from superex_deploy.onboard.planning.bounds import ExplorationBounds
    from superex_deploy.onboard.planning.goal_policy import GoalPolicy
    from superex_deploy.onboard.planning.motion import MotionConfig
    from superex_deploy.onboard.planning.planners.hector import HectorConfig
    from superex_deploy.onboard.planning.planners.mapex import MapexConfig
    from superex_deploy.onboard.planning.planners.superex import SuperexConfig
    from superex_deploy.onboard.planning.visibility import VisibilityConfig
    from superex_deploy.onboard.prediction.inference.sessions import GraphOptimization, SessionConfig, ThreadBudget
    from superex_deploy.pipeline import PIPELINES, PROFILES
    from superex_deploy.sim.exploration import ExplorationConfig
    from superex_deploy.sim.noise.lidar import LidarNoise
    from superex_deploy.sim.noise.model import SimNoise
    from superex_deploy.sim.noise.pose import PoseNoise
    from superex_deploy.sim.world import LidarConfig, WorldConfig
    from superex_deploy.spad_types import SPAD_PRESETS, SpadConfig, SpadNoise

    samples: dict = {}
    for name, cls in CONFIGS.items():
        try:
            samples[name] = [cls()]
        except TypeError:  # fields without defaults: the instances below
            samples[name] = []
    bounds = ExplorationBounds([(0, 0), (6.5, 0), (6.5, 4), (0, 4.25)])
    explorer = ExplorerConfig(
        motion=MotionConfig(step_m=0.2, drive_carved=True, planning_cell_m=0.2), frontier_min_m=0.5,
        prediction=PredictionSchedule("simulated", 2, 2, True), reuse=PredictionReuse(crop_margin_m=6.4),
        occupancy=OccupancyConfig(footprint_clearing=False), scan_matching=ScanMatchingConfig(enabled=True),
        growth=MapGrowth(), bounds=bounds, return_to_start=True, goal_policy=GoalPolicy(no_progress_s=None))
    noise = SimNoise(pose=PoseNoise(sigma_xy_m=0.05, seed=3), lidar=LidarNoise(sigma_m=0.02, seed=4), spad="low")
    spad = SpadConfig(n_rays=90, noise=SpadNoise(enabled=True, ambient_per_bin=0.01))
    session = SessionConfig(intra_op_threads=1, providers=("CUDAExecutionProvider", "CPUExecutionProvider"),
                            graph_optimization=GraphOptimization.BASIC, allow_spinning=False)
    samples["ExplorationBounds"].append(bounds)
    samples["ExplorerConfig"] += [explorer, ExplorerConfig().for_simulation()]
    samples["ExplorationConfig"] += [
        ExplorationConfig(lidar=LidarConfig(n_rays=360, range_m=8.0), explorer=explorer, iou_every=5,
                          noise=noise),
        ExplorationConfig(noise=SimNoise(pose=noise.pose))]
    samples["WorldConfig"].append(WorldConfig(lidar=LidarConfig(n_rays=360), spad=spad, step_m=0.2,
                                              noise=noise))
    samples["SimNoise"] += [noise, SimNoise(lidar=noise.lidar)]
    samples["SpadConfig"].append(spad)
    samples["RealtimeProfile"] += list(PROFILES.values())
    samples["SessionConfig"].append(session)
    samples["ThreadBudget"] += [ThreadBudget(2, True), ThreadBudget(1, False)]
    samples["Pipeline"] += list(PIPELINES.values())
    samples["PhotonBudget"] += [budget for budget in SPAD_PRESETS.values() if budget is not None]
    samples["MapexConfig"].append(MapexConfig(visibility=VisibilityConfig(n_rays=90, accumulate=True),
                                              min_distance_m=1.0))
    samples["SuperexConfig"].append(SuperexConfig(gain="path", drop_resolved_m=2.0))
    samples["HectorConfig"] += [HectorConfig(visibility=None), HectorConfig(visibility=VisibilityConfig(n_rays=60))]
    samples["GoalPolicy"].append(GoalPolicy(no_progress_s=None, blacklist_expire_s=None, commit_margin=None))
    return samples


SAMPLES = _samples()


def _is_plain_json(value) -> bool:
    """Whether ``value`` is made of JSON's types only (dict with str keys, list, str, int, float, bool, None)."""
    if value is None or isinstance(value, (str, bool, int, float)):
        return type(value) in (type(None), str, bool, int, float)
    if isinstance(value, list):
        return type(value) is list and all(_is_plain_json(item) for item in value)
    if isinstance(value, dict):
        return type(value) is dict and all(isinstance(k, str) and _is_plain_json(v) for k, v in value.items())
    return False


def test_every_configuration_is_found():
    missing = MINIMUM - set(CONFIGS)
    assert not missing, f"configurations without to_json / from_json: {sorted(missing)}"
    for name, cls in CONFIGS.items():
        assert name in OWN_FORMAT or issubclass(cls, JsonConfig), name
        assert SAMPLES[name], f"{name}: no instance to round-trip (give one in _samples)"


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_configurations_round_trip_through_json(name):
    cls = CONFIGS[name]
    for config in SAMPLES[name]:
        written = config.to_json()
        assert _is_plain_json(written), f"{name}.to_json() holds values JSON does not: {written!r}"
        text = json.dumps(written, allow_nan=False)
        again = cls.from_json(json.loads(text))
        assert again == config and type(again) is cls
        assert again.to_json() == written


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_an_unknown_field_is_refused_by_name(name):
    cls = CONFIGS[name]
    written = {**SAMPLES[name][0].to_json(), "no_such_field": 1}
    if name in OWN_FORMAT:
        with pytest.raises(ValueError, match="no_such_field"):
            cls.from_json(written)
        return
    fields = ", ".join(f.name for f in dataclasses.fields(cls) if f.init)
    with pytest.raises(ValueError) as raised:
        cls.from_json(written)
    assert str(raised.value) == f"{name} has no field 'no_such_field' (its fields: {fields})"


def test_reading_is_strict_and_names_the_class():
    from superex_deploy.onboard import ExplorerConfig
    from superex_deploy.onboard.planning.bounds import ExplorationBounds
    from superex_deploy.onboard.planning.motion import MotionConfig
    from superex_deploy.sim.world import LidarConfig

    with pytest.raises(ValueError) as raised:
        LidarConfig.from_json({"n_rays": 360, "rays": 1, "range": 2})
    assert str(raised.value) == "LidarConfig has no fields 'rays', 'range' (its fields: n_rays, range_m)"
    # a nested configuration is read by its own class, which names itself
    with pytest.raises(ValueError, match=re.escape("MotionConfig has no field 'step' (its fields: robot_radius_m")):
        ExplorerConfig.from_json({"motion": {"step": 0.3}})
    # a wrong type gets the class's own error
    with pytest.raises(ValueError, match="step_m"):
        MotionConfig.from_json({"step_m": "fast"})
    with pytest.raises(ValueError, match="motion must be a MotionConfig"):
        ExplorerConfig.from_json({"motion": 0.3})
    with pytest.raises(ValueError) as raised:
        ExplorationBounds.from_json({})
    assert str(raised.value) == "ExplorationBounds.from_json: the field 'points' must be given"
    with pytest.raises(ValueError) as raised:
        MotionConfig.from_json([0.3])
    assert str(raised.value) == "MotionConfig.from_json takes a JSON object, got list [0.3]"
    # left-out fields take their defaults
    assert ExplorerConfig.from_json({}) == ExplorerConfig()
    assert MotionConfig.from_json({"step_m": 0.2}) == MotionConfig(step_m=0.2)


def test_values_are_written_as_json_types():
    from superex_deploy.onboard.planning.motion import MotionConfig
    from superex_deploy.onboard.prediction.inference.sessions import GraphOptimization, SessionConfig
    from superex_deploy.sim.exploration import ExplorationConfig

    written = SessionConfig(graph_optimization=GraphOptimization.EXTENDED).to_json()
    assert written["graph_optimization"] == "ORT_ENABLE_EXTENDED" and written["providers"] == ["CPUExecutionProvider"]
    motion = MotionConfig(step_m=np.float64(0.25), robot_radius_m=np.float32(0.25))
    assert type(motion.to_json()["step_m"]) is float and _is_plain_json(to_json(motion))
    # an enum is read from its value and from the form RealtimeProfile.to_json writes (str of the member)
    for text in ("ORT_ENABLE_BASIC", "GraphOptimization.BASIC"):
        assert SessionConfig.from_json({"graph_optimization": text}).graph_optimization is GraphOptimization.BASIC
    with pytest.raises(ValueError, match="graph_optimization must be a GraphOptimization"):
        SessionConfig.from_json({"graph_optimization": "fastest"})
    # the noise entries of an episode's configuration only where noise is on
    assert "noise" not in ExplorationConfig().to_json()
    assert ExplorationConfig.from_json(ExplorationConfig().to_json()) == ExplorationConfig()


def test_the_functions_serve_any_dataclass():
    @dataclasses.dataclass(frozen=True)
    class Plain:
        size: tuple[int, int] = (1, 2)
        name: str = "a"

    assert to_json(Plain()) == {"size": [1, 2], "name": "a"}
    assert from_json(Plain, {"size": [3, 4]}) == Plain((3, 4))
    with pytest.raises(TypeError, match="to_json takes a dataclass instance"):
        to_json({"size": 1})


def test_a_recording_of_a_newer_format_is_refused(tmp_path, capsys):
    from superex_deploy.cli import main
    from superex_deploy.messages import MapFrame
    from superex_deploy.recording import FORMAT_VERSION, EpisodeRecorder, read_recording

    assert FORMAT_VERSION == "2"
    path = tmp_path / "newer.mcap"
    with EpisodeRecorder(path, MapFrame((20, 20), 0.1), {"format_version": "3"}):
        pass
    expected = f"{path} has recording format '3', this package reads '2': a newer version of superex_deploy wrote it; " \
               "upgrade to replay it"
    with pytest.raises(ValueError) as raised:
        read_recording(path)
    assert str(raised.value) == expected
    assert main(["replay", str(path), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == f"superex replay: error: {expected}"
