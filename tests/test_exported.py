"""The committed models in exported/: torch vs ONNX Runtime parity, manifest and metadata, the ONNX Runtime
predictors, and the errors for missing, corrupt or mismatched models."""

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from superex_deploy.onboard.prediction.inference import (DEFAULT_MODEL_DIR, MODEL_CHANNELS, LamaEnsemble, ModelKind, Pix2PixFilter,
                                      SessionConfig, encode_map, make_session, read_manifest, sha256_file)
from superex_train.training import build_generator, load_checkpoint

torch.set_num_threads(2)

MANIFEST = read_manifest(DEFAULT_MODEL_DIR)
ENTRIES = {entry.path.stem: entry for entry in MANIFEST}
ATOL, RTOL = 1e-4, 0.0


def _torch_model(stem: str) -> tuple[torch.nn.Module, dict]:
    checkpoint = load_checkpoint(DEFAULT_MODEL_DIR / "checkpoints" / f"{stem}.pt")
    config = dict(checkpoint["model_config"])
    if checkpoint["kind"] is not ModelKind.PIX2PIX:
        config["spectral"] = "matmul"
    generator = build_generator(checkpoint["kind"], config)
    generator.load_state_dict(checkpoint["state"]["generator"])
    return generator.eval(), checkpoint


def _realistic_input(kind: ModelKind, rows: int, cols: int, seed: int) -> np.ndarray:
    """Pix2Pix: [2, 1, 160, 160] back-projection-like windows in [-1, 1]; LaMa: a partly observed random plan."""
    rng = np.random.default_rng(seed)
    if kind is ModelKind.PIX2PIX:
        bp = rng.random((2, rows, cols)) ** 6  # mostly dark, a few bright arcs, like a normalised back-projection
        return (2.0 * bp - 1.0)[:, None].astype(np.float32)
    walls = np.zeros((rows, cols), bool)
    walls[::16, :] = walls[:, ::24] = True
    observed = np.full((rows, cols), UNKNOWN, np.int8)
    seen = np.hypot(*np.meshgrid(np.arange(rows) - rows / 2, np.arange(cols) - cols / 3, indexing="ij")) < rows / 3
    observed[seen] = np.where(walls[seen], OCCUPIED, FREE)
    evidence = (rng.random((rows, cols)) * (~seen)).astype(np.float32)
    return encode_map(observed, evidence if kind is ModelKind.LAMA_BP else None, kind)


def test_manifest_lists_every_model_once_with_matching_files():
    kinds = sorted((e.kind.value, e.member) for e in MANIFEST)
    assert kinds == [("lama_bp", 0), ("lama_bp", 1), ("lama_bp", 2), ("lama_los", 0), ("lama_los", 1),
                     ("lama_los", 2), ("pix2pix", 0)]
    for entry in MANIFEST:
        assert sha256_file(entry.path) == entry.sha256
    total = sum(entry.path.stat().st_size for entry in MANIFEST)
    assert total < 20e6


@pytest.mark.slow
@pytest.mark.parametrize("stem", sorted(ENTRIES))
def test_torch_and_onnx_runtime_agree(stem):
    entry = ENTRIES[stem]
    generator, checkpoint = _torch_model(stem)
    session = make_session(entry.path, SessionConfig())
    input_name, output_name = session.get_inputs()[0].name, session.get_outputs()[0].name
    metadata = session.get_modelmeta().custom_metadata_map
    scale, offset = float(metadata["logit_scale"]), float(metadata["logit_offset"])  # Platt calibration
    sizes = [(160, 160)] if entry.kind is ModelKind.PIX2PIX else [(64, 96), (120, 48)]  # LaMa: dynamic H, W
    for seed, (rows, cols) in enumerate(sizes):
        x = _realistic_input(entry.kind, rows, cols, seed)
        with torch.no_grad():
            expected = torch.sigmoid(generator(torch.from_numpy(x)) * scale + offset).numpy()
        got = session.run([output_name], {input_name: x})[0]
        assert got.shape == expected.shape == (x.shape[0], 1, rows, cols)
        np.testing.assert_allclose(got, expected, atol=ATOL, rtol=RTOL)
        assert 0.01 < float(expected.std())  # a trained model's output varies; parity on a constant proves little


