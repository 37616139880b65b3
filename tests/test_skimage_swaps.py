"""The functions that now call scikit-image give what the code before them gave (``tests/naive.py``), to the bit:
``pool_observed`` and ``pool_prediction`` (``skimage.measure.block_reduce``). What scikit-image was measured
against and did not replace: ``benchmarks/skimage/``."""

import numpy as np
import pytest

from superex_deploy.onboard.prediction.scale import pool_observed, pool_prediction
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Prediction
from tests.naive import naive_pool_observed, naive_pool_prediction


def _random_observed(rng, shape, weights):
    return rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.int8), size=shape, p=weights)


def test_pool_observed_equals_the_reshape_rule_on_random_maps():
    rng = np.random.default_rng(0)
    for _ in range(200):
        shape = tuple(int(v) for v in rng.integers(1, 40, size=2))
        # Sparse walls or sparse knowledge as well as even mixtures: blocks of one class are the common case.
        weights = [(1 / 3, 1 / 3, 1 / 3), (0.8, 0.15, 0.05), (0.05, 0.9, 0.05), (0.0, 0.0, 1.0)][rng.integers(4)]
        observed = _random_observed(rng, shape, weights)
        k = int(rng.integers(1, 6))
        pooled = pool_observed(observed, k)
        assert pooled.dtype == np.int8 and pooled.shape == (-(-shape[0] // k), -(-shape[1] // k))
        np.testing.assert_array_equal(pooled, naive_pool_observed(observed, k))


@pytest.mark.parametrize("shape, k", [((1, 1), 1), ((1, 1), 4), ((1, 7), 2), ((7, 1), 3), ((4, 4), 4), ((5, 5), 4),
                                      ((3, 9), 9)])
def test_pool_observed_equals_the_reshape_rule_at_the_edges(shape, k):
    """Maps thinner than a block, one block, a block cut by both edges: cells past the edge count as unknown."""
    for fill in (UNKNOWN, FREE, OCCUPIED):
        observed = np.full(shape, fill, np.int8)
        np.testing.assert_array_equal(pool_observed(observed, k), naive_pool_observed(observed, k))
    observed = np.full(shape, UNKNOWN, np.int8)
    observed[-1, -1] = FREE  # the last cell alone decides the last block
    pooled = pool_observed(observed, k)
    np.testing.assert_array_equal(pooled, naive_pool_observed(observed, k))
    assert pooled[-1, -1] == FREE and (pooled == FREE).sum() == 1


def test_pool_prediction_equals_the_reshape_rule_on_random_maps():
    rng = np.random.default_rng(1)
    for _ in range(100):
        u = int(rng.integers(1, 4))
        rows, cols = (int(v) for v in rng.integers(1, 30, size=2))
        mean = rng.random((rows * u, cols * u)).astype(np.float32)
        if rng.random() < 0.3:  # observed cells: exact 0 / 1 with no variance
            mean = np.round(mean)
        variance = (0.25 * rng.random(mean.shape)).astype(np.float32)
        pooled = pool_prediction(Prediction(mean=mean, variance=variance), u, (rows, cols))
        expected_mean, expected_variance = naive_pool_prediction(mean, variance, u)
        assert pooled.mean.dtype == np.float32 and pooled.variance.dtype == np.float32
        np.testing.assert_array_equal(pooled.mean, expected_mean)
        np.testing.assert_array_equal(pooled.variance, expected_variance)


def test_pool_prediction_still_takes_whole_blocks_only():
    """block_reduce would pad a cut block; the function refuses it as before."""
    blank = np.zeros((5, 4), np.float32)
    with pytest.raises(ValueError, match="blocks"):
        pool_prediction(Prediction(mean=blank, variance=blank), 2, (2, 2))


def test_importing_the_explorer_does_not_load_scikit_image():
    """The CLI's start pays nothing for scikit-image: the swapped functions import it when first called (a model
    on another grid than its own), not at import."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    code = ("import sys, superex_deploy.onboard.explorer\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'skimage'))\n")
    env = dict(os.environ, PYTHONPATH=str(root))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[]"
