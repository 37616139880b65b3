"""The NLOS processing's lengths are metres on every grid: the same parameters in cells of a 0.1 m grid as they
always were, twice as many cells at 0.05 m; the learned filter runs at its model's scale on a finer grid."""

import dataclasses

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard import ExplorerConfig
from superex_deploy.onboard.nlos import NlosConfig, laplacian_filter, process_scan
from superex_deploy.onboard.nlos.shared import metres_to_cells
from superex_deploy.onboard.nlos.processing import SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig


def _fine_l_corner(k: int) -> OccupancyGrid:
    """The conftest's L corner (0.1 m a cell) at ``0.1 / k`` m a cell."""
    walls = np.ones((70, 60), bool)
    walls[45:56, 1:40] = False
    walls[10:45, 30:40] = False
    fine = np.kron(walls, np.ones((k, k), bool))
    return OccupancyGrid(fine, ~fine, 0.1 / k, "fine l-corner")


def test_lengths_in_cells_are_the_former_cell_settings_at_0_1_m_and_scale_with_the_grid():
    cells = NlosConfig().in_cells(0.1)
    # The former defaults, bit for bit: the kernels get the same numbers at 0.1 m.
    assert (cells.apex_margin, cells.wall_strip, cells.normal_radius, cells.normal_max_residual,
            cells.normal_max_gap, cells.normal_interior, cells.laplacian_sigma) == (1.5, 1.5, 5.0, 0.9, 2.0, 2.5, 1.0)
    fine = NlosConfig().in_cells(0.05)
    assert (fine.apex_margin, fine.wall_strip, fine.normal_radius, fine.normal_max_residual, fine.normal_max_gap,
            fine.normal_interior, fine.laplacian_sigma) == (3.0, 3.0, 10.0, 1.8, 4.0, 5.0, 2.0)
    assert metres_to_cells(0.15, 0.1) == 1.5 and 0.15 / 0.1 != 1.5
    assert NlosConfig().in_cells(float(np.float32(0.1))) == cells  # a ROS map's float32 resolution
    with pytest.raises(ValueError, match="must span at least 1.5 and 1 cells of a 0.4 m grid"):
        NlosConfig().in_cells(0.4)
    with pytest.raises(ValueError, match="resolution_m must be a positive"):
        NlosConfig().in_cells(0.0)
    for name in ("normal_radius_m", "normal_max_gap_m", "normal_max_residual_m"):
        with pytest.raises(ValueError, match=name):
            NlosConfig(**{name: 0.0})
    with pytest.raises(ValueError, match="wall_strip_m"):
        NlosConfig(wall_strip_m=-0.1)


def test_a_recorded_configuration_in_cells_is_converted_to_metres_of_its_grid():
    from superex_deploy.recording.convert import convert_metadata

    def converted(nlos, resolution):
        old = {"format_version": "1", "frame": {"shape": [10, 10], "resolution_m": resolution, "origin_xy": [0, 0]},
               "planner": "nearest", "predictor": "observed", "seed": 0, "spad": True,
               "sensor": SpadConfig().to_json(), "nlos": nlos, "explorer": ExplorerConfig().to_json()}
        return NlosConfig.from_json(convert_metadata(old)["nlos"])

    cfg = converted({"window_m": 6.0, "wall_strip_cells": 0.5, "normal_radius_cells": 5.0, "retired_option": 3}, 0.05)
    assert cfg.window_m == 6.0 and cfg.wall_strip_m == 0.025 and cfg.normal_radius_m == 0.25
    assert cfg.in_cells(0.05).wall_strip == 0.5 and cfg.in_cells(0.05).normal_radius == 5.0
    assert converted(NlosConfig().to_json(), 0.1) == NlosConfig()
    assert converted({"apex_margin_cells": 1.5}, 0.1).in_cells(0.1).apex_margin == 1.5
    with pytest.raises(ValueError, match="NlosConfig has no field 'retired_option'"):
        NlosConfig.from_json({"retired_option": 3})


def test_the_laplacian_baseline_blurs_over_metres():
    scan = simulate_scan(_fine_l_corner(2), (100, 20), SpadConfig(n_rays=360, n_secondary=32))
    result = process_scan(scan, NlosConfig(window_m=3.0))
    assert result.bp.any()
    np.testing.assert_array_equal(result.bp_filtered, laplacian_filter(result.bp, 2.0))  # 0.1 m: two cells
    assert not np.array_equal(result.bp_filtered, laplacian_filter(result.bp, 1.0))


def test_the_learned_filter_runs_at_its_models_scale_on_a_finer_grid():
    calls = []

    def spy(bp, pose_rc):
        calls.append((bp.shape, tuple(pose_rc)))
        return np.full(bp.shape, 0.5, np.float32)

    spy.resolution_m = 0.1
    scan = simulate_scan(_fine_l_corner(2), (101, 21), SpadConfig(n_rays=360, n_secondary=32))
    processing = SpadProcessing(nlos_cfg=NlosConfig(window_m=3.0), bp_filter=spy)
    _, evidence = processing.process_scan(scan, np.zeros(scan.grid_shape, bool))
    assert calls == [((70, 60), (50, 10))]
    assert evidence.shape == (140, 120) and np.allclose(evidence, 0.5)
    with pytest.raises(ValueError, match="cannot be served"):
        processing.check_resolution(0.07)


@pytest.mark.parametrize("k", [2, 4])
def test_on_a_finer_copy_of_a_floor_the_evidence_is_the_0_1_m_evidence_interpolated(k):
    """The back-projection is drawn on the model's 0.1 m cells: the same scan of the same floor at 0.1 / k m gives
    the 0.1 m run's filtered evidence, interpolated onto the finer cells (and its carving at the finer grid)."""
    from superex_deploy.onboard.prediction.inference import Pix2PixFilter
    from superex_deploy.onboard.prediction.scale import upsample_linear

    p2p = Pix2PixFilter.from_manifest()
    cfg, sensor = NlosConfig(window_m=4.0), SpadConfig(n_rays=360, n_secondary=32)
    coarse_scan = simulate_scan(_fine_l_corner(1), (50, 10), sensor)
    known = np.zeros(coarse_scan.grid_shape, bool)
    known[45:56, 1:20] = True  # the robot's end of the corridor seen already
    _, coarse = SpadProcessing(nlos_cfg=cfg, bp_filter=p2p.filter_map).process_scan(coarse_scan, known)
    # The same measurement, placed on the finer grid (the sensor where it was: the corner of four fine cells).
    origin = (coarse_scan.origin_yx[0] * k, coarse_scan.origin_yx[1] * k)
    fine_scan = dataclasses.replace(coarse_scan, origin_yx=origin, pose_rc=(int(origin[0]), int(origin[1])),
                                    resolution_m=0.1 / k, grid_shape=(70 * k, 60 * k), truth=None)
    fine_known = np.kron(known, np.ones((k, k), bool))
    _, fine = SpadProcessing(nlos_cfg=cfg, bp_filter=p2p.filter_map).process_scan(fine_scan, fine_known)
    assert coarse.max() > 0.1
    np.testing.assert_allclose(fine, upsample_linear(coarse, k, fine.shape), atol=1e-6)
