import numpy as np

from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.onboard.planning.planners import NearestFrontier
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.maps import load_map, start_poses


def test_spad_sensing_adds_sound_carved_coverage_to_an_episode():
    # From this start the first 40 steps carve ~800 cells the LiDAR has not seen (measured).
    grid = load_map("50052750")
    start = start_poses("50052750")[2]
    sensing = SpadSensing()  # default sensor: with fewer primaries too few wall normals are trusted to carve
    seen_walls = []

    class Recorder:
        name = "observed"

        def predict(self, observed, extra=None):
            seen_walls.append(extra)
            return ObservedAsPrediction().predict(observed)

    result = run_episode(grid, start, NearestFrontier(), Recorder(), steps=40, seed=0, sensing=sensing)
    assert np.all(result.coverage_with_carving >= result.coverage)
    assert result.coverage_with_carving[-1] > result.coverage[-1]
    carved_walls = np.any(result.final_observed[grid.occupied] == 0)
    assert not carved_walls, "a carved cell was a ground-truth wall"
    # The evidence channel reached the predictor and accumulates back-projection.
    assert seen_walls and seen_walls[-1] is not None and seen_walls[-1].max() > 0


def test_a_bp_filter_replaces_the_laplacian_and_evidence_is_its_running_maximum():
    from superex_deploy.onboard.types import UNKNOWN
    from superex_deploy.onboard.nlos import laplacian_filter

    grid = load_map("50052750")
    poses = [start_poses("50052750")[2], (start_poses("50052750")[2][0], start_poses("50052750")[2][1] + 30)]
    observed = np.full(grid.shape, UNKNOWN, np.int8)
    default, laplacian, raw = SpadSensing(), SpadSensing(bp_filter=lambda bp, pose: laplacian_filter(bp)), []

    def keep_raw(bp, pose):
        raw.append((bp.copy(), pose))
        return bp

    identity = SpadSensing(bp_filter=keep_raw)
    for pose in poses:
        carved_a, evidence_a = default(grid, pose, observed)
        carved_b, evidence_b = laplacian(grid, pose, observed)
        carved_c, evidence_c = identity(grid, pose, observed)
        # The filtered path computes the same carving and, with the Laplacian as filter, the same evidence.
        assert np.array_equal(carved_a, carved_b) and np.array_equal(carved_a, carved_c)
        np.testing.assert_array_equal(evidence_a, evidence_b)
    assert [pose for _, pose in raw] == poses
    np.testing.assert_array_equal(evidence_c, np.maximum(raw[0][0], raw[1][0]))
    assert evidence_c.max() == 1.0 and not np.array_equal(evidence_c, evidence_a)
