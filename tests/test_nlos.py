from dataclasses import replace

import numpy as np
import pytest

from scipy import ndimage, stats

from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.nlos import (
    NlosConfig, back_project, carve, carve_radius_cap_m, estimate_los, laplacian_filter, process_scan)
from superex_deploy.onboard.nlos.back_projection import RING_PAD, _accumulate_votes, _draw_rings, _window
from superex_deploy.onboard.nlos.carving import carve_sectors
from superex_deploy.onboard.nlos.los import _los_and_first_late_bins, late_threshold
from superex_deploy.onboard.nlos.normals import hit_normals, step_deviation
from superex_deploy.evaluation.metrics import wall_iou, wall_iou_tolerant
from superex_deploy.sim.spad import nlos_ground_truth
from superex_deploy.spad_types import SpadConfig, SpadNoise, SparseHistograms
from superex_deploy.sim.spad import simulate_scan
from tests.naive import (
    naive_back_projection, naive_draw_rings, naive_carve_sectors, naive_hit_normals, naive_step_deviation,
    naive_los_and_first_late_bins)

RES = 0.1


def test_los_estimates_recover_the_wall_points(l_corner):
    grid = l_corner()
    scan = simulate_scan(grid, (50, 10), SpadConfig(n_rays=720, n_secondary=64))
    los = estimate_los(scan)
    hit = scan.truth.h1_rc[:, 0] >= 0
    assert np.all(los.los_bin[hit] >= 0)
    np.testing.assert_allclose(los.d1_m[hit], scan.truth.d1_m[hit], atol=scan.bin_path_m / 2)
    exact = np.all(los.h1_rc[hit] == scan.truth.h1_rc[hit], axis=1)
    # Rays that clip a wall corner for less than the half-bin distance uncertainty land in the next cell.
    assert exact.mean() > 0.85
    assert np.all(np.abs(los.h1_rc[hit] - scan.truth.h1_rc[hit]).max(axis=1) <= 1)


def test_l_corner_carves_hidden_free_space_and_back_projects_the_hidden_wall(l_corner):
    grid = l_corner()
    scan = simulate_scan(grid, (50, 12), SpadConfig(n_rays=1440, n_secondary=128))
    result = process_scan(scan, NlosConfig(window_m=6.0))
    assert not np.any(result.carved & grid.occupied)
    seen = np.zeros(grid.shape, bool)
    hits = scan.truth.h1_rc[scan.truth.h1_rc[:, 0] >= 0]
    seen[hits[:, 0], hits[:, 1]] = True
    hidden_free = ~grid.occupied.copy()
    hidden_free[45:, :] = False  # the robot's corridor is in line of sight
    assert np.any(result.carved & hidden_free), "no hidden free cell was carved"
    assert result.carved[40, 35]  # 0.5 m up the side corridor, out of sight
    # The back-projection's strongest hidden-region response lies near a hidden wall.
    hidden_bp = np.where(np.arange(70)[:, None] < 44, result.bp, 0.0)
    peak = np.unravel_index(np.argmax(hidden_bp), hidden_bp.shape)
    truth = nlos_ground_truth(scan)
    near = np.argwhere(truth)
    assert np.min(np.hypot(*(near - peak).T)) <= 3.0


def test_los_and_first_late_bins_match_naive():
    rng = np.random.default_rng(0)
    histograms = (rng.random((40, 50)) < 0.1).astype(np.float32) * rng.random((40, 50)).astype(np.float32)
    histograms[:5] = 0.0  # rays without any detection
    histograms[5:10, -3:] = 1.0  # detections in the last bins: the guard window runs past the end
    histograms[10:15, 20:23] = 0.7  # a flat-topped direct peak: the earliest of the tied bins
    for guard, threshold in [(1, 0.0), (3, 0.5), (4, 0.0)]:
        los_bin = np.empty(40, np.int64)
        first_late = np.empty(40, np.int64)
        # The kernel reads only the detections: the dense rows thresholded, as estimate_los passes them.
        detections = SparseHistograms.from_dense(histograms, threshold)
        _los_and_first_late_bins(detections.row_start, detections.bins, detections.counts, threshold, guard,
                                 los_bin, first_late)
        expected_los, expected_late = naive_los_and_first_late_bins(histograms, threshold, guard)
        np.testing.assert_array_equal(los_bin, expected_los)
        np.testing.assert_array_equal(first_late, expected_late)
        assert np.all(los_bin[:5] == -1) and np.all(first_late[:5] == -1)


