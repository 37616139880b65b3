"""Settings in metres, never cells: each gives the cell counts of the 0.1 m grid there and the same metres on a
finer grid; the old cell-count names are unknown fields; a recording written with the old names replays once
``superex convert-recording`` has converted them with its grid."""

import json
from dataclasses import asdict

import numpy as np
import pytest

from superex_deploy.cli import main
from superex_deploy.maps import OccupancyGrid, load_map, start_poses
from superex_deploy.messages import Command, MapFrame
from superex_deploy.onboard import Explorer, ExplorerConfig, PredictionReuse
from superex_deploy.onboard.checks import cells_at_least, cells_within, in_cells
from superex_deploy.onboard.mapping.scan_matching import ScanMatchingConfig
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.planning.motion import MotionConfig
from superex_deploy.onboard.planning.planners import MapexConfig, UpenConfig, make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.prediction.reuse import ReusingPredictor
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.pipeline import PROFILES
from superex_deploy.recording.convert import in_metres
from superex_deploy.sim.world import World, WorldConfig

RESOLUTIONS = (0.1, 0.05, 0.025)
MAP = "50052750"


@pytest.mark.parametrize("resolution, step, frontier, changed", [(0.1, 3, 10, 200), (0.05, 6, 20, 800),
                                                                 (0.025, 12, 40, 3200)])
def test_the_defaults_give_the_cells_of_0_1_m_and_the_same_metres_on_finer_grids(resolution, step, frontier,
                                                                                   changed):
    frame = MapFrame((40, 40), resolution)
    assert MotionConfig().cells_per_step(resolution) == step
    assert World(OccupancyGrid(np.zeros((40, 40), bool), np.ones((40, 40), bool), resolution, "open"),
                 (20, 20)).step_cells == step
    assert ExplorerConfig().frontier_min_cells(resolution) == frontier
    fine = ExplorerConfig(motion=MotionConfig(planning_cell_m=resolution))
    assert Explorer(frame, make_planner("nearest"), ObservedAsPrediction(), cfg=fine).frontier_min_cells == frontier
    # By default the planning runs on blocks of about 0.1 m: its frontier tier is 10 of them on every grid.
    explorer = Explorer(frame, make_planner("nearest"), ObservedAsPrediction())
    assert explorer.planning_grid.factor == round(0.1 / resolution) and explorer.frontier_min_cells == 10
    reusing = ReusingPredictor(ObservedAsPrediction(), PredictionReuse(min_changed_m2=2.0), resolution)
    assert reusing.min_changed_cells == changed
    assert in_cells(UpenConfig().expand_m, resolution) == 5 * 0.1 / resolution
    assert in_cells(MapexConfig().min_distance_m, resolution) == 0.1 / resolution
    matching = ScanMatchingConfig()
    assert (in_cells(matching.field_sigma_m, resolution), in_cells(matching.coarse_sigma_m, resolution)) == (
        0.1 / resolution, 0.2 / resolution)
    assert cells_at_least(matching.min_map_wall_m, resolution) == round(5.0 / resolution)


@pytest.mark.parametrize("resolution", RESOLUTIONS + (0.2, 0.15, 0.03, float(np.float32(0.05))))
def test_a_multiple_of_the_cell_is_that_many_cells_exactly(resolution):
    # 1.0 / 0.1 is 9.999999999999998 and 0.3 / 0.1 2.9999999999999996 in floating point: neither may lose a cell.
    for cells in range(1, 400):
        metres = round(cells * resolution, 12)
        assert cells_at_least(metres, resolution) == cells_within(metres, resolution) == cells
        area = in_metres("reuse", {"min_changed_cells": cells}, resolution)["min_changed_m2"]
        assert cells_at_least(area, resolution ** 2) == cells
    assert cells_within(0.34, 0.1) == 3 and cells_at_least(0.34, 0.1) == 4  # between cells: floor / ceil


def test_the_world_drives_the_same_metres_per_step_on_every_grid():
    for resolution in RESOLUTIONS:
        scale = round(0.1 / resolution)
        occupied = np.zeros((20 * scale, 60 * scale), bool)
        world = World(OccupancyGrid(occupied, ~occupied, resolution, "corridor"), (10 * scale, 2 * scale),
                      WorldConfig(step_m=0.3))
        path = np.array([(10 * scale, c) for c in range(2 * scale, 50 * scale)])
        driven = world.apply(Command(0.0, None, None, world.frame.centres_xy(path), path, False, False))
        assert driven == pytest.approx(0.3) and world.pose_rc == (10 * scale, 2 * scale + world.step_cells)


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_the_first_frontier_tier_holds_the_same_metres_on_every_grid(resolution):
    # A room whose far wall has a 0.5 m and a 1.5 m opening onto the unknown: the frontier above each opening is as
    # long as the opening; the first tier (frontier_min_m = 1 m) holds only the 1.5 m one, on every grid.
    s = round(0.1 / resolution)
    observed = np.full((10 * s, 60 * s), UNKNOWN, np.int8)
    observed[:5 * s] = FREE
    observed[5 * s] = OCCUPIED
    observed[5 * s, 5 * s:10 * s] = observed[5 * s, 20 * s:35 * s] = UNKNOWN
    explorer = Explorer(MapFrame(observed.shape, resolution), make_planner("nearest"), ObservedAsPrediction(),
                        cfg=ExplorerConfig(motion=MotionConfig(planning_cell_m=resolution)))
    assert sorted(len(f.cells) for f in find_frontiers(observed, 1)) == [5 * s, 15 * s]
    first_tier = find_frontiers(observed, explorer.frontier_min_cells)
    assert [len(f.cells) * resolution for f in first_tier] == [pytest.approx(1.5)]


