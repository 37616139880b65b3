"""Training-data generation from exploration episodes (superex_train.generate)."""

import shutil

import numpy as np
import pytest

from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR, MODEL_CHANNELS, ModelKind
from superex_deploy.maps import list_maps, load_map, map_building
from superex_train.datasets import ShardDataset
from superex_train.generate import (GenerationConfig, generate_lama, generate_pix2pix, heldout_buildings,
                                    random_start)

SMALL_MAP = "50009418"  # a small train map: episodes stay short


def test_eval_maps_are_refused():
    with pytest.raises(ValueError, match="eval maps"):
        GenerationConfig(maps=(list_maps("eval")[0],))


@pytest.mark.parametrize("field, value", [("steps", 0), ("sample_every", 0), ("jobs", 0), ("planners", ()),
                                          ("planners", ("teleport",)), ("min_clearance_m", -1.0)])
def test_bad_settings_raise(field, value):
    with pytest.raises(ValueError):
        GenerationConfig(maps=(SMALL_MAP,), **{field: value})


def test_heldout_buildings_are_fixed_and_about_a_fifth_of_the_maps():
    held = heldout_buildings()
    assert held == heldout_buildings() and held == tuple(sorted(set(held)))
    train = list_maps("train")
    share = np.mean([map_building(name) in held for name in train])
    assert 0.2 <= share < 0.35
    assert set(held) < {map_building(name) for name in train}
    assert heldout_buildings(seed=1) != held


def test_random_start_is_clear_of_walls():
    grid = load_map(SMALL_MAP)
    rng = np.random.default_rng(0)
    for _ in range(50):
        r, c = random_start(grid, rng, 0.4)
        assert grid.valid[r, c] and not grid.occupied[r, c]
        assert not grid.occupied[max(r - 3, 0):r + 4, max(c - 3, 0):c + 4].any()  # 0.4 m > 3 cells diagonal


@pytest.fixture(scope="module")
def pix2pix_data(tmp_path_factory):
    cfg = GenerationConfig(maps=(SMALL_MAP,), episodes_per_map=2, steps=40, sample_every=10, window_cells=64)
    return generate_pix2pix(tmp_path_factory.mktemp("p2p") / "data", cfg, progress=False), cfg


def test_pix2pix_samples_are_encoded_windows_with_hidden_wall_targets(pix2pix_data):
    info, cfg = pix2pix_data
    data = ShardDataset(info.directory, ModelKind.PIX2PIX)
    assert info.tile_hw == (64, 64) and info.channels == MODEL_CHANNELS[ModelKind.PIX2PIX]
    assert 4 <= len(data) <= 2 * 40 // 10
    assert set(data.groups.tolist()) == {map_building(SMALL_MAP)}
    hidden = 0
    for i in range(len(data)):
        inputs, target, mask = data.arrays(i)
        assert inputs.shape == (1, 64, 64) and -1.0 <= inputs.min() and inputs.max() <= 1.0
        assert not (target & ~mask).any()  # labels only where the loss is defined (unknown cells)
        # Known cells are skipped by the back-projection: the raw input is exactly -1 (zero votes) off the mask.
        assert np.all(inputs[0][~mask] == -1.0)
        hidden += int(target.sum())
    assert hidden > 0


def test_generation_is_deterministic(pix2pix_data, tmp_path):
    info, cfg = pix2pix_data
    again = generate_pix2pix(tmp_path / "again", cfg, progress=False)
    assert again.data_sha256 == info.data_sha256


@pytest.mark.slow
def test_lama_datasets_share_tiles_and_differ_only_by_nlos(tmp_path):
    cfg = GenerationConfig(maps=("0510030965_A-40",), episodes_per_map=1, steps=40, sample_every=10,
                           tile_cells=48, tiles_per_sample=2)
    bp_info, los_info = generate_lama(tmp_path / "bp", tmp_path / "los", None, cfg, progress=False)
    bp, los = ShardDataset(bp_info.directory, ModelKind.LAMA_BP), ShardDataset(los_info.directory, ModelKind.LAMA_LOS)
    assert len(bp) == len(los) >= 2
    grid = load_map("0510030965_A-40")
    wall_share = grid.occupied.mean()
    carved_any = False
    for i in range(len(bp)):
        (x_bp, y_bp, m_bp), (x_los, y_los, m_los) = bp.arrays(i), los.arrays(i)
        assert np.array_equal(y_bp, y_los) and np.array_equal(m_bp, m_los)
        wall, evidence, unknown = x_bp
        los_wall, los_unknown = x_los
        # Carving only turns unknown cells free: same walls, unknown cells a subset of the LOS ones.
        assert np.array_equal(wall, los_wall)
        assert np.all(unknown <= los_unknown)
        carved_any |= bool((unknown < los_unknown).any())
        assert 0.0 <= evidence.min() and evidence.max() <= 1.0
        assert np.all(wall[wall > 0] <= y_bp[wall > 0])  # observed walls are true walls
    assert carved_any
    assert 0 < np.mean([bp.arrays(i)[1].mean() for i in range(len(bp))]) < 5 * wall_share + 0.2


@pytest.mark.slow
def test_lama_data_hash_does_not_depend_on_where_the_filter_lies(tmp_path):
    cfg = GenerationConfig(maps=(SMALL_MAP,), episodes_per_map=1, steps=20, sample_every=10, tile_cells=32)
    hashes = []
    for folder in ("checkout_a", "elsewhere/checkout_b"):
        model = tmp_path / folder / "pix2pix.onnx"
        model.parent.mkdir(parents=True)
        shutil.copy(DEFAULT_MODEL_DIR / "pix2pix.onnx", model)
        infos = generate_lama(tmp_path / folder / "bp", tmp_path / folder / "los", model, cfg, progress=False)
        hashes.append([info.data_sha256 for info in infos])
    assert hashes[0] == hashes[1]


def test_lama_generation_checks_the_filter_model(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        generate_lama(tmp_path / "bp", tmp_path / "los", tmp_path / "nope.onnx",
                      GenerationConfig(maps=(SMALL_MAP,), steps=5))


def test_the_ceiling_study_uses_the_held_out_buildings_of_the_training_split():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "ceiling_study.py"
    spec = importlib.util.spec_from_file_location("ceiling_study", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.HELDOUT_BUILDINGS == heldout_buildings()
    places = module.scenarios(2, 1, 40000, heldout=True)
    assert len(places) == 2 and all(map_building(name) in heldout_buildings() for name, _ in places)
