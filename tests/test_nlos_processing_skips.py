"""The SPAD processing's skips (superex_deploy.onboard.nlos.processing.NlosSkips): evidence every k-th frame on
real frames, the carving left out, the physics invariants (sound carving, finite evidence) with the skips on, and
the options checked and counted."""

import numpy as np
import pytest

from superex_deploy.maps import list_maps, load_map, random_start
from superex_deploy.onboard.nlos.processing import COUNTS, NlosSkips, SpadProcessing
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig

RES = 0.1
SENSOR = SpadConfig(n_rays=360, n_secondary=32, range_m=4.0)


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



def test_carving_stays_sound_and_evidence_finite_with_the_skips_on():
    rng = np.random.default_rng(11)
    for name in list_maps("train")[6:10]:
        grid = load_map(name)
        processing = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter(),
                                    skips=NlosSkips(evidence_every=2))
        known = np.zeros(grid.shape, bool)
        for step in range(8):
            scan = simulate_scan(grid, random_start(grid, rng, 0.3), SENSOR)
            carved, evidence = processing.process_scan(scan, known)
            assert not (carved & grid.occupied).any(), f"{name}: a wall cell was carved"
            assert np.isfinite(evidence).all() and evidence.min() >= 0.0 and evidence.max() <= 1.0
            known |= carved
        assert processing.counts == {"frames": 8, "evidence_skipped": 4}


def test_without_carving_nothing_is_carved_and_the_evidence_is_the_same():
    grid, frames = _episode_frames(2, 4, still_every=100)
    full = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter())
    uncarved = SpadProcessing(sensor=SENSOR, bp_filter=PoseDependentFilter(), skips=NlosSkips(carving=True))
    known = np.zeros(grid.shape, bool)
    for pose, scan in frames:
        carved_f, evidence_f = full.process_scan(scan, known)
        carved_u, evidence_u = uncarved.process_scan(scan, known)
        assert carved_f.any() and not carved_u.any()
        np.testing.assert_array_equal(evidence_u, evidence_f)


def test_the_skips_are_checked_and_counted():
    with pytest.raises(ValueError, match="skips must be an NlosSkips, got dict"):
        SpadProcessing(skips={"evidence_every": 2})
    with pytest.raises(ValueError, match="evidence_every must be an integer >= 1, got 0"):
        NlosSkips(evidence_every=0)
    with pytest.raises(ValueError, match="evidence_every must be an integer >= 1, got True"):
        NlosSkips(evidence_every=True)
    with pytest.raises(ValueError, match="carving must be True or False, got 'no'"):
        NlosSkips(carving="no")
    processing = SpadProcessing()
    assert tuple(processing.counts) == COUNTS == ("frames", "evidence_skipped")
    processing.counts["frames"] = 5
    processing.reset()
    assert set(processing.counts.values()) == {0}
