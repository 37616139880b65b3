"""Accuracy and calibration by distance from known space (superex_deploy.evaluation.known_distance): distances,
bins, counts and their measures on hand-made grids whose answers are worked out by hand, pooling, and the lattice
measure on patterns of known period."""

import json
import math

import numpy as np
import pytest

from superex_deploy.evaluation.known_distance import (DISTANCE_BINS_M, NLL_EPSILON, CalibrationCounts,
                                                      counts_by_distance, distance_bin_label, distance_to_known,
                                                      lattice_strength, pool_counts)


def _strip() -> tuple[np.ndarray, float]:
    """A 1 x 25 strip at 0.5 m a cell, known at column 0 only: column k lies k * 0.5 m from known space, so the
    bins hold columns 1-4 (0-2 m), 5-10 (2-5 m), 11-20 (5-10 m) and 21-24 (>10 m)."""
    unknown = np.ones((1, 25), bool)
    unknown[0, 0] = False
    return unknown, 0.5


def test_distance_to_known_in_metres():
    unknown, resolution = _strip()
    np.testing.assert_allclose(distance_to_known(unknown, resolution)[0], 0.5 * np.arange(25))
    square = np.ones((3, 3), bool)
    square[1, 1] = False
    np.testing.assert_allclose(distance_to_known(square, 0.1), 0.1 * np.array(
        [[math.sqrt(2), 1, math.sqrt(2)], [1, 0, 1], [math.sqrt(2), 1, math.sqrt(2)]]))
    assert np.all(np.isinf(distance_to_known(np.ones((2, 3), bool), 0.1)))  # nothing known: no distance
    assert not distance_to_known(np.zeros((2, 3), bool), 0.1).any()
    with pytest.raises(ValueError, match="positive"):
        distance_to_known(square, 0.0)


def test_bin_labels():
    assert [distance_bin_label(*b) for b in DISTANCE_BINS_M] == ["0-2 m", "2-5 m", "5-10 m", ">10 m"]


def test_counts_by_distance_on_a_hand_made_strip():
    unknown, resolution = _strip()
    probability = np.full((1, 25), 0.1)
    wall = np.zeros((1, 25), bool)
    # 0-2 m (columns 1-4): p 0.9, 0.6, 0.2, 0.0 against walls at columns 2 and 3.
    probability[0, 1:5] = [0.9, 0.6, 0.2, 0.0]
    wall[0, 2:4] = True
    # >10 m (columns 21-24): one wall, never called.
    wall[0, 22] = True
    probability[0, 0] = 1.0  # the known cell is never scored
    counts = counts_by_distance(probability, wall, unknown, resolution)
    assert list(counts) == ["0-2 m", "2-5 m", "5-10 m", ">10 m"]
    assert [c.cells for c in counts.values()] == [4, 6, 10, 4]

    near = counts["0-2 m"].summary()
    assert near["cells"] == 4 and near["wall_share"] == 0.5
    assert near["predicted_share"] == 0.5  # 0.9 and 0.6
    assert near["iou"] == pytest.approx(1 / 3)  # hit at column 2; union columns 1, 2, 3
    assert near["mean_p"] == pytest.approx(1.7 / 4)
    # Each cell in its own probability bin: |0.9 - 0| + |0.6 - 1| + |0.2 - 1| + |0.0 - 0|, over 4 cells.
    assert near["ece"] == pytest.approx((0.9 + 0.4 + 0.8 + 0.0) / 4)
    expected_nll = -(math.log(0.1) + math.log(0.6) + math.log(0.2) + math.log1p(-NLL_EPSILON)) / 4
    assert near["nll"] == pytest.approx(expected_nll)
    assert near["brier"] == pytest.approx((0.81 + 0.16 + 0.64 + 0.0) / 4)

    middle = counts["2-5 m"].summary()
    assert middle["wall_share"] == 0.0 and middle["predicted_share"] == 0.0
    assert middle["iou"] == 1.0  # neither walls nor calls: as map_iou
    assert middle["ece"] == pytest.approx(0.1) and middle["mean_p"] == pytest.approx(0.1)
    far = counts[">10 m"].summary()
    assert far["wall_share"] == 0.25 and far["iou"] == 0.0
    # All four cells in the 0.1 bin: |0.1 - 0.25|.
    assert far["ece"] == pytest.approx(0.15)