@pytest.mark.parametrize("stem", sorted(ENTRIES))
def test_export_reference_still_reproduces(stem):
    entry = ENTRIES[stem]
    record = next(m for m in json.loads((DEFAULT_MODEL_DIR / "manifest.json").read_text())["models"]
                  if m["file"] == entry.path.name)
    reference = np.load(DEFAULT_MODEL_DIR / record["reference"])
    assert sha256_file(DEFAULT_MODEL_DIR / record["reference"]) == record["reference_sha256"]
    session = make_session(entry.path)
    names = sorted(k for k in reference.files if k.startswith("input_"))
    assert names
    for name in names:
        got = session.run(None, {session.get_inputs()[0].name: reference[name]})[0]
        np.testing.assert_allclose(got, reference[name.replace("input", "output")], atol=ATOL, rtol=RTOL)


@pytest.mark.parametrize("stem", sorted(ENTRIES))
def test_metadata_describes_the_model(stem):
    entry = ENTRIES[stem]
    metadata = {p.key: p.value for p in onnx.load(str(entry.path)).metadata_props}
    _, checkpoint = _torch_model(stem)
    assert metadata["model_kind"] == entry.kind.value
    assert json.loads(metadata["channels"]) == list(MODEL_CHANNELS[entry.kind])
    assert float(metadata["resolution_m"]) == 0.1
    assert int(metadata["ensemble_member"]) == entry.member == checkpoint["member"]
    assert metadata["training_data_sha256"] == checkpoint["training_data_sha256"]
    assert json.loads(metadata["architecture"]) == {**checkpoint["model_config"], **(
        {"spectral": "matmul"} if entry.kind is not ModelKind.PIX2PIX else {})}
    model = onnx.load(str(entry.path))
    assert model.opset_import[0].version == 18
    dims = model.graph.input[0].type.tensor_type.shape.dim
    calibration = float(metadata["logit_scale"]), float(metadata["logit_offset"])
    if entry.kind is ModelKind.PIX2PIX:
        assert metadata["window_cells"] == "160" and [d.dim_value for d in dims[2:]] == [160, 160]
        assert calibration == (1.0, 0.0)
    else:
        assert all(d.dim_param for d in dims[2:])  # dynamic height and width
        # The ensembles are Platt-calibrated (the wall-weighted loss biases them towards walls), all members
        # of a kind alike.
        assert calibration != (1.0, 0.0) and calibration[0] > 0 and calibration[1] < 0
        first = {p.key: p.value for p in onnx.load(str(ENTRIES[f"{entry.kind.value}_0"].path)).metadata_props}
        assert calibration == (float(first["logit_scale"]), float(first["logit_offset"]))


def test_lama_ensemble_predicts_mean_and_member_variance():
    rows, cols = 50, 77  # not a multiple of the size multiple: padded and cropped
    encoded = _realistic_input(ModelKind.LAMA_LOS, rows, cols, 3)
    observed = np.where(encoded[0, 1] > 0, UNKNOWN, np.where(encoded[0, 0] > 0, OCCUPIED, FREE)).astype(np.int8)
    for kind in (ModelKind.LAMA_LOS, ModelKind.LAMA_BP):
        ensemble = LamaEnsemble.from_manifest(kind)
        evidence = np.random.default_rng(0).random((rows, cols)).astype(np.float32)
        members = ensemble.predict_members(observed, evidence)
        prediction = ensemble.predict(observed, evidence)
        assert members.shape == (3, rows, cols) and prediction.mean.shape == (rows, cols)
        assert prediction.mean.dtype == prediction.variance.dtype == np.float32
        unknown = observed == UNKNOWN
        np.testing.assert_allclose(prediction.mean[unknown], members.mean(0)[unknown], atol=1e-6)
        np.testing.assert_allclose(prediction.variance[unknown], members.var(0)[unknown], atol=1e-6)
        assert np.all(prediction.variance[~unknown] == 0.0)
        assert np.array_equal(prediction.mean[~unknown], (observed[~unknown] == OCCUPIED).astype(np.float32))
        assert prediction.variance[unknown].max() > 0.0 and prediction.variance.max() <= 0.25


