"""The exact SPAD skips of issue #25: rays whose late light cannot vote on an unknown window cell are left out of
the back-projection (bit-identical result), and the learned filter is not rerun on an input it has seen; the
inexact ``evidence_every`` skips the evidence of frames between. Kernels against their slow twins in
tests/naive.py."""

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, list_maps, load_map, random_start
from superex_deploy.onboard.nlos import NlosConfig, estimate_los
from superex_deploy.onboard.nlos.back_projection import (READ_BLOCK, _n_radii, _readable_ring_bounds, _window,
                                                          back_project_patch, rays_reaching_unknown)
from superex_deploy.onboard.nlos.los import late_threshold
from superex_deploy.onboard.nlos.processing import COUNTS, NlosSkips, SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig, SpadNoise

from tests.naive import naive_readable_rings, naive_voted_rings

SHORT = SpadConfig(n_rays=360, n_secondary=32, range_m=4.0)
EXACT = NlosSkips(rays_without_unknown=True, filter_same_input=True)


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


class CountingFilter:
    """A stand-in learned filter that depends on its input and the robot cell; counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, bp, pose_rc):
        self.calls += 1
        out = np.sqrt(bp).astype(np.float32)
        out[pose_rc[0], :] = np.maximum(out[pose_rc[0], :], np.float32(0.25))
        return out


def _episode_frames(seed, n_frames, still_every=3):
    """A random walk of frames on a train floor, standing still every ``still_every``-th frame, with the known
    mask growing by what the frames carve (as in an episode)."""
    rng = np.random.default_rng(seed)
    grid = load_map(list_maps("train")[seed % 7])
    pose = random_start(grid, rng, 0.3)
    frames = []
    for k in range(n_frames):
        if k % still_every:
            pose = random_start(grid, rng, 0.3)
        frames.append((pose, simulate_scan(grid, pose, SHORT)))
    return grid, frames


@pytest.mark.parametrize("bp_filter", [None, "counting"])
def test_the_exact_skips_give_the_same_carving_and_evidence_as_processing_in_full(bp_filter):
    for seed in range(3):
        grid, frames = _episode_frames(seed, 15)
        filters = [CountingFilter(), CountingFilter()] if bp_filter else [None, None]
        full = SpadProcessing(sensor=SHORT, bp_filter=filters[0])
        skipping = SpadProcessing(sensor=SHORT, bp_filter=filters[1], skips=EXACT)
        known = np.zeros(grid.shape, bool)
        rows, cols = np.indices(grid.shape)
        for pose, scan in frames:
            known |= (rows - pose[0]) ** 2 + (cols - pose[1]) ** 2 < 30 ** 2  # what the robot has seen around it
            carved_f, evidence_f = full.process_scan(scan, known)
            carved_s, evidence_s = skipping.process_scan(scan, known)
            np.testing.assert_array_equal(carved_s, carved_f)
            np.testing.assert_array_equal(evidence_s, evidence_f)
            known |= carved_f
        counts = skipping.counts
        assert counts["rays_skipped"] > 0 and counts["rays"] > counts["rays_skipped"]
        if bp_filter:
            # Standing still with the same known cells repeats the filter's input: it runs once for those.
            assert counts["same_input"] >= 1
            assert filters[1].calls == filters[0].calls - counts["same_input"]
        else:
            assert counts["same_input"] == 0  # the Laplacian filter is cheap: always run


def test_the_filter_reruns_when_the_input_or_the_robot_cell_changes():
    grid, frames = _episode_frames(0, 2, still_every=10)  # the same cell twice
    (pose, scan), _ = frames
    bp_filter = CountingFilter()
    processing = SpadProcessing(sensor=SHORT, bp_filter=bp_filter, skips=NlosSkips(filter_same_input=True))
    known = np.zeros(grid.shape, bool)
    processing.process_scan(scan, known)
    processing.process_scan(scan, known)
    assert bp_filter.calls == 1 and processing.counts["same_input"] == 1
    # A known cell in the window changes the back-projection: the filter runs again.
    bp = back_project_patch(scan, estimate_los(scan), NlosConfig(), known)
    r, c = np.argwhere(bp.values > 0)[0]
    known[bp.top + r, bp.left + c] = True
    processing.process_scan(scan, known)
    assert bp_filter.calls == 2
    # The same back-projection read from another robot cell is another input (the filter reads the cell).
    bp = back_project_patch(scan, estimate_los(scan), NlosConfig(), known)
    assert processing._same_filter_input(bp, scan.pose_rc)
    assert not processing._same_filter_input(bp, (scan.pose_rc[0], scan.pose_rc[1] + 1))


def test_evidence_every_k_back_projects_every_kth_frame_and_carves_every_frame():
    grid, frames = _episode_frames(1, 9, still_every=100)
    bp_filter = CountingFilter()
    every3 = SpadProcessing(sensor=SHORT, bp_filter=bp_filter, skips=NlosSkips(evidence_every=3))
    full = SpadProcessing(sensor=SHORT, bp_filter=CountingFilter())
    known = np.zeros(grid.shape, bool)
    reference = SpadProcessing(sensor=SHORT, bp_filter=CountingFilter())  # fed only frames 0, 3, 6
    for k, (pose, scan) in enumerate(frames):
        carved_k, evidence_k = every3.process_scan(scan, known)
        carved_f, _ = full.process_scan(scan, known)
        np.testing.assert_array_equal(carved_k, carved_f)  # carving is never skipped
        if k % 3 == 0:
            reference.process_scan(scan, known)
        np.testing.assert_array_equal(evidence_k, reference.evidence)
    assert bp_filter.calls == 3
    assert every3.counts["evidence_skipped"] == 6 and every3.counts["frames"] == 9


def test_the_new_skips_are_checked_and_counted():
    with pytest.raises(ValueError, match="evidence_every must be an integer >= 1, got 0"):
        NlosSkips(evidence_every=0)
    with pytest.raises(ValueError, match="evidence_every must be an integer >= 1, got True"):
        NlosSkips(evidence_every=True)
    with pytest.raises(ValueError, match="rays_without_unknown must be True or False"):
        NlosSkips(rays_without_unknown=1)
    processing = SpadProcessing(skips=EXACT)
    assert tuple(processing.counts) == COUNTS
    processing.counts["rays"] = 5
    processing.reset()
    assert set(processing.counts.values()) == {0}


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