@pytest.mark.parametrize("build, old", [
    (lambda: MotionConfig(step_cells=3), "step_cells"),
    (lambda: WorldConfig(step_cells=3), "step_cells"),
    (lambda: ExplorerConfig(frontier_min_cells=10), "frontier_min_cells"),
    (lambda: PredictionReuse(min_changed_cells=200), "min_changed_cells"),
    (lambda: make_planner("upen", expand_cells=5), "expand_cells"),
    (lambda: make_planner("mapex", min_distance_cells=1), "min_distance_cells"),
    (lambda: ScanMatchingConfig(field_sigma_cells=1.0), "field_sigma_cells"),
    (lambda: ExplorerConfig.from_json({"scan_matching": {"min_map_walls": 50}}), "min_map_walls"),
])
def test_an_old_cell_count_name_is_no_field(build, old):
    with pytest.raises((TypeError, ValueError), match=old):
        build()


def test_the_converter_turns_cells_into_metres_with_the_grid_and_refuses_both_names():
    assert in_metres("motion", {"step_cells": 3, "goal_reached_m": 1.0}, 0.05) == {"step_m": 0.15,
                                                                                   "goal_reached_m": 1.0}
    assert in_metres("motion", {"step_m": 0.3}, 0.05) == {"step_m": 0.3}
    with pytest.raises(ValueError, match="both 'step_cells' and its new name 'step_m'"):
        in_metres("motion", {"step_cells": 3, "step_m": 0.3}, 0.1)
    with pytest.raises(ValueError, match="step_cells must be a finite number >= 0"):
        in_metres("motion", {"step_cells": "x"}, 0.1)


def test_a_recording_with_cell_count_settings_replays_once_converted(tmp_path, record_episode):
    """A recording of an earlier version carries ``step_cells``, ``frontier_min_cells``, ``min_changed_cells``
    (explorer and profile settings), the scan matcher's cell counts and ``expand_cells``: converted with the recording's
    grid (``superex convert-recording``), it replays the same goals."""
    from superex_deploy.evaluation.episodes import make_world_and_explorer

    grid = load_map(MAP)
    cfg = PROFILES["full"].episode_config(iou_every=0)
    explorer_cfg = asdict(cfg.explorer)
    explorer_cfg["motion"]["step_cells"] = 3
    del explorer_cfg["motion"]["step_m"]
    explorer_cfg["frontier_min_cells"] = 10
    del explorer_cfg["frontier_min_m"]
    explorer_cfg["reuse"]["min_changed_cells"] = 0
    del explorer_cfg["reuse"]["min_changed_m2"]
    for old, new in (("field_sigma_cells", "field_sigma_m"), ("coarse_sigma_cells", "coarse_sigma_m"),
                     ("min_map_walls", "min_map_wall_m")):
        explorer_cfg["scan_matching"][old] = round(explorer_cfg["scan_matching"].pop(new) / 0.1)
    settings = PROFILES["full"].to_json()
    settings["reuse"]["min_changed_cells"] = 0
    del settings["reuse"]["min_changed_m2"]
    metadata = {"format_version": "1", "map": MAP, "planner": "upen",
                "planner_options": {"expand_cells": 5, "rrt_samples": 300},
                "predictor": "observed", "seed": 0, "spad": False, "models": None, "sensor": None, "nlos": None,
                "explorer": explorer_cfg, "profile": "full", "profile_settings": settings}
    path = tmp_path / "old.mcap"
    world, explorer = make_world_and_explorer(grid, start_poses(MAP)[1], make_planner("upen", rrt_samples=300),
                                              ObservedAsPrediction(), 0, cfg)
    goals = record_episode(path, world, explorer, metadata)
    assert main(["convert-recording", str(path), str(tmp_path / "new.mcap")]) == 0
    assert main(["replay", str(tmp_path / "new.mcap"), "--out", str(tmp_path / "replay")]) == 0
    replay = json.loads((tmp_path / "replay" / "metrics.json").read_text())
    assert replay["goals_match"] and replay["goals"]["cells"] == goals and goals