def test_hit_normals_match_naive():
    rng = np.random.default_rng(1)
    for trial in range(10):
        points = rng.integers(0, 30, size=(60, 2)) + 0.5
        if trial % 2:  # hits along a few digitised straight walls, so that the residual bound decides
            t = rng.uniform(0, 12, size=60)
            starts = rng.uniform(5, 20, size=(4, 2))[rng.integers(4, size=60)]
            direction = rng.normal(size=(4, 2))[rng.integers(4, size=60)]
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            points = np.floor(starts + t[:, None] * direction) + 0.5
        points = points[np.argsort(points[:, 0], kind="stable")]  # the kernel's contract: sorted by row
        max_residual = [np.inf, 0.9, 0.6][trial % 3]
        max_gap = [np.inf, 2.0, 1.0, 1.5][trial % 4]
        # One interior distance per point (widened by the pose-error margin in carving), on some trials.
        interior = np.full(60, 1.5) if trial < 6 else rng.uniform(1.0, 4.0, size=60)
        ref_normals, ref_reliable = naive_hit_normals(points, 5.0, interior=interior, max_residual=max_residual,
                                                      max_gap=max_gap)
        results = []
        for n_parts in (1, 4, 70):  # sequential, uneven runs, more parts than points
            normals = np.zeros((60, 2))
            reliable = np.zeros(60, bool)
            hit_normals(points, 5.0, 0.1, max_residual, max_gap, interior, normals, reliable, n_parts)
            np.testing.assert_array_equal(reliable, ref_reliable)
            np.testing.assert_allclose(np.abs(np.sum(normals * ref_normals, axis=1))[reliable], 1.0, atol=1e-6)
            results.append(normals)
        for normals in results[1:]:
            np.testing.assert_array_equal(normals, results[0])


def test_step_deviation_matches_naive_and_the_staircase_geometry():
    rng = np.random.default_rng(5)
    for trial in range(6):
        points = np.unique(rng.integers(0, 12, size=(50, 2)), axis=0) + 0.5  # unique rows come sorted by row
        angles = rng.uniform(0, 2 * np.pi, size=len(points))
        normals = np.stack([np.sin(angles), np.cos(angles)], axis=1)
        out = np.full(len(points), -1.0)
        step_deviation(points, normals, out)
        np.testing.assert_allclose(out, naive_step_deviation(points, normals), atol=1e-12)
    # A straight row: no step; a one-cell jog in it: the cells either side of the jog see a diagonal neighbour
    # 45 degrees off the row's line; an isolated cell: nothing.
    row = np.array([[5.5, c + 0.5] for c in range(6)])
    jog = np.array([[5.5, 0.5], [5.5, 1.5], [5.5, 2.5], [6.5, 3.5], [6.5, 4.5], [6.5, 5.5], [9.5, 9.5]])
    for points, expected_deg in [(row, [0.0] * 6), (jog, [0, 0, 45, 45, 0, 0, 0])]:
        out = np.zeros(len(points))
        step_deviation(points, np.tile([1.0, 0.0], (len(points), 1)), out)
        np.testing.assert_allclose(np.rad2deg(out), expected_deg, atol=1e-9)