def test_area_and_given_distance_restrict_and_agree():
    unknown, resolution = _strip()
    rng = np.random.default_rng(0)
    probability = rng.random((1, 25))
    wall = rng.random((1, 25)) < 0.3
    area = np.ones((1, 25), bool)
    area[0, 3:8] = False  # columns 3-4 (0-2 m) and 5-7 (2-5 m) left out
    counts = counts_by_distance(probability, wall, unknown, resolution, area=area)
    assert [c.cells for c in counts.values()] == [2, 3, 10, 4]
    again = counts_by_distance(probability, wall, unknown, resolution, area=area,
                               distance=distance_to_known(unknown, resolution))
    assert all(a.to_dict() == b.to_dict() for a, b in zip(counts.values(), again.values()))


def test_pooling_sums_cells_not_means():
    # Two predictions: one with a single wall called right (IoU 1), one with 3 walls all missed (IoU 0). Pooled:
    # 1 hit over a union of 4, not the mean of the two IoUs (0.5).
    first = CalibrationCounts.from_cells(np.array([0.9, 0.0]), np.array([True, False]))
    second = CalibrationCounts.from_cells(np.array([0.1, 0.1, 0.1]), np.array([True, True, True]))
    pooled = pool_counts([{"a": first}, {"a": second}])["a"]
    assert pooled.summary()["iou"] == pytest.approx(0.25)
    assert pooled.cells == 5 and pooled.walls == 4
    whole = CalibrationCounts.from_cells(np.array([0.9, 0.0, 0.1, 0.1, 0.1]),
                                         np.array([True, False, True, True, True]))
    for key, value in whole.summary().items():
        assert pooled.summary()[key] == pytest.approx(value)
    assert pool_counts([]) == {}


def test_counts_survive_json_and_empty_bins_have_no_measures():
    counts = CalibrationCounts.from_cells(np.array([0.25, 0.75, 1.0]), np.array([False, True, True]))
    assert counts.bin_cells[9] == 1  # p = 1.0 falls in the last bin
    back = CalibrationCounts.from_dict(json.loads(json.dumps(counts.to_dict())))
    assert back.to_dict() == counts.to_dict()
    empty = CalibrationCounts().summary()
    assert empty["cells"] == 0 and all(empty[k] is None for k in empty if k != "cells")
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        CalibrationCounts.from_cells(np.array([1.5]), np.array([True]))
    with pytest.raises(ValueError, match="cells"):
        CalibrationCounts.from_cells(np.array([0.5, 0.5]), np.array([True]))


def test_a_calibrated_prediction_has_zero_ece():
    # Every probability bin's mean p equals its wall share: 10 cells at 0.3 with 3 walls, 4 at 0.75 with 3 walls.
    p = np.array([0.3] * 10 + [0.75] * 4)
    y = np.array([True] * 3 + [False] * 7 + [True] * 3 + [False])
    summary = CalibrationCounts.from_cells(p, y).summary()
    assert summary["ece"] == pytest.approx(0.0, abs=1e-12)
    assert summary["mean_p"] == pytest.approx(summary["wall_share"])


def test_lattice_strength_of_known_patterns():
    rng = np.random.default_rng(1)
    template = rng.uniform(-0.05, 0.05, (8, 8))
    lattice = 0.1 + np.tile(template, (12, 12))
    region = np.ones(lattice.shape, bool)
    pure = lattice_strength(lattice, region, 8)
    assert pure.share == pytest.approx(1.0) and pure.cells == 96 * 96
    assert pure.amplitude == pytest.approx(np.ptp(template))
    # Locked to the array's origin, not to the region: the same lattice over a region starting at (3, 5).
    assert lattice_strength(lattice, np.pad(np.ones((60, 60), bool), ((3, 33), (5, 31))), 8).share == \
        pytest.approx(1.0)
    # Noise with no period: the 64 phase means explain about 64 / cells of its variance.
    noise = rng.normal(0.1, 0.05, lattice.shape)
    assert lattice_strength(noise, region, 8).share < 5 * 64 / noise.size
    # Half lattice, half noise of equal variance: about half.
    mixed = lattice_strength(0.1 + np.tile(template, (12, 12)) + rng.normal(0.0, template.std(), lattice.shape),
                             region, 8)
    assert 0.4 < mixed.share < 0.6
    # A smooth ramp: the phase means differ by its slope times the phase offset only (share 0.007 here).
    ramp = np.add.outer(np.arange(96), np.arange(96)) * 1e-3
    assert lattice_strength(ramp, region, 8).share < 0.01
    assert lattice_strength(np.full((16, 16), 0.2), np.ones((16, 16), bool), 8) == (0.0, 0.0, 256)
    with pytest.raises(ValueError, match="no cell"):
        lattice_strength(ramp, np.zeros(ramp.shape, bool), 8)
    with pytest.raises(ValueError, match="period"):
        lattice_strength(ramp, region, 1)
