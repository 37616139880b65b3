"""The SPAD processing's frame skips (superex_deploy.onboard.nlos.processing.NlosSkips): each trigger on hand-built
scenes (no unknown cell in reach, a robot standing still, an empty back-projection window, a filter input seen
before, evidence every k-th frame), the exact skips give exactly the result of processing in full, the physics
invariants (sound carving, finite evidence) hold with every skip on, and the options are checked and counted. The
rays skipped inside the back-projection are in test_nlos_back_projection_skips.py."""

from dataclasses import replace

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, list_maps, load_map, random_start
from superex_deploy.onboard.nlos import NlosConfig, carve_radius_cap_m, estimate_los
from superex_deploy.onboard.nlos.back_projection import back_project_patch
from superex_deploy.onboard.nlos.processing import COUNTS, NlosSkips, SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig

RES = 0.1
SENSOR = SpadConfig(n_rays=360, n_secondary=32, range_m=4.0)
ALL = NlosSkips(without_unknown=True, when_still=True, filter_without_votes=True)
EXACT = NlosSkips(rays_without_unknown=True, filter_same_input=True)


class CountingFilter:
    """A stand-in Pix2Pix filter: wall probability 0.5 wherever the back-projection has a vote; counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, bp, pose_rc):
        self.calls += 1
        return np.where(bp > 0, np.float32(0.5), np.float32(0.0)).astype(np.float32)


def _reach(sensor=SENSOR):
    """The reach by hand: the carving reach (range + cap) or the back-projection window, whichever is larger."""
    carving = int(np.ceil((sensor.range_m + carve_radius_cap_m(sensor.n_secondary, RES)) / RES)) + 1
    return max(carving, int(np.ceil(NlosConfig().window_m / RES)))


def test_a_frame_with_no_unknown_cell_in_reach_is_skipped_and_one_with_a_single_unknown_cell_is_not():
    walls = np.ones((200, 200), bool)
    walls[70:130, 70:130] = False
    grid = OccupancyGrid(walls, ~walls, RES, "room")
    pose = (100, 100)
    scan = simulate_scan(grid, pose, SENSOR)
    known = np.ones(grid.shape, bool)
    processing = SpadProcessing(sensor=SENSOR, skips=NlosSkips(without_unknown=True))
    carved, evidence = processing.process_scan(scan, known)
    assert {k: processing.counts[k] for k in ("frames", "no_unknown", "still", "no_votes")} == {
        "frames": 1, "no_unknown": 1, "still": 0, "no_votes": 0}
    assert not carved.any() and not evidence.any()

    # An unknown cell on the edge of the reach is enough to process the frame...
    reach = _reach()
    assert pose[1] + reach + 1 < grid.shape[1]  # the reach ends inside the map
    known[pose[0], pose[1] + reach] = False
    processing.reset()
    processing.process_scan(scan, known)
    assert processing.counts["no_unknown"] == 0
    # ...and one just outside it is not.
    known[pose[0], pose[1] + reach] = True
    known[pose[0], pose[1] + reach + 1] = False
    processing.reset()
    processing.process_scan(scan, known)
    assert processing.counts["no_unknown"] == 1


def test_the_no_unknown_skip_is_exact_on_random_scenes():
    """Wherever the skip triggers, processing the frame would have carved nothing new and raised no evidence."""
    rng = np.random.default_rng(4)
    names = list_maps("train")[:6]
    triggered = 0
    for name in names:
        grid = load_map(name)
        for _ in range(3):
            pose = random_start(grid, rng, 0.3)
            scan = simulate_scan(grid, pose, SENSOR)
            reach = _reach()
            known = np.zeros(grid.shape, bool)
            r, c = pose
            known[max(r - reach, 0):r + reach + 1, max(c - reach, 0):c + reach + 1] = True
            skipped = SpadProcessing(sensor=SENSOR, bp_filter=CountingFilter(), skips=NlosSkips(without_unknown=True))
            full = SpadProcessing(sensor=SENSOR, bp_filter=CountingFilter())
            carved_s, evidence_s = skipped.process_scan(scan, known)
            carved_f, evidence_f = full.process_scan(scan, known)
            assert skipped.counts["no_unknown"] == 1
            triggered += 1
            assert not (carved_f & ~known).any()  # nothing new to carve
            np.testing.assert_array_equal(evidence_s, evidence_f)  # no vote lands on a known cell
    assert triggered == 18


def test_a_robot_standing_still_for_100_frames_is_processed_once(l_corner):
    grid = l_corner()
    scan = simulate_scan(grid, (50, 12), SENSOR)
    bp_filter = CountingFilter()
    processing = SpadProcessing(sensor=SENSOR, bp_filter=bp_filter, skips=NlosSkips(when_still=True))
    known = np.zeros(grid.shape, bool)
    first_carved, _ = processing.process_scan(scan, known)
    first_evidence = processing.evidence.copy()
    assert first_carved.any()
    for _ in range(99):
        carved, evidence = processing.process_scan(scan, known | first_carved)
        assert not carved.any()
        assert np.isfinite(evidence).all()
    assert {k: processing.counts[k] for k in ("frames", "no_unknown", "still", "no_votes")} == {
        "frames": 100, "no_unknown": 0, "still": 99, "no_votes": 0}
    assert bp_filter.calls == 1
    np.testing.assert_array_equal(processing.evidence, first_evidence)
    # One cell further on, the frame is processed again.
    processing.process_scan(simulate_scan(grid, (50, 13), SENSOR), known | first_carved)
    assert processing.counts["still"] == 99 and bp_filter.calls == 2


def test_a_turn_on_the_spot_is_not_still(l_corner):
    grid = l_corner()
    scan = simulate_scan(grid, (50, 12), SENSOR)
    turned = replace(scan, angles=scan.angles + 0.3)  # the same cell, another heading
    processing = SpadProcessing(sensor=SENSOR, skips=NlosSkips(when_still=True))
    known = np.zeros(grid.shape, bool)
    processing.process_scan(scan, known)
    processing.process_scan(turned, known)
    processing.process_scan(turned, known)
    assert processing.counts["still"] == 1


def test_an_empty_back_projection_window_skips_the_filter(l_corner):
    """In a hall whose walls lie beyond the sensor's range, no photon returns and nothing votes: the filter does
    not run and the evidence stays zero (without the skip, the learned filter's bias on an empty window would
    enter the running maximum)."""
    walls = np.zeros((200, 200), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    grid = OccupancyGrid(walls, ~walls, RES, "hall")
    scan = simulate_scan(grid, (100, 100), SENSOR)
    known = np.zeros(grid.shape, bool)
    bp_filter = CountingFilter()
    processing = SpadProcessing(sensor=SENSOR, bp_filter=bp_filter, skips=NlosSkips(filter_without_votes=True))
    _, evidence = processing.process_scan(scan, known)
    assert processing.counts["no_votes"] == 1 and bp_filter.calls == 0
    assert not evidence.any()
    # The L corner has a hidden wall: votes, so the filter runs.
    corner = l_corner()
    processing.reset()
    processing.process_scan(simulate_scan(corner, (50, 12), SENSOR), np.zeros(corner.shape, bool))
    assert processing.counts["no_votes"] == 0 and bp_filter.calls == 1


def test_carving_stays_sound_and_evidence_finite_with_every_skip_on():
    rng = np.random.default_rng(11)
    for name in list_maps("train")[6:10]:
        grid = load_map(name)
        processing = SpadProcessing(sensor=SENSOR, bp_filter=CountingFilter(), skips=ALL)
        known = np.zeros(grid.shape, bool)
        pose = random_start(grid, rng, 0.3)
        for step in range(12):
            if step % 3 == 2:  # stand still every third frame
                scan = simulate_scan(grid, pose, SENSOR)
            else:
                pose = random_start(grid, rng, 0.3)
                scan = simulate_scan(grid, pose, SENSOR)
            carved, evidence = processing.process_scan(scan, known)
            assert not (carved & grid.occupied).any(), f"{name}: a wall cell was carved"
            assert np.isfinite(evidence).all() and evidence.min() >= 0.0 and evidence.max() <= 1.0
            known |= carved
        assert processing.counts["still"] >= 1


def test_skips_must_be_an_nlos_skips():
    with pytest.raises(ValueError, match="skips must be an NlosSkips, got dict"):
        SpadProcessing(skips={"when_still": True})
    with pytest.raises(ValueError, match="when_still must be True or False, got 'no'"):
        NlosSkips(when_still="no")


def test_with_a_biased_filter_the_no_unknown_skip_also_leaves_out_the_bias():
    """A learned filter answers an empty window with its bias; processing a frame with nothing unknown in reach
    would put that bias into the evidence, the skip does not (as filter_without_votes would not)."""
    walls = np.ones((200, 200), bool)
    walls[70:130, 70:130] = False
    grid = OccupancyGrid(walls, ~walls, RES, "room")
    scan = simulate_scan(grid, (100, 100), SENSOR)
    known = np.ones(grid.shape, bool)

    def biased(bp, pose_rc):
        return np.full(bp.shape, np.float32(0.3))

    full = SpadProcessing(sensor=SENSOR, bp_filter=biased)
    skipped = SpadProcessing(sensor=SENSOR, bp_filter=biased, skips=NlosSkips(without_unknown=True))
    _, with_bias = full.process_scan(scan, known)
    _, without = skipped.process_scan(scan, known)
    assert with_bias.min() == np.float32(0.3) and not without.any()


class PoseDependentFilter:
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
        frames.append((pose, simulate_scan(grid, pose, SENSOR)))
    return grid, frames


@pytest.mark.parametrize("bp_filter", [None, "counting"])
def test_the_exact_skips_give_the_same_carving_and_evidence_as_processing_in_full(bp_filter):
    for seed in range(3):
        grid, frames = _episode_frames(seed, 15)
        filters = [PoseDependentFilter(), PoseDependentFilter()] if bp_filter else [None, None]
        full = SpadProcessing(sensor=SENSOR, bp_filter=filters[0])
        skipping = SpadProcessing(sensor=SENSOR, bp_filter=filters[1], skips=EXACT)
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
    bp_filter = PoseDependentFilter()
    processing = SpadProcessing(sensor=SENSOR, bp_filter=bp_filter, skips=NlosSkips(filter_same_input=True))
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
    bp_filter = PoseDependentFilter()
    every3 = SpadProcessing(sensor=SENSOR, bp_filter=bp_filter, skips=NlosSkips(evidence_every=3))
    full = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter())
    known = np.zeros(grid.shape, bool)
    reference = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter())  # fed only frames 0, 3, 6
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


@pytest.mark.parametrize("learned", [True, False], ids=["learned", "laplacian"])
@pytest.mark.parametrize("skips", [NlosSkips(), EXACT, NlosSkips(evidence_every=2)], ids=["none", "exact", "every2"])
def test_without_carving_nothing_is_carved_and_the_evidence_is_that_of_processing_in_full(skips, learned):
    grid, frames = _episode_frames(1, 12)
    full = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter() if learned else None, skips=skips)
    ablated = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter() if learned else None,
                             skips=replace(skips, carving=True))
    known = np.zeros(grid.shape, bool)
    rows, cols = np.indices(grid.shape)
    carved_any = np.zeros(grid.shape, bool)
    for pose, scan in frames:
        known |= (rows - pose[0]) ** 2 + (cols - pose[1]) ** 2 < 30 ** 2
        carved_f, evidence_f = full.process_scan(scan, known)
        carved_a, evidence_a = ablated.process_scan(scan, known)
        assert carved_a.shape == grid.shape and not carved_a.any()
        np.testing.assert_array_equal(evidence_a, evidence_f)
        carved_any |= carved_f
    assert carved_any.any()  # the full processing does carve on these frames: the ablation takes something away


def test_the_carving_skip_is_a_bool():
    with pytest.raises(ValueError, match="carving must be True or False, got 1"):
        NlosSkips(carving=1)
