"""Networks, Fourier units, losses, the shard format and the training loops (torch, CPU, small sizes)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from superex_deploy.onboard.prediction.inference import MODEL_CHANNELS, ModelKind, encode_map, sha256_file
from superex_train.datasets import (ShardDataset, ShardWriter, read_index, split_by_group, synthetic_walls,
                                    write_synthetic_dataset)
from superex_train.losses import soft_dice_loss, wall_weighted_bce, wall_weighted_l1, wall_weights
from superex_train.models import (FourierUnit, LamaConfig, LamaGenerator, PatchDiscriminator, Pix2PixConfig,
                                  SpectralBackend, UNetGenerator, calibrate_batchnorm, count_parameters,
                                  dft_basis, irfft2_ortho, rfft2_ortho)
from superex_train.training import (LamaTrainConfig, Pix2PixTrainConfig, epoch_learning_rate,
                                    initialise_lama_from, load_checkpoint, train_lama, train_pix2pix)

torch.set_num_threads(2)

SMALL_LAMA = dict(base_channels=4, n_downsample=2, max_channels=16, n_blocks=1)
SMALL_PIX2PIX = Pix2PixConfig(window_cells=32, channels=(4, 8, 8), discriminator_channels=4)


# --- shapes and configuration ---------------------------------------------------------------------------------

def test_pix2pix_shapes_and_default_size():
    generator, discriminator = UNetGenerator(), PatchDiscriminator()
    x = torch.rand(2, 1, 160, 160) * 2 - 1
    assert generator(x).shape == (2, 1, 160, 160)
    assert discriminator(x, x).shape == (2, 1, 18, 18)  # S / 8 - 2
    assert 500_000 < count_parameters(generator) < 1_000_000  # ~2.9 MB of float32


@pytest.mark.parametrize("in_channels", [3, 2])
@pytest.mark.parametrize("rows, cols", [(32, 48), (40, 24), (16, 16)])
def test_lama_shapes_for_non_square_sizes(in_channels, rows, cols):
    generator = LamaGenerator(LamaConfig(in_channels=in_channels)).eval()
    assert generator(torch.rand(1, in_channels, rows, cols)).shape == (1, 1, rows, cols)


def test_lama_default_size_fits_the_budget():
    params = count_parameters(LamaGenerator(LamaConfig()))
    assert 400_000 < params < 800_000  # six members (two ensembles) plus Pix2Pix stay under 20 MB


@pytest.mark.parametrize("make, message", [
    (lambda: Pix2PixConfig(window_cells=100), "multiple of 32"),
    (lambda: Pix2PixConfig(channels=(8,)), "at least 2"),
    (lambda: LamaConfig(global_ratio=1.0), "global_ratio"),
    (lambda: LamaConfig(n_blocks=0), "n_blocks"),
    (lambda: LamaConfig(base_channels=1, max_channels=1), "room for both"),
])
def test_bad_configs_raise(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_configs_round_trip_through_dicts():
    cfg = LamaConfig(in_channels=2, n_blocks=3, spectral=SpectralBackend.TORCH_FFT)
    assert LamaConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    assert Pix2PixConfig.from_dict(json.loads(json.dumps(SMALL_PIX2PIX.to_dict()))) == SMALL_PIX2PIX


# --- Fourier unit as matrix products -------------------------------------------------------------------------

@pytest.mark.parametrize("rows, cols", [(8, 8), (7, 9), (16, 1), (1, 12), (56, 166), (31, 64)])
def test_matmul_rfft2_equals_torch_fft(rows, cols):
    x = torch.randn(2, 3, rows, cols, generator=torch.Generator().manual_seed(rows * cols))
    real, imag = rfft2_ortho(x)
    reference = torch.fft.rfft2(x, norm="ortho")
    torch.testing.assert_close(real, reference.real, atol=1e-5, rtol=0)
    torch.testing.assert_close(imag, reference.imag, atol=1e-5, rtol=0)
    spectrum = torch.complex(torch.randn_like(real), torch.randn_like(imag))
    torch.testing.assert_close(irfft2_ortho(spectrum.real, spectrum.imag, cols),
                               torch.fft.irfft2(spectrum, s=(rows, cols), norm="ortho"), atol=1e-5, rtol=0)
    torch.testing.assert_close(irfft2_ortho(real, imag, cols, dft_basis(rows, cols, x)), x, atol=1e-5, rtol=0)


def test_dft_angles_stay_accurate_for_long_axes():
    """Angles reduced modulo N before the float conversion: a pure tone of frequency k lands in bin k only."""
    n, k = 1328, 611
    tone = np.cos(2 * np.pi * ((k * np.arange(n)) % n) / n)  # exact in float64
    real, imag = rfft2_ortho(torch.from_numpy(tone).float()[None, :])
    expected = np.zeros(n // 2 + 1)
    expected[k] = np.sqrt(n) / 2
    # Angles 2 pi k n / N formed in float32 without the reduction leak ~1e-3 into the neighbouring bins.
    np.testing.assert_allclose(real[0].numpy(), expected, atol=2e-5)
    np.testing.assert_allclose(imag[0].numpy(), 0.0, atol=2e-5)


def test_fourier_unit_and_generator_backends_agree():
    torch.manual_seed(0)
    matmul = FourierUnit(6, 6, SpectralBackend.MATMUL)
    reference = FourierUnit(6, 6, SpectralBackend.TORCH_FFT)
    reference.load_state_dict(matmul.state_dict())
    x = torch.randn(2, 6, 12, 21)
    with torch.no_grad():
        torch.testing.assert_close(matmul.eval()(x), reference.eval()(x), atol=1e-5, rtol=0)
    generator = LamaGenerator(LamaConfig(**SMALL_LAMA))
    twin = LamaGenerator(LamaConfig(**SMALL_LAMA, spectral=SpectralBackend.TORCH_FFT))
    twin.load_state_dict(generator.state_dict())
    x = torch.rand(2, 3, 24, 40)
    calibrate_batchnorm(generator, [x])
    twin.load_state_dict(generator.state_dict())
    with torch.no_grad():
        out = generator(x)
        assert out.std() > 0.05  # calibrated: a varying output, so the comparison means something
        torch.testing.assert_close(out, twin.eval()(x), atol=1e-5, rtol=0)


def test_global_branch_sees_the_whole_map():
    """One FFC block: a change in one corner alters the output in the opposite corner (the local 3x3 paths
    alone could not reach it)."""
    torch.manual_seed(1)
    generator = LamaGenerator(LamaConfig(**SMALL_LAMA))
    x = torch.zeros(1, 3, 64, 64)
    calibrate_batchnorm(generator, [torch.rand(2, 3, 64, 64)])
    y = x.clone()
    y[0, 0, :4, :4] = 1.0
    with torch.no_grad():
        change = (generator(y) - generator(x))[0, 0, -8:, -8:].abs().max()
    assert change > 1e-4


# --- losses ----------------------------------------------------------------------------------------------------

def _grad(loss_fn, value, target, **kwargs):
    prediction = torch.full_like(target, value, requires_grad=True)
    loss_fn(prediction, target, **kwargs).backward()
    return prediction.grad


def test_wall_weight_scales_the_gradient_at_walls():
    target = torch.zeros(1, 1, 10, 10)
    target[0, 0, 4, :] = 1.0  # 10 % walls
    for weight in (1.0, 9.0, 50.0):
        grad = _grad(wall_weighted_l1, 0.5, target, wall_weight=weight)
        wall, free = grad[target > 0.5], grad[target < 0.5]
        assert torch.allclose(wall, wall[0]) and torch.allclose(free, free[0])
        # L1 at p = 0.5: walls pull up, free cells push down, walls w times as hard.
        assert wall[0] < 0 < free[0]
        assert torch.isclose(-wall[0] / free[0], torch.tensor(weight))
        # BCE at logit 0: d/dz = sigmoid(z) - y = -+0.5, again w times as hard at walls.
        grad = _grad(wall_weighted_bce, 0.0, target, wall_weight=weight)
        assert torch.isclose(-grad[target > 0.5][0] / grad[target < 0.5][0], torch.tensor(weight))


def test_unweighted_l1_pulls_towards_blank_and_balancing_stops_it():
    target = torch.zeros(1, 1, 20, 20)
    target[0, 0, 3, 5:9] = 1.0  # 1 % walls
    n_wall = int(target.sum())
    # The summed gradient on a uniform prediction: > 0 means gradient descent lowers every cell (blank map).
    assert _grad(wall_weighted_l1, 0.5, target, wall_weight=1.0).sum() > 0
    balanced = (target.numel() - n_wall) / n_wall
    assert abs(float(_grad(wall_weighted_l1, 0.5, target, wall_weight=balanced).sum())) < 1e-6
    assert _grad(wall_weighted_l1, 0.5, target, wall_weight=2 * balanced).sum() < 0


def test_mask_removes_cells_from_the_loss_and_focal_down_weights_easy_cells():
    target = torch.zeros(1, 1, 4, 4)
    target[0, 0, 0, 0] = 1.0
    mask = torch.ones_like(target)
    mask[0, 0, 3, :] = 0.0
    grad = _grad(wall_weighted_l1, 0.3, target, wall_weight=2.0, mask=mask)
    assert (grad[0, 0, 3] == 0).all() and (grad[0, 0, :3] != 0).all()
    logits = torch.tensor([[[[4.0, -4.0]]]])  # an easy wall, a badly wrong free cell
    labels = torch.tensor([[[[1.0, 1.0]]]])
    plain = wall_weighted_bce(logits, labels, 1.0)
    focal = wall_weighted_bce(logits, labels, 1.0, focal_gamma=2.0)
    assert focal < plain
    easy_share = lambda gamma: float(wall_weighted_bce(logits[..., :1], labels[..., :1], 1.0, gamma)  # noqa: E731
                                     / wall_weighted_bce(logits[..., 1:], labels[..., 1:], 1.0, gamma))
    assert easy_share(2.0) < easy_share(0.0) / 100


def test_soft_dice_is_one_minus_the_pooled_dice():
    target = torch.zeros(2, 1, 3, 3)
    target[0, 0, 0, :2] = 1.0  # two walls in the first window, none in the second
    assert float(soft_dice_loss(target, target, smooth=1e-9)) == pytest.approx(0.0, abs=1e-6)
    assert float(soft_dice_loss(1.0 - target, target, smooth=1e-9)) == pytest.approx(1.0, abs=1e-6)
    probability = torch.full_like(target, 0.25)
    # Pooled over the batch: 2 * (0.25 * 2) / (0.25 * 18 + 2)
    expected = 1.0 - (2 * 0.5 + 1.0) / (4.5 + 2.0 + 1.0)
    assert float(soft_dice_loss(probability, target)) == pytest.approx(expected)
    mask = torch.ones_like(target)
    mask[1] = 0.0  # the empty window no longer counts
    assert float(soft_dice_loss(probability, target, mask)) == pytest.approx(1.0 - (2 * 0.5 + 1.0) / (2.25 + 2 + 1))
    # Its gradient raises the walls' probability and lowers the rest.
    grad = _grad(lambda p, y: soft_dice_loss(p, y), 0.25, target)
    assert (grad[target > 0.5] < 0).all() and (grad[target < 0.5] > 0).all()


def test_loss_inputs_are_checked():
    with pytest.raises(ValueError, match="wall_weight"):
        wall_weights(torch.zeros(1, 1, 2, 2), 0.0)
    with pytest.raises(ValueError, match="shape"):
        wall_weighted_l1(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 3), 1.0)
    with pytest.raises(ValueError, match="focal_gamma"):
        wall_weighted_bce(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 2), 1.0, focal_gamma=-1.0)
    with pytest.raises(ValueError, match="shape"):
        soft_dice_loss(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 2), torch.ones(1, 1, 2, 3))
    with pytest.raises(ValueError, match="smooth"):
        soft_dice_loss(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 2), smooth=0.0)


# --- shard format -----------------------------------------------------------------------------------------------

def test_shards_round_trip_exactly(tmp_path):
    rng = np.random.default_rng(0)
    samples = []
    with ShardWriter(tmp_path / "d", ModelKind.LAMA_LOS, (8, 12), shard_size=3, generator={"test": 1}) as writer:
        for i in range(7):
            inputs = (rng.random((2, 8, 12)) < 0.5).astype(np.float32)
            target, mask = rng.random((8, 12)) < 0.2, rng.random((8, 12)) < 0.9
            writer.add(inputs, target, mask, group=i // 2)
            samples.append((inputs, target, mask))
    info = read_index(tmp_path / "d")
    assert info.count == 7 and [n for _, n in info.shards] == [3, 3, 1] and info.generator == {"test": 1}
    dataset = ShardDataset(tmp_path / "d", ModelKind.LAMA_LOS, verify=True)
    assert len(dataset) == 7 and dataset.groups.tolist() == [0, 0, 1, 1, 2, 2, 3]
    for i, (inputs, target, mask) in enumerate(samples):
        got = dataset.arrays(i)
        np.testing.assert_array_equal(got[0], inputs)
        np.testing.assert_array_equal(got[1], target)
        np.testing.assert_array_equal(got[2], mask)
    x, y, m = dataset[6]
    assert x.dtype == torch.float32 and x.shape == (2, 8, 12) and y.shape == m.shape == (1, 8, 12)
    with pytest.raises(IndexError):
        dataset.arrays(7)


def test_shard_errors(tmp_path):
    with pytest.raises(ValueError, match="no dataset"):
        ShardDataset(tmp_path)
    writer = ShardWriter(tmp_path / "d", ModelKind.PIX2PIX, (4, 4))
    with pytest.raises(ValueError, match="float32"):
        writer.add(np.zeros((1, 4, 5), np.float32), np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="target must be bool"):
        writer.add(np.zeros((1, 4, 4), np.float32), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="no samples"):
        writer.close()
    writer.add(np.zeros((1, 4, 4), np.float32), np.zeros((4, 4), bool))
    info = writer.close()
    with pytest.raises(ValueError, match="already holds"):
        ShardWriter(tmp_path / "d", ModelKind.PIX2PIX, (4, 4))
    with pytest.raises(ValueError, match="holds pix2pix data"):
        ShardDataset(tmp_path / "d", ModelKind.LAMA_BP)
    targets = tmp_path / "d" / "shard_00000.targets.npy"
    np.save(targets, np.ones((1, 4, 4), np.uint8))
    with pytest.raises(ValueError, match="sha256"):
        ShardDataset(tmp_path / "d", verify=True)
    assert read_index(tmp_path / "d").data_sha256 == info.data_sha256  # the index itself is unchanged


def test_split_by_group_keeps_buildings_together():
    groups = np.repeat(np.arange(10), np.arange(1, 11))
    for seed in range(5):
        train, val = split_by_group(groups, 0.2, seed)
        assert len(train) + len(val) == len(groups) and len(val) > 0
        assert not set(groups[train]) & set(groups[val])
    assert len(split_by_group(groups, 0.0, 0)[1]) == 0


def test_synthetic_plans_are_closed_and_datasets_are_encoded(tmp_path):
    for seed in range(50):
        walls = synthetic_walls(np.random.default_rng(seed), (40, 64), (8, 20))
        assert walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()
        assert 0.05 < walls.mean() < 0.5
    info = write_synthetic_dataset(tmp_path / "bp", ModelKind.LAMA_BP, 4, 32, seed=3)
    inputs, target, _ = ShardDataset(info.directory).arrays(0)
    wall, evidence, unknown = inputs
    assert set(np.unique(wall)) <= {0.0, 1.0} and set(np.unique(unknown)) <= {0.0, 1.0}
    assert (wall[unknown == 1] == 0).all() and (target[wall == 1]).all()
    assert 0.0 <= evidence.min() and evidence.max() <= 1.0
    assert MODEL_CHANNELS[info.kind] == info.channels


# --- training loops ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def synthetic_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    return {kind: write_synthetic_dataset(root / kind.value, kind, 48, 32, seed=0).directory for kind in ModelKind}


@pytest.mark.slow
def test_lama_training_learns_and_resumes_exactly(synthetic_data, tmp_path):
    base = dict(data_dir=str(synthetic_data[ModelKind.LAMA_BP]), model=LamaConfig(**SMALL_LAMA), batch_size=8,
                lr=3e-3, progress=False)
    result = train_lama(LamaTrainConfig(out_dir=str(tmp_path / "straight"), epochs=4, **base))
    losses = [r["train_loss"] for r in result.history]
    assert losses[-1] < 0.8 * losses[0]
    assert {"val_loss", "val_wall_iou", "seconds"} <= set(result.history[-1])
    train_lama(LamaTrainConfig(out_dir=str(tmp_path / "resumed"), epochs=2, **base))
    resumed = train_lama(LamaTrainConfig(out_dir=str(tmp_path / "resumed"), epochs=4, **base))
    assert [r["epoch"] for r in resumed.history] == [0, 1, 2, 3]
    straight, again = load_checkpoint(result.checkpoint), load_checkpoint(resumed.checkpoint)
    for name, tensor in straight["state"]["generator"].items():
        torch.testing.assert_close(again["state"]["generator"][name], tensor, atol=0, rtol=0)
    with pytest.raises(ValueError, match="other settings"):
        train_lama(LamaTrainConfig(out_dir=str(tmp_path / "resumed"), epochs=5, wall_weight=3.0, **base))


def _lama_checkpoint(synthetic_data, tmp_path, kind: ModelKind, model: LamaConfig):
    cfg = LamaTrainConfig(data_dir=str(synthetic_data[kind]), out_dir=str(tmp_path / kind.value), kind=kind,
                          model=model, epochs=1, batch_size=8, max_batches=2, progress=False)
    return train_lama(cfg).checkpoint


def test_bp_member_started_from_los_first_predicts_what_los_does(synthetic_data, tmp_path):
    los_model = LamaConfig(in_channels=2, **SMALL_LAMA)
    los_path = _lama_checkpoint(synthetic_data, tmp_path, ModelKind.LAMA_LOS, los_model)
    los = LamaGenerator(los_model)
    los.load_state_dict(load_checkpoint(los_path)["state"]["generator"])
    bp = LamaGenerator(LamaConfig(in_channels=3, **SMALL_LAMA))
    initialise_lama_from(bp, ModelKind.LAMA_BP, los_path)
    los.eval(), bp.eval()
    generator = torch.Generator().manual_seed(0)
    observed, unknown = (torch.rand(2, 2, 32, 48, generator=generator) > 0.7).float().unbind(1)
    evidence = torch.rand(2, 1, 32, 48, generator=generator)
    with torch.no_grad():
        expected = los(torch.stack([observed, unknown], 1))
        got = bp(torch.cat([observed[:, None], evidence, unknown[:, None]], 1))
    torch.testing.assert_close(got, expected, atol=1e-6, rtol=1e-6)
    assert float(expected.std()) > 0  # a constant output would make the comparison empty

    # through the training loop: '{member}' resolves, epoch -1 records the starting point, the source is hashed
    shutil.copy(los_path, tmp_path / "los_member_0.pt")
    cfg = LamaTrainConfig(data_dir=str(synthetic_data[ModelKind.LAMA_BP]), out_dir=str(tmp_path / "fine"),
                          model=LamaConfig(**SMALL_LAMA), epochs=2, batch_size=8, lr_schedule="cosine",
                          init_from=str(tmp_path / "los_member_{member}.pt"), progress=False)
    history = train_lama(cfg).history
    assert [r["epoch"] for r in history] == [-1, 0, 1]
    assert [r["lr"] for r in history[1:]] == [pytest.approx(cfg.lr), pytest.approx(cfg.lr / 2)]
    assert load_checkpoint(tmp_path / "fine")["extra"]["init_sha256"] == sha256_file(los_path)


def test_member_placeholder_and_bad_starting_points(synthetic_data, tmp_path):
    bp_model = LamaConfig(in_channels=3, **SMALL_LAMA)
    bp_path = _lama_checkpoint(synthetic_data, tmp_path, ModelKind.LAMA_BP, bp_model)
    cfg = LamaTrainConfig(data_dir="d", out_dir="o", model=bp_model, member=2, init_from="runs/m{member}/c.pt")
    assert cfg.init_checkpoint == Path("runs/m2/c.pt")
    assert LamaTrainConfig(data_dir="d", out_dir="o").init_checkpoint is None
    with pytest.raises(ValueError, match="evidence"):  # LOS would silently drop the evidence channel
        initialise_lama_from(LamaGenerator(LamaConfig(in_channels=2, **SMALL_LAMA)), ModelKind.LAMA_LOS, bp_path)
    with pytest.raises(ValueError, match="another architecture"):
        initialise_lama_from(LamaGenerator(LamaConfig(in_channels=3, **dict(SMALL_LAMA, n_blocks=2))),
                             ModelKind.LAMA_BP, bp_path)
    with pytest.raises(ValueError, match="no checkpoint"):
        initialise_lama_from(LamaGenerator(bp_model), ModelKind.LAMA_BP, tmp_path / "missing.pt")
    pix2pix = Pix2PixTrainConfig(data_dir=str(synthetic_data[ModelKind.PIX2PIX]), out_dir=str(tmp_path / "p2p"),
                                 epochs=1, model=SMALL_PIX2PIX, batch_size=8, max_batches=1, progress=False)
    with pytest.raises(ValueError, match="starts only from a LaMa"):
        initialise_lama_from(LamaGenerator(bp_model), ModelKind.LAMA_BP, train_pix2pix(pix2pix).checkpoint)


def test_learning_rate_schedules():
    assert [epoch_learning_rate(1e-3, "constant", e, 4) for e in range(4)] == [1e-3] * 4
    cosine = [epoch_learning_rate(1e-3, "cosine", e, 4) for e in range(4)]
    np.testing.assert_allclose(cosine, [1e-3, 1e-3 * (1 + np.cos(np.pi / 4)) / 2, 5e-4,
                                        1e-3 * (1 + np.cos(3 * np.pi / 4)) / 2])
    with pytest.raises(ValueError, match="schedule"):
        epoch_learning_rate(1e-3, "step", 0, 4)
    with pytest.raises(ValueError, match="lr_schedule"):
        LamaTrainConfig(data_dir="d", out_dir="o", lr_schedule="step")


@pytest.mark.slow
def test_pix2pix_training_learns(synthetic_data, tmp_path):
    cfg = Pix2PixTrainConfig(data_dir=str(synthetic_data[ModelKind.PIX2PIX]), out_dir=str(tmp_path), epochs=4,
                             model=SMALL_PIX2PIX, batch_size=8, lr=2e-3, wall_weight=50.0,
                             lr_schedule="constant", progress=False)
    history = train_pix2pix(cfg).history
    assert history[-1]["train_l1"] < 0.8 * history[0]["train_l1"]
    assert history[-1]["train_gan_d"] > 0 and history[-1]["train_gan_g"] > 0
    checkpoint = load_checkpoint(tmp_path)
    assert checkpoint["kind"] is ModelKind.PIX2PIX and set(checkpoint["state"]) == {"generator", "discriminator"}


def test_training_configs_are_checked(synthetic_data, tmp_path):
    with pytest.raises(ValueError, match="in_channels"):
        LamaTrainConfig(data_dir="x", out_dir="y", kind=ModelKind.LAMA_LOS, model=LamaConfig(in_channels=3))
    with pytest.raises(ValueError, match="holds lama_bp data"):
        train_lama(LamaTrainConfig(data_dir=str(synthetic_data[ModelKind.LAMA_BP]), out_dir=str(tmp_path),
                                   kind=ModelKind.LAMA_LOS, model=LamaConfig(in_channels=2), progress=False))
    with pytest.raises(ValueError, match="windows"):
        train_pix2pix(Pix2PixTrainConfig(data_dir=str(synthetic_data[ModelKind.PIX2PIX]), out_dir=str(tmp_path),
                                         progress=False))


def test_encodings_match_the_channel_lists():
    observed = np.array([[-1, 0], [1, -1]], np.int8)
    evidence = np.array([[0.5, 0], [0, 1]], np.float32)
    bp = encode_map(observed, evidence, ModelKind.LAMA_BP)[0]
    np.testing.assert_array_equal(bp[MODEL_CHANNELS[ModelKind.LAMA_BP].index("observed_wall")], [[0, 0], [1, 0]])
    np.testing.assert_array_equal(bp[MODEL_CHANNELS[ModelKind.LAMA_BP].index("unknown")], [[1, 0], [0, 1]])
    np.testing.assert_array_equal(bp[MODEL_CHANNELS[ModelKind.LAMA_BP].index("evidence")], evidence)
    np.testing.assert_array_equal(encode_map(observed, evidence, ModelKind.LAMA_LOS)[0], bp[[0, 2]])


# --- Pix2Pix input encodings ----------------------------------------------------------------------------------

def test_bp_encodings_agree_between_numpy_and_the_training_reencoder():
    from superex_deploy.onboard.prediction.inference import BpEncoding
    from superex_train.training import _bp_reencoder

    windows = np.random.default_rng(0).random((3, 16, 16)).astype(np.float32) ** 4
    windows[0, 0, :3] = (0.0, 1.0, 1e-4)
    linear = BpEncoding.LINEAR.apply(windows)
    np.testing.assert_allclose(linear, 2 * windows - 1, atol=0, rtol=0)
    logged = BpEncoding.LOG.apply(windows)
    assert logged[0, 0, 0] == -1.0 and abs(logged[0, 0, 1] - 1.0) < 1e-6
    assert np.all(np.diff(np.sort(logged.ravel())) >= 0) and np.all(logged >= linear - 1e-6)  # lifts faint votes
    assert _bp_reencoder(BpEncoding.LINEAR) is None
    np.testing.assert_allclose(_bp_reencoder(BpEncoding.LOG)(torch.from_numpy(linear)).numpy(), logged,
                               atol=2e-6, rtol=0)
    for encoding in BpEncoding:
        assert BpEncoding.from_description(encoding.description) is encoding
    with pytest.raises(ValueError, match="unknown back-projection normalisation"):
        BpEncoding.from_description("bp: x")
    with pytest.raises(ValueError):
        Pix2PixTrainConfig(data_dir="x", out_dir="y", input_encoding="sqrt")


def test_log_encoded_pix2pix_trains_exports_and_is_fed_its_encoding(synthetic_data, tmp_path):
    from superex_deploy.onboard.prediction.inference import BpEncoding, Pix2PixFilter
    from superex_train.export import export_checkpoint

    cfg = Pix2PixTrainConfig(data_dir=str(synthetic_data[ModelKind.PIX2PIX]), out_dir=str(tmp_path / "run"),
                             epochs=1, model=SMALL_PIX2PIX, batch_size=8, input_encoding="log", bce_weight=1.0,
                             adversarial_weight=0.1, progress=False)
    train_pix2pix(cfg)
    checkpoint = load_checkpoint(tmp_path / "run")
    assert checkpoint["train_config"]["input_encoding"] == "log"
    record = export_checkpoint(tmp_path / "run", tmp_path / "p2p.onnx")
    p2p = Pix2PixFilter(record.path, record.sha256)
    assert p2p.encoding is BpEncoding.LOG
    windows = np.random.default_rng(1).random((2, 32, 32)).astype(np.float32) ** 6
    generator = UNetGenerator(SMALL_PIX2PIX)
    generator.load_state_dict(checkpoint["state"]["generator"])
    with torch.no_grad():
        expected = torch.sigmoid(generator.eval()(torch.from_numpy(BpEncoding.LOG.apply(windows)[:, None])))[:, 0]
        linear = torch.sigmoid(generator(torch.from_numpy(BpEncoding.LINEAR.apply(windows)[:, None])))[:, 0]
    got = p2p.filter_windows(windows)
    np.testing.assert_allclose(got, expected.numpy(), atol=1e-4, rtol=0)
    assert np.abs(got - linear.numpy()).max() > 1e-3  # the encoding matters, so the check above is meaningful


def test_export_models_writes_the_generator_checkpoints_the_parity_tests_read(synthetic_data, tmp_path):
    from superex_deploy.onboard.prediction.inference import BpEncoding, Pix2PixFilter, read_manifest
    from superex_train.export import export_models

    cfg = Pix2PixTrainConfig(data_dir=str(synthetic_data[ModelKind.PIX2PIX]), out_dir=str(tmp_path / "run"),
                             epochs=1, model=SMALL_PIX2PIX, batch_size=8, progress=False)
    train_pix2pix(cfg)
    export_models(tmp_path / "models", pix2pix=tmp_path / "run")
    full = load_checkpoint(tmp_path / "run")
    slim = load_checkpoint(tmp_path / "models" / "checkpoints" / "pix2pix.pt")
    assert set(full["state"]) == {"generator", "discriminator"} and full["optimizers"]
    assert set(slim["state"]) == {"generator"} and slim["optimizers"] == {}
    assert slim["kind"] is ModelKind.PIX2PIX and slim["history"] == full["history"]
    assert slim["training_data_sha256"] == full["training_data_sha256"]
    generator = UNetGenerator(SMALL_PIX2PIX)
    generator.load_state_dict(slim["state"]["generator"])  # the torch side of the parity check
    entry = read_manifest(tmp_path / "models")[0]
    windows = np.random.default_rng(2).random((2, 32, 32)).astype(np.float32) ** 6
    with torch.no_grad():
        encoded = BpEncoding(full["train_config"]["input_encoding"]).apply(windows)[:, None]
        expected = torch.sigmoid(generator.eval()(torch.from_numpy(encoded)))[:, 0]
    got = Pix2PixFilter(entry.path, entry.sha256).filter_windows(windows)
    np.testing.assert_allclose(got, expected.numpy(), atol=1e-4, rtol=0)


@pytest.mark.parametrize("model", ["pix2pix", "lama"])
def test_cli_defaults_are_the_training_config_defaults(model):
    """`superex train pix2pix|lama` without options must train the recipe the config classes document."""
    import argparse
    import dataclasses

    from superex_train.commands import train as train_command

    parser = argparse.ArgumentParser()
    train_command.add_arguments(parser)
    args = parser.parse_args([model, "--data", "d", "--out", "o"])
    cls = Pix2PixTrainConfig if model == "pix2pix" else LamaTrainConfig
    defaults = {f.name: f.default for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}
    names = ["epochs", "batch_size", "lr", "wall_weight", "l1_weight", "seed", "threads"]
    names += (["adversarial_weight", "bce_weight", "input_encoding"] if model == "pix2pix"
              else ["focal_gamma", "known_weight", "lr_schedule", "init_from"])
    for name in names:
        assert getattr(args, name) == defaults[name], name
    if model == "pix2pix":
        assert (not args.no_adversarial) == defaults["adversarial"]
        assert tuple(args.channels) == tuple(Pix2PixConfig().channels)
    else:
        lama = LamaConfig()
        assert (args.base_channels, args.max_channels, args.blocks) == (lama.base_channels, lama.max_channels,
                                                                         lama.n_blocks)