def test_carve_sectors_match_naive():
    rng = np.random.default_rng(2)
    apex = rng.uniform(5, 25, size=(10, 2))
    # Random normals, and normals along the axes and a hair off them (the column bounds' special cases).
    angles = np.concatenate([rng.uniform(0, 2 * np.pi, size=6), np.pi / 2 * np.arange(4) + [0, 1e-12, 0, -1e-12]])
    normals = np.stack([np.sin(angles), np.cos(angles)], axis=1)
    normals[6:] = np.round(normals[6:], 15)
    radius = rng.uniform(0, 12, size=10)
    radius[6:] = 9.0  # reaching past the grid's edges
    # One wall strip per wall point (the pose-error margin widens each by its own amount).
    strip = np.full(10, 1.5)
    strip[[1, 4]] = [2.7, 4.0]
    # One sector per wall point (narrowed where the wall steps), an empty one among them.
    limits = np.cos(np.deg2rad(rng.uniform(0, 90, size=10)))
    limits[[0, 7]] = [np.cos(np.deg2rad(70)), 2.0]
    expected = naive_carve_sectors((30, 32), apex, normals, radius, strip, limits)
    assert expected.any()
    for n_parts in (1, 2, 5):  # rows dealt to parallel parts in blocks
        out = np.zeros((30, 32), bool)
        carve_sectors(apex, normals, radius, strip, limits, 0, 0, out, n_parts)
        np.testing.assert_array_equal(out, expected)
        # A patch of the grid receives exactly its part of the carving.
        for top, left, height, width in [(7, 3, 12, 20), (0, 20, 30, 12), (29, 31, 1, 1), (10, 10, 0, 5)]:
            patch = np.zeros((height, width), bool)
            carve_sectors(apex, normals, radius, strip, limits, top, left, patch, n_parts)
            np.testing.assert_array_equal(patch, expected[top:top + height, left:left + width])


