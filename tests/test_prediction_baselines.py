"""The predictors that need no model (superex_deploy.onboard.prediction.baselines, and the simulator's oracle): what
they fill unknown cells with, and the maps they refuse."""

import numpy as np
import pytest

from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.oracle import OraclePredictor
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.maps import OccupancyGrid


def test_observed_as_prediction_treats_unknown_as_free():
    observed = np.array([[UNKNOWN, FREE], [OCCUPIED, UNKNOWN]], np.int8)
    prediction = ObservedAsPrediction().predict(observed)
    np.testing.assert_array_equal(prediction.mean, [[0, 0], [1, 0]])
    assert prediction.mean.dtype == np.float32 and not prediction.variance.any()


def test_oracle_fills_unknown_with_ground_truth():
    walls = np.array([[True, False, True], [False, False, True]])
    grid = OccupancyGrid(walls, ~walls, 0.1, "t")
    observed = np.full(walls.shape, UNKNOWN, np.int8)
    observed[0, 0] = OCCUPIED
    observed[1, 1] = FREE
    prediction = OraclePredictor(grid).predict(observed)
    np.testing.assert_array_equal(prediction.mean, walls.astype(np.float32))
    assert prediction.variance.shape == walls.shape and not prediction.variance.any()


def test_bad_observed_maps_are_rejected():
    with pytest.raises(ValueError, match="int8"):
        ObservedAsPrediction().predict(np.zeros((2, 2), np.float32))
    with pytest.raises(ValueError, match="only -1"):
        ObservedAsPrediction().predict(np.full((2, 2), 3, np.int8))
    grid = OccupancyGrid(np.zeros((2, 2), bool), np.ones((2, 2), bool), 0.1, "t")
    with pytest.raises(ValueError, match="shape"):
        OraclePredictor(grid).predict(np.zeros((3, 2), np.int8))
