"""The rays skipped inside the back-projection (superex_deploy.onboard.nlos.back_projection): rays whose late light
cannot vote on an unknown window cell are left out, with a bit-identical result; the ring bounds and the kept rays
against their slow twins in tests/naive.py. The whole-frame skips are in test_nlos_processing_skips.py."""

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, list_maps, load_map, random_start
from superex_deploy.onboard.nlos import NlosConfig, estimate_los
from superex_deploy.onboard.nlos.back_projection import (READ_BLOCK, back_project_patch, _n_radii,
                                                          _readable_ring_bounds, _window, rays_reaching_unknown)
from superex_deploy.onboard.nlos.los import late_threshold
from superex_deploy.onboard.nlos.processing import NlosSkips, SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig, SpadNoise

from tests.naive import naive_readable_rings, naive_voted_rings

SHORT = SpadConfig(n_rays=360, n_secondary=32, range_m=4.0)


def _known_mask(grid, pose, rng, kind):
    """A known mask of one of several shapes: a disc around the robot (what exploring leaves), the disc with holes,
    random noise, everything, nothing."""
    rows, cols = np.indices(grid.shape)
    if kind == "disc":
        radius = rng.uniform(5, 90)
        return (rows - pose[0]) ** 2 + (cols - pose[1]) ** 2 < radius ** 2
    if kind == "disc_holes":
        known = (rows - pose[0]) ** 2 + (cols - pose[1]) ** 2 < rng.uniform(20, 120) ** 2
        for _ in range(3):
            r, c, size = rng.integers(0, grid.shape[0]), rng.integers(0, grid.shape[1]), rng.integers(1, 6)
            known[r:r + size, c:c + size] = False
        return known
    if kind == "noise":
        return rng.random(grid.shape) < rng.uniform(0.5, 0.999)
    if kind == "all":
        return np.ones(grid.shape, bool)
    return np.zeros(grid.shape, bool)


def _scenes(n, seed, sensor, kinds=("disc", "disc_holes", "noise", "all", "none")):
    rng = np.random.default_rng(seed)
    names = list_maps("train")
    for k in range(n):
        grid = load_map(names[rng.integers(len(names))])
        pose = random_start(grid, rng, 0.3)
        noisy = k % 3 == 2
        cfg = sensor if not noisy else SpadConfig(n_rays=sensor.n_rays, n_secondary=sensor.n_secondary,
                                                   range_m=sensor.range_m, noise=SpadNoise(enabled=True))
        scan = simulate_scan(grid, pose, cfg, rng=rng if noisy else None)
        yield grid, pose, scan, _known_mask(grid, pose, rng, kinds[k % len(kinds)])


def test_the_readable_ring_bounds_hold_every_ring_an_unknown_cell_in_front_lies_on():
    cfg = NlosConfig(window_m=2.0)
    checked = empty = 0
    for grid, pose, scan, known in _scenes(8, 1, SHORT, kinds=("disc", "disc_holes", "noise", "all")):
        los = estimate_los(scan, cfg)
        window = _window(scan, cfg)
        lo = np.empty(len(los.wall_cells), np.int64)
        hi = np.empty(len(los.wall_cells), np.int64)
        _readable_ring_bounds(los.wall_apex, los.wall_normal, window, known, lo, hi)
        rings = naive_readable_rings(los.wall_apex, los.wall_normal, window, known)
        slack = int(np.ceil(READ_BLOCK * np.sqrt(2))) + 2
        for u, exact in enumerate(rings):
            if len(exact) == 0:
                empty += 1
                if known[window[0]:window[1] + 1, window[2]:window[3] + 1].all():
                    assert lo[u] > hi[u]  # nothing unknown in the window: nothing readable
                continue
            checked += 1
            assert lo[u] <= exact[0] and hi[u] >= exact[-1], (u, lo[u], hi[u], exact[0], exact[-1])
            assert lo[u] >= exact[0] - slack and hi[u] <= exact[-1] + slack  # bounds, but not loose ones
    assert checked > 100 and empty > 10


@pytest.mark.slow
def test_a_kept_ray_is_one_whose_rings_span_meets_the_bounds_and_every_ray_that_votes_on_a_readable_ring_is_kept():
    cfg = NlosConfig(window_m=2.0)
    skipped = kept = 0
    for grid, pose, scan, known in _scenes(9, 2, SHORT):
        los = estimate_los(scan, cfg)
        keep = rays_reaching_unknown(scan, los, cfg, known)
        window = _window(scan, cfg)
        readable = naive_readable_rings(los.wall_apex, los.wall_normal, window, known)
        threshold, guard = late_threshold(scan, cfg, scan.n_bins)
        d = los.detections
        voted = naive_voted_rings(d.row_start, d.bins, d.counts, los.los_bin, los.ray_wall, guard, threshold,
                                  scan.bin_path_m, scan.resolution_m, _n_radii(scan))
        for i, rings in enumerate(voted):
            u = los.ray_wall[i]
            if u < 0 or len(rings) == 0:
                assert not keep[i]
                continue
            if np.isin(rings, readable[u]).any():
                assert keep[i], f"ray {i} votes on a ring an unknown cell reads, but was skipped"
            kept += int(keep[i])
            skipped += int(not keep[i])
    assert kept > 100 and skipped > 100


@pytest.mark.slow
@pytest.mark.parametrize("sensor, window_m, n", [(SHORT, 8.0, 30), (SHORT, 2.0, 15), (SpadConfig(), 8.0, 12)])
def test_skipping_the_rays_that_reach_no_unknown_cell_gives_the_same_back_projection_to_the_last_bit(sensor,
                                                                                                       window_m, n):
    cfg = NlosConfig(window_m=window_m)
    shares = []
    for grid, pose, scan, known in _scenes(n, 3 + n, sensor):
        los = estimate_los(scan, cfg)
        keep = rays_reaching_unknown(scan, los, cfg, known)
        full = back_project_patch(scan, los, cfg, known)
        skipped = back_project_patch(scan, los, cfg, known, keep_rays=keep)
        assert (full.top, full.left) == (skipped.top, skipped.left)
        np.testing.assert_array_equal(skipped.values, full.values)
        voting = (los.ray_wall >= 0).sum()
        shares.append(1 - keep.sum() / max(voting, 1))
    shares = np.array(shares)
    assert (shares == 1).any() and (shares < 0.5).any() and ((shares > 0) & (shares < 1)).any(), shares


def test_keep_rays_is_checked():
    grid, pose, scan, known = next(_scenes(1, 0, SHORT))
    los = estimate_los(scan)
    with pytest.raises(ValueError, match="keep_rays must be a bool array of shape"):
        back_project_patch(scan, los, NlosConfig(), known, keep_rays=np.ones(3, bool))
    with pytest.raises(ValueError, match="known must be a bool array of shape"):
        rays_reaching_unknown(scan, los, NlosConfig(), known[:-1])


def test_a_window_with_no_unknown_cell_skips_every_ray_and_draws_nothing():
    walls = np.ones((120, 120), bool)
    walls[40:80, 40:80] = False
    grid = OccupancyGrid(walls, ~walls, 0.1, "room")
    scan = simulate_scan(grid, (60, 60), SHORT)
    known = np.ones(grid.shape, bool)
    processing = SpadProcessing(sensor=SHORT, skips=NlosSkips(rays_without_unknown=True))
    _, evidence = processing.process_scan(scan, known)
    assert processing.counts["rays"] > 300 and processing.counts["rays_skipped"] == processing.counts["rays"]
    assert not evidence.any()