@pytest.mark.parametrize("noisy", [False, True])
def test_back_projection_matches_naive(noisy):
    walls = np.zeros((40, 40), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[10:30, 25] = True
    walls[20, 5:15] = True
    grid = OccupancyGrid(walls, ~walls, RES, "room")
    noise = SpadNoise(enabled=noisy, ambient_per_bin=0.5, jitter_s=0.0)
    scan = simulate_scan(grid, (30, 10), SpadConfig(n_rays=90, n_secondary=16, range_m=4.0, noise=noise),
                         rng=np.random.default_rng(0))
    cfg = NlosConfig(window_m=1.5)
    los = estimate_los(scan, cfg)
    known = np.zeros(grid.shape, bool)
    known[25:35, 5:15] = True
    fast = back_project(scan, los, cfg, known)
    for threads in (1, 2, 5):  # the parallel split changes nothing
        np.testing.assert_array_equal(back_project(scan, los, replace(cfg, threads=threads), known), fast)
    threshold, guard = late_threshold(scan, cfg, scan.n_bins)
    assert scan.is_sparse != noisy  # noise-free scans come sparse, noisy ones dense
    apex, normals = los.wall_apex, los.wall_normal
    n_radii = int(np.ceil(scan.config.range_m / RES)) + 1
    votes = np.zeros((len(los.wall_cells), n_radii + RING_PAD))
    q_max = np.full(len(los.wall_cells), -1, np.int64)
    detections = los.detections
    for n_parts in (3, 1):  # split over the wall cells: every part sums its own votes, so nothing changes
        previous = votes.copy()
        votes[:] = 0.0
        q_max[:] = -1
        _accumulate_votes(detections.row_start, detections.bins, detections.counts, los.los_bin, los.ray_wall,
                          np.nan_to_num(los.d1_m), guard, threshold, scan.config.noise.background_per_bin,
                          scan.bin_path_m, RES, votes, q_max, n_parts)
    np.testing.assert_array_equal(votes, previous)
    assert votes.any() and not votes[:, n_radii:].any()
    voted = votes != 0
    np.testing.assert_array_equal(q_max, np.where(voted.any(axis=1), voted.shape[1] - 1 - np.argmax(voted[:, ::-1],
                                                                                                    axis=1), -1))
    slow = naive_back_projection(scan.histograms, los.los_bin, los.ray_wall, np.nan_to_num(los.d1_m), apex, normals,
                                 guard, threshold, scan.config.noise.background_per_bin, scan.bin_path_m, RES,
                                 _window(scan, cfg), known, n_radii)
    assert slow.max() > 0
    np.testing.assert_allclose(fast, slow / slow.max(), rtol=1e-5, atol=1e-6)
    assert not fast[known].any()
    # The window bounds the map: nothing outside it.
    r0, r1, c0, c1 = _window(scan, cfg)
    outside = np.ones(grid.shape, bool)
    outside[r0:r1 + 1, c0:c1 + 1] = False
    assert not fast[outside].any()


def test_draw_rings_matches_naive_on_random_and_axis_aligned_wall_points():
    rng = np.random.default_rng(6)
    n_walls = 8
    # Apexes on cell centres and edges and normals along the axes (and a hair off them) hit the ties.
    apex = np.concatenate([rng.uniform(2, 28, size=(4, 2)), rng.integers(3, 27, size=(4, 2)) + [[0.5, 0.0]]])
    angles = np.concatenate([rng.uniform(0, 2 * np.pi, size=4), np.pi / 2 * np.arange(4) + [0, 1e-12, 0, -1e-12]])
    normals = np.stack([np.sin(angles), np.cos(angles)], axis=1)
    normals[4:] = np.round(normals[4:], 15)
    votes = rng.random((n_walls, 25)) * (rng.random((n_walls, 25)) < 0.4)
    votes[:, -1] = 1.0  # rings out to the last radius: the largest ring index must stay inside the votes
    votes[-1, 10:] = 0.0  # a wall point whose rings stop early
    votes[-2] = 0.0  # one without any vote
    voted = votes != 0
    q_max = np.where(voted.any(axis=1), 24 - np.argmax(voted[:, ::-1], axis=1), -1)
    padded = np.concatenate([votes, np.zeros((n_walls, RING_PAD))], axis=1)
    # Known cells scattered, in long runs and blocks (the sweep jumps over runs of known cells), none and all.
    blocks = np.zeros((30, 34), bool)
    blocks[5:25, 10:20] = blocks[:, 30:] = blocks[14, :] = True
    for known in (rng.random((30, 34)) < 0.2, blocks, np.zeros((30, 34), bool), np.ones((30, 34), bool)):
        for window in ([0, 29, 0, 33], [5, 20, 8, 30], [12, 12, 3, 3]):
            expected = naive_draw_rings(apex, normals, votes, window, known)
            draws = []
            for n_parts in (1, 3, 7):  # sequential, uneven parts, more parts than row blocks
                drawn = np.zeros((window[1] - window[0] + 1, window[3] - window[2] + 1))
                _draw_rings(apex, normals, padded, q_max, np.array(window, np.int64), known, drawn, n_parts)
                draws.append(drawn)
                bp = np.zeros((30, 34))
                bp[window[0]:window[1] + 1, window[2]:window[3] + 1] = drawn
                np.testing.assert_allclose(bp, expected, rtol=1e-12)
                assert not bp[known].any()
                assert known.all() or bp.any()
            for drawn in draws[1:]:  # every cell adds its votes in the same order, whatever the split
                np.testing.assert_array_equal(drawn, draws[0])


def test_noisy_false_alarm_rate_matches_its_setting():
    """Background only (no walls in range): the fraction of rays with a detection matches the exact rate the
    Poisson threshold implies, and that rate is at most the stated one (Bonferroni over the bins)."""
    grid = OccupancyGrid(np.zeros((400, 400), bool), np.ones((400, 400), bool), RES, "void")
    noise = SpadNoise(enabled=True, ambient_per_bin=3.0, dark_per_bin=0.1, jitter_s=0.0)
    n_rays = 4000
    cfg_spad = SpadConfig(n_rays=n_rays, n_secondary=4, noise=noise)
    scan = simulate_scan(grid, (200, 200), cfg_spad, rng=np.random.default_rng(3))
    n_bins = scan.n_bins
    for stated in (0.05, 0.2):
        threshold, _ = late_threshold(scan, NlosConfig(false_alarm_rate=stated), n_bins)
        rate = np.mean((scan.histograms > threshold).any(axis=1))
        per_bin = stats.poisson.sf(np.floor(threshold), noise.background_per_bin)
        expected = 1.0 - (1.0 - per_bin) ** n_bins
        # The integer threshold overshoots the per-bin budget (0.05 -> 0.018, 0.2 -> 0.075), never undershoots.
        assert stated / 4 < expected <= stated
        assert abs(rate - expected) <= 5 * np.sqrt(expected * (1 - expected) / n_rays), (stated, rate, expected)
    loose = NlosConfig(false_alarm_rate=0.9)
    assert late_threshold(scan, loose, n_bins)[0] < late_threshold(scan, NlosConfig(), n_bins)[0]


def test_carve_radius_cap_follows_angular_sampling():
    assert carve_radius_cap_m(64, 0.1) == pytest.approx(0.1 * 64 / np.pi)
    assert carve_radius_cap_m(128, 0.1) == pytest.approx(2 * carve_radius_cap_m(64, 0.1))


def test_wall_iou_and_laplacian():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert wall_iou(a, b) == 1.0
    a[0, :2] = True
    b[0, 1:3] = True
    assert wall_iou(a, b) == pytest.approx(1 / 3)
    spike = np.zeros((9, 9))
    spike[4, 4] = 1.0
    filtered = laplacian_filter(spike)
    assert filtered.max() == pytest.approx(1.0) and np.argmax(filtered) == 40 and filtered.min() >= 0.0
    with pytest.raises(ValueError, match="bool"):
        wall_iou(a.astype(int), b)
    with pytest.raises(ValueError, match="one shape"):
        wall_iou(a, b[:2])


def test_laplacian_filter_on_the_nonzero_box_equals_filtering_the_whole_grid():
    rng = np.random.default_rng(4)
    for _ in range(60):
        height, width = rng.integers(5, 50, size=2)
        bp = np.zeros((height, width))
        r0, c0 = rng.integers(0, height), rng.integers(0, width)
        r1, c1 = rng.integers(r0, height) + 1, rng.integers(c0, width) + 1
        bp[r0:r1, c0:c1] = rng.random((r1 - r0, c1 - c0)) * (rng.random((r1 - r0, c1 - c0)) < 0.5)
        sigma = float(rng.choice([0.0, 0.5, 1.0, 2.0]))
        whole = np.clip(-ndimage.laplace(ndimage.gaussian_filter(bp, sigma)), 0.0, None)
        expected = (whole / whole.max() if whole.max() > 0 else whole).astype(np.float32)
        np.testing.assert_array_equal(laplacian_filter(bp, sigma), expected)
    assert not laplacian_filter(np.zeros((6, 7))).any()
    # Grids thinner than the stencils: the reflections wrap more than once (scipy's extension, to the bit).
    for shape in [(1, 1), (1, 7), (7, 1), (2, 2), (3, 1), (2, 9)]:
        bp = rng.random(shape) + 0.1
        for sigma in (0.0, 1.0, 2.0):
            whole = np.clip(-ndimage.laplace(ndimage.gaussian_filter(bp, sigma)), 0.0, None)
            expected = (whole / whole.max() if whole.max() > 0 else whole).astype(np.float32)
            np.testing.assert_array_equal(laplacian_filter(bp, sigma), expected)
    with pytest.raises(ValueError, match="sigma_cells"):
        laplacian_filter(np.zeros((6, 7)), -1.0)


def test_wall_iou_tolerant():
    pred = np.zeros((10, 10), bool)
    truth = np.zeros((10, 10), bool)
    assert wall_iou_tolerant(pred, truth, 1.0) == 1.0
    truth[5, 2:6] = True
    pred[6, 2:6] = True  # the same wall drawn one row off
    assert wall_iou(pred, truth) == 0.0
    assert wall_iou_tolerant(pred, truth, 1.0) == 1.0
    assert wall_iou_tolerant(pred, truth, 0.5) == 0.0
    pred[9, 9] = True  # a false alarm far from every wall
    assert wall_iou_tolerant(pred, truth, 1.0) == pytest.approx(4 / 5)
    rng = np.random.default_rng(5)
    for _ in range(20):
        a, b = rng.random((2, 12, 12)) < 0.2
        assert wall_iou_tolerant(a, b, 0.0) == pytest.approx(wall_iou(a, b))
    with pytest.raises(ValueError, match="tolerance_cells"):
        wall_iou_tolerant(pred, truth, -1.0)
    with pytest.raises(ValueError, match="one shape"):
        wall_iou_tolerant(pred, truth[:3], 1.0)


def test_bad_inputs(l_corner):
    grid = l_corner()
    scan = simulate_scan(grid, (50, 10), SpadConfig(n_rays=90, n_secondary=8))
    with pytest.raises(ValueError, match="SpadScan"):
        process_scan(scan.histograms)
    with pytest.raises(ValueError, match="known"):
        back_project(scan, estimate_los(scan), NlosConfig(), np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="sector_margin_deg"):
        NlosConfig(sector_margin_deg=90.0)
    with pytest.raises(ValueError, match="false_alarm_rate"):
        NlosConfig(false_alarm_rate=0.0)
    with pytest.raises(ValueError, match="window_m"):
        NlosConfig(window_m=-1.0)
    for threads in (-1, 1.5):
        with pytest.raises(ValueError, match="threads"):
            NlosConfig(threads=threads)


def test_process_scan_patches_hold_the_whole_maps(l_corner):
    """process_scan keeps its maps as patches: each equals the public whole-map function's result, and nothing
    non-zero lies outside it."""
    grid = l_corner()
    scan = simulate_scan(grid, (50, 10), SpadConfig(n_rays=360, n_secondary=32))
    known = np.zeros(grid.shape, bool)
    known[45:55, 5:15] = True
    cfg = NlosConfig(window_m=3.0)
    result = process_scan(scan, cfg, known)
    los = estimate_los(scan, cfg)
    np.testing.assert_array_equal(result.carved, carve(scan, los, cfg))
    np.testing.assert_array_equal(result.bp, back_project(scan, los, cfg, known))
    np.testing.assert_array_equal(result.bp_filtered, laplacian_filter(result.bp))
    for patch, whole in ((result.carved_patch, result.carved), (result.bp_patch, result.bp),
                         (result.bp_filtered_patch, result.bp_filtered)):
        assert patch.grid_shape == grid.shape and whole.any()
        np.testing.assert_array_equal(whole[patch.slices], patch.values)
        outside = np.ones(grid.shape, bool)
        outside[patch.slices] = False
        assert not whole[outside].any()
    r0, r1, c0, c1 = _window(scan, cfg)
    assert result.bp_patch.slices == (slice(r0, r1 + 1), slice(c0, c1 + 1))


def test_dense_histograms_give_the_same_results_as_sparse_ones(l_corner):
    """A sensor that delivers dense histograms (as a real one does) is processed exactly like the simulator's
    sparse ones: only the detections are read."""
    scan = simulate_scan(l_corner(), (50, 10), SpadConfig(n_rays=360, n_secondary=32))
    dense = replace(scan, stored=scan.histograms)
    assert scan.is_sparse and not dense.is_sparse
    known = np.zeros(scan.grid_shape, bool)
    known[40:60, 0:20] = True
    a, b = process_scan(scan, NlosConfig(), known), process_scan(dense, NlosConfig(), known)
    for name in ("carved", "bp", "bp_filtered"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for name in ("los_bin", "first_late_bin", "h1_rc", "wall_cells", "wall_normal", "normal_reliable"):
        np.testing.assert_array_equal(getattr(a.los, name), getattr(b.los, name))
    assert a.bp.any() and a.carved.any()