def test_fewer_members():
    rows, cols = 50, 77
    encoded = _realistic_input(ModelKind.LAMA_LOS, rows, cols, 3)
    observed = np.where(encoded[0, 1] > 0, UNKNOWN, np.where(encoded[0, 0] > 0, OCCUPIED, FREE)).astype(np.int8)
    ensemble = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS)
    members = ensemble.predict_members(observed)
    unknown = observed == UNKNOWN
    disagreement = float(np.abs(members[0] - members[1])[unknown].mean())
    assert 0.0 < disagreement < 0.5

    one = ensemble.with_members(max_members=1)
    prediction = one.predict(observed)
    assert one.members_run == 1 and ensemble.members_run == 3 and ensemble.max_members is None
    np.testing.assert_allclose(prediction.mean[unknown], members[0][unknown], atol=1e-6)
    assert np.all(prediction.variance == 0.0)
    two = ensemble.with_members(max_members=2)
    np.testing.assert_allclose(two.predict(observed).variance[unknown], members[:2].var(0)[unknown], atol=1e-6)

    with pytest.raises(ValueError, match=r"max_members must be an integer in 1..3 or None, got 4"):
        ensemble.with_members(max_members=4)


def test_pix2pix_filter_pastes_its_window_around_the_robot():
    p2p = Pix2PixFilter.from_manifest()
    size = p2p.window_cells
    rng = np.random.default_rng(1)
    bp = (rng.random((300, 260)) ** 6).astype(np.float32)
    pose = (40, 200)  # the window crosses the map's top and right edges
    out = p2p.filter_map(bp, pose)
    r0, c0 = pose[0] - size // 2, pose[1] - size // 2
    inside = np.zeros(bp.shape, bool)
    inside[max(r0, 0):r0 + size, max(c0, 0):c0 + size] = True
    assert np.all(out[~inside] == 0.0) and out[inside].max() > 0.0
    window = np.zeros((size, size), np.float32)
    window[-r0:, :bp.shape[1] - c0] = bp[0:r0 + size, c0:]
    np.testing.assert_allclose(out[inside].reshape(r0 + size, bp.shape[1] - c0),
                               p2p.filter_windows(window)[-r0:, :bp.shape[1] - c0], atol=1e-6)
    assert p2p.filter_windows(np.stack([window, window])).shape == (2, size, size)


def _copy_models(tmp_path):
    target = tmp_path / "models"
    shutil.copytree(DEFAULT_MODEL_DIR, target, ignore=shutil.ignore_patterns("checkpoints"))
    return target


def test_missing_corrupt_and_mismatched_models_raise(tmp_path):
    models = _copy_models(tmp_path)
    (models / "lama_los_1.onnx").unlink()
    with pytest.raises(ValueError, match="missing"):
        LamaEnsemble.from_manifest(ModelKind.LAMA_LOS, models)
    data = bytearray((models / "pix2pix.onnx").read_bytes())
    data[len(data) // 2:len(data) // 2 + 64] = bytes(64)
    (models / "pix2pix.onnx").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="sha256"):
        Pix2PixFilter.from_manifest(models)
    (models / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="could not be loaded"):
        Pix2PixFilter(models / "junk.onnx")
    with pytest.raises(ValueError, match="is a lama_bp model, expected pix2pix"):
        Pix2PixFilter(models / "lama_bp_0.onnx")
    with pytest.raises(ValueError, match="no model manifest"):
        read_manifest(tmp_path)
    (models / "manifest.json").write_text("{\"format_version\": \"1\", \"models\": [{\"file\": 3}]}")
    with pytest.raises(ValueError, match="malformed"):
        read_manifest(models)


