"""Platt calibration of the LaMa ensembles: the fit against known parameters, its errors, the calibration set,
and the export applying it inside the graph."""

import json

import numpy as np
import pytest
import torch

from superex_deploy.onboard.prediction.inference import LamaEnsemble, ModelKind, make_session
from superex_deploy.maps import list_maps, map_building
from superex_train.calibration import (CalibrationConfig, LogitCalibration, calibration_maps,
                                       fit_logit_calibration, read_calibration)
from superex_train.export import export_generator, untrained_generator, write_manifest
from superex_train.generate import heldout_buildings
from superex_train.models import LamaConfig

SMALL_LAMA = LamaConfig(in_channels=2, base_channels=4, n_downsample=2, max_channels=16, n_blocks=1)


def _sigmoid(z):
    return 1.0 / (1.0 + np.exp(-z))


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (0.7, -2.0), (1.8, 0.9)])
def test_fit_recovers_the_parameters_that_generated_the_labels(scale, offset):
    # Labels drawn from sigmoid(scale * z + offset): maximum likelihood must find (scale, offset) back.
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 2.5, 200_000)
    labels = rng.random(z.size) < _sigmoid(scale * z + offset)
    fit = fit_logit_calibration(_sigmoid(z), labels)
    assert abs(fit.logit_scale - scale) < 0.03 and abs(fit.logit_offset - offset) < 0.03
    assert fit.nll_after <= fit.nll_before + 1e-12
    assert fit.cells == z.size and abs(fit.wall_fraction - labels.mean()) < 1e-12


def test_fit_undoes_a_class_weighted_bias():
    # Probabilities biased as a wall-weighted loss biases them (odds x 10) are brought back to the base rate.
    rng = np.random.default_rng(1)
    truth = rng.beta(0.5, 4.0, 100_000)  # true wall probabilities, mean ~0.11
    labels = rng.random(truth.size) < truth
    biased = 10 * truth / (10 * truth + 1 - truth)
    fit = fit_logit_calibration(biased, labels)
    assert fit.predicted_walls_before > 0.3
    assert abs(fit.logit_offset + np.log(10)) < 0.1 and abs(fit.logit_scale - 1) < 0.05
    calibrated = fit.apply(biased)
    assert calibrated.dtype == np.float32
    assert abs(calibrated.mean() - labels.mean()) < 0.01
    np.testing.assert_allclose(LogitCalibration().apply(np.array([0.2, 0.5, 0.9])), [0.2, 0.5, 0.9], atol=1e-6)


def test_fit_and_calibration_inputs_are_checked(tmp_path):
    p = np.array([0.1, 0.9])
    with pytest.raises(ValueError, match="both classes"):
        fit_logit_calibration(p, np.array([True, True]))
    with pytest.raises(ValueError, match="bool"):
        fit_logit_calibration(p, np.array([0, 1]))
    with pytest.raises(ValueError, match="one size"):
        fit_logit_calibration(p, np.array([True]))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        fit_logit_calibration(np.array([0.1, 1.5]), np.array([True, False]))
    with pytest.raises(ValueError, match="logit_scale > 0"):
        LogitCalibration(logit_scale=0.0)
    with pytest.raises(ValueError, match="coverages"):
        CalibrationConfig(coverages=(0.3, 0.1))
    with pytest.raises(ValueError, match="missing"):
        read_calibration(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text(json.dumps({"format": "superex-calibration/1", "ensembles": {"x": {}}}))
    with pytest.raises(ValueError, match="malformed"):
        read_calibration(tmp_path / "bad.json")


def test_calibration_maps_are_training_buildings_only():
    maps = calibration_maps(CalibrationConfig())
    heldout = set(heldout_buildings())
    assert maps and not {map_building(m) for m in maps} & heldout
    assert set(maps) | {m for m in list_maps("train") if map_building(m) in heldout} == set(list_maps("train"))
    for refused in (list_maps("eval")[0], next(m for m in list_maps("train") if map_building(m) in heldout)):
        with pytest.raises(ValueError, match="refused"):
            calibration_maps(CalibrationConfig(maps=(refused,)))


@pytest.mark.slow
def test_export_applies_the_calibration_in_the_graph(tmp_path):
    generator = untrained_generator(ModelKind.LAMA_LOS, SMALL_LAMA, seed=3)
    fit = LogitCalibration(logit_scale=0.6, logit_offset=-1.5)
    plain = export_generator(generator, ModelKind.LAMA_LOS, tmp_path / "plain.onnx")
    calibrated = export_generator(generator, ModelKind.LAMA_LOS, tmp_path / "calibrated.onnx", calibration=fit)
    x = np.random.default_rng(0).random((1, 2, 32, 48)).astype(np.float32)
    outputs = {}
    for record in (plain, calibrated):
        session = make_session(record.path)
        outputs[record.path.stem] = session.run(None, {session.get_inputs()[0].name: x})[0]
        metadata = session.get_modelmeta().custom_metadata_map
        expected = (0.6, -1.5) if record is calibrated else (1.0, 0.0)
        assert (float(metadata["logit_scale"]), float(metadata["logit_offset"])) == expected
    with torch.no_grad():
        logits = generator(torch.from_numpy(x)).numpy().astype(np.float64)
    np.testing.assert_allclose(outputs["plain"], _sigmoid(logits), atol=1e-5, rtol=0)
    np.testing.assert_allclose(outputs["calibrated"], _sigmoid(0.6 * logits - 1.5), atol=1e-5, rtol=0)
    np.testing.assert_allclose(fit.apply(outputs["plain"]), outputs["calibrated"], atol=1e-4, rtol=0)
    assert np.abs(outputs["plain"] - outputs["calibrated"]).max() > 0.05  # the calibration matters here
    write_manifest(tmp_path, [calibrated])
    ensemble = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS, tmp_path)
    observed = np.full((32, 48), -1, np.int8)
    assert ensemble.predict(observed).mean.shape == (32, 48)
