"""The SPAD processing's skips (#16): each trigger on hand-built scenes, the exact skip gives exactly the result of
processing, and the physics invariants (sound carving, finite evidence) hold with every skip on."""

from dataclasses import replace

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, list_maps, load_map, random_start
from superex_deploy.onboard.nlos import NlosConfig, carve_radius_cap_m
from superex_deploy.onboard.nlos.processing import NlosSkips, SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig

RES = 0.1
SENSOR = SpadConfig(n_rays=360, n_secondary=32, range_m=4.0)
ALL = NlosSkips(without_unknown=True, when_still=True, filter_without_votes=True)


def _l_corner():
    """The test_nlos scene: the robot's corridor (rows 45-55) and a side corridor north to a hidden wall."""
    walls = np.ones((70, 60), bool)
    walls[45:56, 1:40] = False
    walls[10:45, 30:40] = False
    return OccupancyGrid(walls, ~walls, RES, "l-corner")


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


def test_a_robot_standing_still_for_100_frames_is_processed_once():
    grid = _l_corner()
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


def test_a_turn_on_the_spot_is_not_still():
    grid = _l_corner()
    scan = simulate_scan(grid, (50, 12), SENSOR)
    turned = replace(scan, angles=scan.angles + 0.3)  # the same cell, another heading
    processing = SpadProcessing(sensor=SENSOR, skips=NlosSkips(when_still=True))
    known = np.zeros(grid.shape, bool)
    processing.process_scan(scan, known)
    processing.process_scan(turned, known)
    processing.process_scan(turned, known)
    assert processing.counts["still"] == 1


def test_an_empty_back_projection_window_skips_the_filter():
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
    corner = _l_corner()
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