def test_models_expose_the_training_resolution_the_manifest_and_their_metadata_give(tmp_path):
    committed = Path(__file__).resolve().parents[1] / "exported"  # this checkout's (the installed may be another's)
    assert {entry.resolution_m for entry in read_manifest(committed)} == {0.1}
    assert Pix2PixFilter.from_manifest(committed).resolution_m == 0.1
    assert LamaEnsemble.from_manifest(ModelKind.LAMA_BP, committed).resolution_m == 0.1
    models = tmp_path / "models"
    shutil.copytree(committed, models, ignore=shutil.ignore_patterns("checkpoints"))
    manifest = json.loads((models / "manifest.json").read_text())
    for record in manifest["models"]:
        record["resolution_m"] = 0.05 if record["file"] == "lama_los_2.onnx" else record["resolution_m"]
    (models / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="different resolutions"):
        LamaEnsemble.from_manifest(ModelKind.LAMA_LOS, models)
    for record in manifest["models"]:
        record["resolution_m"] = 0.05
    (models / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="trained at 0.1 m/cell, its manifest says 0.05"):
        Pix2PixFilter.from_manifest(models)
    for record in manifest["models"]:
        del record["resolution_m"]  # a manifest written before the field: the file's metadata alone
    (models / "manifest.json").write_text(json.dumps(manifest))
    assert read_manifest(models)[0].resolution_m is None
    assert LamaEnsemble.from_manifest(ModelKind.LAMA_LOS, models).resolution_m == 0.1
    manifest["models"][0]["resolution_m"] = -1
    (models / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="malformed.*resolution_m must be a positive number"):
        read_manifest(models)


def test_session_factory_applies_its_config():
    entry = ENTRIES["pix2pix"]
    quiet = make_session(entry.path, SessionConfig(intra_op_threads=1, allow_spinning=False))
    default = make_session(entry.path)
    left_spinning = make_session(entry.path, SessionConfig(stop_spinning_after_run=False))
    spin, stop = "session.intra_op.allow_spinning", "session.force_spinning_stop"
    assert quiet.get_session_options().get_session_config_entry(spin) == "0"
    assert default.get_session_options().get_session_config_entry(spin) == "1"
    assert default.get_session_options().get_session_config_entry(stop) == "1"
    assert left_spinning.get_session_options().get_session_config_entry(stop) == "0"
    assert quiet.get_session_options().intra_op_num_threads == 1
    with pytest.raises(ValueError, match="thread counts"):
        SessionConfig(intra_op_threads=-1)
    with pytest.raises(ValueError, match="providers"):
        make_session(entry.path, SessionConfig(providers=("NoSuchExecutionProvider",)))


def test_bad_inputs_raise():
    ensemble = LamaEnsemble.from_manifest(ModelKind.LAMA_BP)
    observed = np.full((40, 40), UNKNOWN, np.int8)
    with pytest.raises(ValueError, match="needs the filtered back-projection"):
        ensemble.predict(observed, None)
    with pytest.raises(ValueError, match="float32"):
        ensemble.predict(observed, np.zeros((40, 40)))
    with pytest.raises(ValueError, match="lie in"):
        ensemble.predict(observed, np.full((40, 40), 2.0, np.float32))
    with pytest.raises(ValueError):
        ensemble.predict(observed.astype(np.float32), np.zeros((40, 40), np.float32))
    with pytest.raises(ValueError, match="windows must be"):
        Pix2PixFilter.from_manifest().filter_windows(np.zeros((64, 64), np.float32))


@pytest.mark.slow
def test_inference_runs_with_torch_blocked():
    code = textwrap.dedent("""
        import sys, numpy as np
        class _Block:
            def find_spec(self, name, path=None, target=None):
                if name == "torch" or name.startswith("torch.") or name.startswith("superex_train"):
                    raise ImportError(name + " is blocked")
        sys.meta_path.insert(0, _Block())
        from superex_deploy.onboard.prediction.inference import LamaEnsemble, ModelKind, Pix2PixFilter
        observed = np.full((30, 50), -1, np.int8); observed[10:20, 10:20] = 0
        p = LamaEnsemble.from_manifest(ModelKind.LAMA_LOS).predict(observed)
        assert p.mean.shape == (30, 50) and "torch" not in sys.modules
        Pix2PixFilter.from_manifest()
        print("ok")
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"
