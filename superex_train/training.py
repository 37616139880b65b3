"""Training loops of the Pix2Pix filter and of one LaMa ensemble member.

Both loops read a :class:`~superex_train.datasets.ShardDataset`, hold out whole buildings for validation
(:func:`~superex_train.datasets.split_by_group`), apply a random dihedral transform (one of the 8 rotations /
reflections, drawn per batch) when ``augment`` is set, and write ``out_dir/checkpoint.pt`` after every epoch
(atomically) together with ``out_dir/history.json``. Everything random derives from ``(seed, member, epoch)``
(batch order, augmentation, dropout), so a run stopped after epoch ``e`` and resumed gives the same weights as
an uninterrupted run: a resumed run reloads the checkpoint and goes on at epoch ``e + 1``; its settings must
equal the checkpoint's except ``epochs``, ``threads``, ``device`` and ``progress``.

The same command trains on the CPU (the reference: every size here is chosen for 2 cores) or, with
``device="cuda"``, on a GPU; results agree statistically, not bit for bit.

Losses (see :mod:`superex_train.losses`): Pix2Pix minimises ``l1_weight * wall-weighted L1`` plus, with
``adversarial``, the conditional PatchGAN loss (the discriminator sees the window and a wall map in [-1, 1]).
LaMa minimises wall-weighted (optionally focal) BCE plus ``l1_weight * wall-weighted L1``, with observed cells
down-weighted by ``known_weight`` (the deployed ensemble keeps observed cells as observed; what matters is
the unknown part). LaMa's adversarial and perceptual losses are left out: maps are binary and the weighted
BCE alone is what MapEx's fine-tuning of LaMa needs to predict walls, and it keeps CPU training affordable.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from superex_deploy.files import write_atomically
from superex_deploy.onboard.prediction.inference import MODEL_CHANNELS, BpEncoding, ModelKind, sha256_file
from superex_train.datasets import ShardDataset, split_by_group
from superex_train.losses import gan_loss, soft_dice_loss, wall_weighted_bce, wall_weighted_l1
from superex_train.models import (LamaConfig, LamaGenerator, PatchDiscriminator, Pix2PixConfig, UNetGenerator,
                                  count_parameters)
from superex_train.train_config import (LR_SCHEDULES, RUN_ONLY_FIELDS, LamaTrainConfig, Pix2PixTrainConfig,
                                        RunSettings, config_dict)

__all__ = ["RunSettings", "Pix2PixTrainConfig", "LamaTrainConfig", "TrainResult", "train_pix2pix", "train_lama",
           "load_checkpoint", "build_generator", "epoch_learning_rate", "initialise_lama_from", "LR_SCHEDULES",
           "CHECKPOINT_NAME", "CHECKPOINT_FORMAT"]

CHECKPOINT_NAME = "checkpoint.pt"
CHECKPOINT_FORMAT = "superex-checkpoint/1"
_STEM_WEIGHT = "stem.1.weight"


@dataclass(frozen=True)
class TrainResult:
    """Outcome of a training run: the checkpoint and the per-epoch history (list of dicts)."""

    checkpoint: Path
    history: list


def build_generator(kind: ModelKind, model_config: dict) -> torch.nn.Module:
    """The generator of a checkpoint's kind from its stored architecture dict."""
    if kind is ModelKind.PIX2PIX:
        return UNetGenerator(Pix2PixConfig.from_dict(model_config))
    return LamaGenerator(LamaConfig.from_dict(model_config))


def load_checkpoint(path) -> dict:
    """A checkpoint written by the loops below (``torch.load`` on CPU), its format checked."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    if not path.is_file():
        raise ValueError(f"no checkpoint at {path}")
    checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a {CHECKPOINT_FORMAT} checkpoint")
    checkpoint["kind"] = ModelKind(checkpoint["kind"])
    return checkpoint


def epoch_learning_rate(lr: float, schedule: str, epoch: int, epochs: int) -> float:
    """The learning rate of 0-based ``epoch`` out of ``epochs`` under ``schedule`` (see LamaTrainConfig)."""
    if schedule == "constant":
        return lr
    if schedule == "cosine":
        return lr * 0.5 * (1.0 + math.cos(math.pi * epoch / epochs))
    raise ValueError(f"unknown learning-rate schedule {schedule!r}; choose one of {LR_SCHEDULES}")


def initialise_lama_from(generator: "LamaGenerator", kind: ModelKind, path) -> str:
    """Load a LaMa checkpoint's generator weights into ``generator`` (of ``kind``), matching input channels by
    name; channels the source lacks get zero stem weights. Returns the checkpoint's sha256.

    Raises ValueError when the checkpoint is not a LaMa one, its architecture differs beyond the input channels,
    or it has an input channel ``kind`` lacks (its information would be dropped silently).
    """
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    checkpoint = load_checkpoint(path)
    source_kind = checkpoint["kind"]
    if source_kind not in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS):
        raise ValueError(f"{path} holds a {source_kind.value} model; a LaMa member starts only from a LaMa one")
    source_model = dict(checkpoint["model_config"], in_channels=generator.cfg.in_channels)
    if source_model != generator.cfg.to_dict():
        diff = sorted(k for k in source_model if source_model[k] != generator.cfg.to_dict().get(k))
        raise ValueError(f"{path} has another architecture than the member to train (differs in {diff})")
    source_channels, target_channels = MODEL_CHANNELS[source_kind], MODEL_CHANNELS[kind]
    extra = sorted(set(source_channels) - set(target_channels))
    if extra:
        raise ValueError(f"{path} reads input channels {extra} that a {kind.value} model does not have")
    state = dict(checkpoint["state"]["generator"])
    source_stem = state[_STEM_WEIGHT]
    stem = torch.zeros(source_stem.shape[0], len(target_channels), *source_stem.shape[2:], dtype=source_stem.dtype)
    for index, name in enumerate(target_channels):
        if name in source_channels:
            stem[:, index] = source_stem[:, source_channels.index(name)]
    state[_STEM_WEIGHT] = stem
    generator.load_state_dict(state)
    return sha256_file(path)


def _dihedral(tensors: list[torch.Tensor], k: int, flip: bool) -> list[torch.Tensor]:
    out = []
    for t in tensors:
        t = torch.rot90(t, k, dims=(2, 3)) if k else t
        out.append(torch.flip(t, dims=(3,)) if flip else t)
    return out


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class _InMemory:
    """The whole dataset in memory (float16 inputs, uint8 labels: a few hundred MB for the KTH data), so a batch
    is one fancy-indexing step instead of a Python loop over memory-mapped samples."""

    def __init__(self, dataset: ShardDataset, device: torch.device):
        parts = dataset.shard_arrays
        self.inputs = np.concatenate([np.asarray(a) for a in parts["inputs"]])
        self.targets = np.concatenate([np.asarray(a) for a in parts["targets"]])
        self.mask = np.concatenate([np.asarray(a) for a in parts["mask"]])
        self.device = device
        self.transform = None  # optional re-encoding of the inputs, applied per batch

    def batch(self, indices: np.ndarray) -> list[torch.Tensor]:
        indices = np.sort(indices)
        inputs = torch.from_numpy(self.inputs[indices]).to(self.device, torch.float32)
        return [inputs if self.transform is None else self.transform(inputs),
                torch.from_numpy(self.targets[indices][:, None]).to(self.device, torch.float32),
                torch.from_numpy(self.mask[indices][:, None]).to(self.device, torch.float32)]


def _bp_reencoder(encoding: BpEncoding):
    """torch twin of :meth:`BpEncoding.apply` on windows stored ``linear``-encoded (None for ``linear``)."""
    if encoding is BpEncoding.LINEAR:
        return None
    scale = 1.0 / float(np.log(101.0))
    return lambda x: 2.0 * torch.log1p(50.0 * (x + 1.0)) * scale - 1.0  # 100 * (x + 1) / 2 = 50 (x + 1)


def _batches(data: _InMemory, indices: np.ndarray, batch_size: int):
    for start in range(0, len(indices), batch_size):
        yield data.batch(indices[start:start + batch_size])


def _iou(probability: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> tuple[int, int]:
    predicted = (probability >= 0.5) & (mask > 0)
    truth = (target > 0.5) & (mask > 0)
    return int((predicted & truth).sum()), int((predicted | truth).sum())


class _Run:
    """Shared machinery: data split, epochs, checkpoints, history."""

    def __init__(self, cfg, kind: ModelKind, member: int, modules: dict, optimizers: dict):
        self.cfg, self.kind, self.member = cfg, kind, member
        self.modules, self.optimizers = modules, optimizers
        self.out_dir = Path(cfg.out_dir)
        self.dataset = ShardDataset(cfg.data_dir, kind)
        self.device = _device(cfg.device)
        self.data = _InMemory(self.dataset, self.device)
        if cfg.val_groups:
            is_val = np.isin(self.dataset.groups, cfg.val_groups)
            self.train_idx, self.val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
        else:
            self.train_idx, self.val_idx = split_by_group(self.dataset.groups, cfg.val_fraction, cfg.seed)
        subsets = getattr(cfg, "subsets", 1)
        if subsets > 1:
            parts = np.array_split(np.random.default_rng([cfg.seed, 7919]).permutation(self.train_idx), subsets)
            self.train_idx = np.sort(parts[member % subsets])
        if len(self.train_idx) == 0:
            raise ValueError(f"{cfg.data_dir} leaves no training samples after the validation split")
        for module in modules.values():
            module.to(self.device)
        self.history: list[dict] = []
        self.start_epoch = 0
        self.extra: dict = {}  # run facts kept in the checkpoint (e.g. the sha256 of the initial weights)

    def checkpoint_path(self) -> Path:
        return self.out_dir / CHECKPOINT_NAME

    def resume(self) -> None:
        path = self.checkpoint_path()
        if not path.is_file():
            return
        checkpoint = load_checkpoint(path)
        saved = {k: v for k, v in checkpoint["train_config"].items() if k not in RUN_ONLY_FIELDS}
        current = {k: v for k, v in config_dict(self.cfg).items() if k not in RUN_ONLY_FIELDS}
        if saved != current or checkpoint["kind"] is not self.kind:
            diff = sorted(k for k in set(saved) | set(current) if saved.get(k) != current.get(k))
            raise ValueError(f"the checkpoint in {self.out_dir} was trained with other settings ({diff}); "
                             f"choose another output directory or start afresh")
        if checkpoint["training_data_sha256"] != self.dataset.info.data_sha256:
            raise ValueError(f"the checkpoint in {self.out_dir} was trained on other data than {self.cfg.data_dir}")
        for name, module in self.modules.items():
            module.load_state_dict(checkpoint["state"][name])
        for name, optimizer in self.optimizers.items():
            optimizer.load_state_dict(checkpoint["optimizers"][name])
        self.history = list(checkpoint["history"])
        self.extra = dict(checkpoint.get("extra", {}))
        self.start_epoch = int(checkpoint["epoch"]) + 1

    def epoch_order(self, epoch: int) -> tuple[np.random.Generator, np.ndarray]:
        rng = np.random.default_rng([self.cfg.seed, self.member, epoch])
        torch.manual_seed(int(rng.integers(2 ** 62)))
        order = rng.permutation(self.train_idx)
        if self.cfg.max_batches:
            order = order[:self.cfg.max_batches * self.cfg.batch_size]
        return rng, order

    def save(self, epoch: int, generator: torch.nn.Module) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        checkpoint = {
            "format": CHECKPOINT_FORMAT, "kind": self.kind.value, "member": self.member, "epoch": epoch,
            "model_config": generator.cfg.to_dict(), "train_config": config_dict(self.cfg),
            "training_data_sha256": self.dataset.info.data_sha256,
            "parameters": count_parameters(generator),
            "state": {name: module.state_dict() for name, module in self.modules.items()},
            "optimizers": {name: opt.state_dict() for name, opt in self.optimizers.items()},
            "history": self.history, "extra": self.extra,
        }
        write_atomically(self.checkpoint_path(), lambda part: torch.save(checkpoint, part))
        (self.out_dir / "history.json").write_text(json.dumps(self.history, indent=1))


def _progress(cfg, total: int, description: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=description, unit="batch", disable=not cfg.progress, leave=False)


def train_pix2pix(cfg: Pix2PixTrainConfig, resume: bool = True) -> TrainResult:
    """Train (or resume training) the Pix2Pix filter; see the module docstring."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    generator, discriminator = UNetGenerator(cfg.model), PatchDiscriminator(cfg.model)
    optimizers = {"generator": torch.optim.Adam(generator.parameters(), cfg.lr, betas=(cfg.beta1, 0.999))}
    modules = {"generator": generator}
    if cfg.adversarial:
        modules["discriminator"] = discriminator
        optimizers["discriminator"] = torch.optim.Adam(discriminator.parameters(), cfg.lr, betas=(cfg.beta1, 0.999))
    run = _Run(cfg, ModelKind.PIX2PIX, 0, modules, optimizers)
    run.data.transform = _bp_reencoder(BpEncoding(cfg.input_encoding))
    if run.dataset.info.tile_hw != (cfg.model.window_cells, cfg.model.window_cells):
        raise ValueError(f"{cfg.data_dir} holds {run.dataset.info.tile_hw} windows, the model reads "
                         f"{cfg.model.window_cells} x {cfg.model.window_cells}")
    if resume:
        run.resume()
    for epoch in range(run.start_epoch, cfg.epochs):
        clock = time.perf_counter()
        for optimizer in optimizers.values():
            for group in optimizer.param_groups:
                group["lr"] = epoch_learning_rate(cfg.lr, cfg.lr_schedule, epoch, cfg.epochs)
        rng, order = run.epoch_order(epoch)
        generator.train()
        discriminator.train()
        sums = {"l1": 0.0, "gan_g": 0.0, "gan_d": 0.0}
        n_batches = 0
        with _progress(cfg, -(-len(order) // cfg.batch_size), f"pix2pix epoch {epoch + 1}/{cfg.epochs}") as bar:
            for window, target, mask in _batches(run.data, order, cfg.batch_size):
                if cfg.augment:
                    window, target, mask = _dihedral([window, target, mask], int(rng.integers(4)),
                                                     bool(rng.integers(2)))
                logits = generator(window)
                probability = torch.sigmoid(logits)
                if cfg.adversarial:
                    d_real = discriminator(window, 2.0 * target - 1.0)
                    d_fake = discriminator(window, 2.0 * probability.detach() - 1.0)
                    loss_d = 0.5 * (gan_loss(d_real, True) + gan_loss(d_fake, False))
                    optimizers["discriminator"].zero_grad(set_to_none=True)
                    loss_d.backward()
                    optimizers["discriminator"].step()
                    sums["gan_d"] += loss_d.item()
                l1 = wall_weighted_l1(probability, target, cfg.wall_weight, mask)
                loss_g = cfg.l1_weight * l1
                if cfg.bce_weight:
                    loss_g = loss_g + cfg.bce_weight * wall_weighted_bce(logits, target, cfg.wall_weight, 0.0, mask)
                if cfg.dice_weight:
                    loss_g = loss_g + cfg.dice_weight * soft_dice_loss(probability, target, mask)
                if cfg.adversarial:
                    gan_g = gan_loss(discriminator(window, 2.0 * probability - 1.0), True)
                    loss_g = loss_g + cfg.adversarial_weight * gan_g
                    sums["gan_g"] += gan_g.item()
                optimizers["generator"].zero_grad(set_to_none=True)
                loss_g.backward()
                optimizers["generator"].step()
                sums["l1"] += l1.item()
                n_batches += 1
                bar.update(1)
                bar.set_postfix(l1=f"{l1.item():.4f}")
        record = {"epoch": epoch, "train_l1": sums["l1"] / n_batches, "batches": n_batches}
        if cfg.adversarial:
            record.update(train_gan_g=sums["gan_g"] / n_batches, train_gan_d=sums["gan_d"] / n_batches)
        record.update(_validate(run, generator, lambda logits, y, m: wall_weighted_l1(
            torch.sigmoid(logits), y, cfg.wall_weight, m), None))
        record["seconds"] = time.perf_counter() - clock
        run.history.append(record)
        run.save(epoch, generator)
    return TrainResult(run.checkpoint_path(), run.history)


def _lama_loss(cfg: LamaTrainConfig, logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor,
               unknown: torch.Tensor) -> torch.Tensor:
    weight = mask * (unknown + cfg.known_weight * (1.0 - unknown))
    loss = wall_weighted_bce(logits, target, cfg.wall_weight, cfg.focal_gamma, weight)
    if cfg.l1_weight:
        loss = loss + cfg.l1_weight * wall_weighted_l1(torch.sigmoid(logits), target, cfg.wall_weight, weight)
    return loss


def _validate(run: _Run, generator: torch.nn.Module, loss_fn, unknown_channel: Optional[int]) -> dict:
    """Validation loss and wall IoU (threshold 0.5, within the mask; LaMa: on unknown cells only)."""
    if len(run.val_idx) == 0:
        return {}
    generator.eval()
    total, batches, intersection, union = 0.0, 0, 0, 0
    with torch.no_grad():
        for inputs, target, mask in _batches(run.data, run.val_idx, run.cfg.batch_size):
            logits = generator(inputs)
            if unknown_channel is not None:
                unknown = inputs[:, unknown_channel:unknown_channel + 1]
                total += float(loss_fn(logits, target, mask, unknown))
                mask = mask * unknown
            else:
                total += float(loss_fn(logits, target, mask))
            batches += 1
            i, u = _iou(torch.sigmoid(logits), target, mask)
            intersection += i
            union += u
    return {"val_loss": total / batches, "val_wall_iou": intersection / union if union else 1.0}


def train_lama(cfg: LamaTrainConfig, resume: bool = True) -> TrainResult:
    """Train (or resume training) one LaMa ensemble member; see the module docstring."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(int(np.random.default_rng([cfg.seed, cfg.member]).integers(2 ** 62)))
    generator = LamaGenerator(cfg.model)
    optimizers = {"generator": torch.optim.Adam(generator.parameters(), cfg.lr)}
    run = _Run(cfg, cfg.kind, cfg.member, {"generator": generator}, optimizers)
    tile = run.dataset.info.tile_hw
    if any(n % cfg.model.size_multiple or n < 2 * cfg.model.size_multiple for n in tile):
        raise ValueError(f"{cfg.data_dir} holds {tile} tiles; the model needs multiples of "
                         f"{cfg.model.size_multiple} of at least {2 * cfg.model.size_multiple}")
    unknown_channel = MODEL_CHANNELS[cfg.kind].index("unknown")
    loss_fn = lambda logits, y, m, u: _lama_loss(cfg, logits, y, m, u)  # noqa: E731
    if resume:
        run.resume()
    if run.start_epoch == 0 and cfg.init_checkpoint is not None:
        run.extra["init_sha256"] = initialise_lama_from(generator, cfg.kind, cfg.init_checkpoint)
        # epoch -1: the starting point's held-out score, the baseline the fine-tuning must beat
        run.history = [{"epoch": -1, **_validate(run, generator, loss_fn, unknown_channel)}]
    for epoch in range(run.start_epoch, cfg.epochs):
        clock = time.perf_counter()
        for group in optimizers["generator"].param_groups:
            group["lr"] = epoch_learning_rate(cfg.lr, cfg.lr_schedule, epoch, cfg.epochs)
        rng, order = run.epoch_order(epoch)
        generator.train()
        total, n_batches = 0.0, 0
        with _progress(cfg, -(-len(order) // cfg.batch_size),
                       f"{cfg.kind.value}[{cfg.member}] epoch {epoch + 1}/{cfg.epochs}") as bar:
            for inputs, target, mask in _batches(run.data, order, cfg.batch_size):
                if cfg.augment:
                    inputs, target, mask = _dihedral([inputs, target, mask], int(rng.integers(4)),
                                                      bool(rng.integers(2)))
                unknown = inputs[:, unknown_channel:unknown_channel + 1]
                loss = _lama_loss(cfg, generator(inputs), target, mask, unknown)
                optimizers["generator"].zero_grad(set_to_none=True)
                loss.backward()
                optimizers["generator"].step()
                total += loss.item()
                n_batches += 1
                bar.update(1)
                bar.set_postfix(loss=f"{loss.item():.4f}")
        record = {"epoch": epoch, "train_loss": total / n_batches, "batches": n_batches,
                  "lr": optimizers["generator"].param_groups[0]["lr"]}
        record.update(_validate(run, generator, loss_fn, unknown_channel))
        record["seconds"] = time.perf_counter() - clock
        run.history.append(record)
        run.save(epoch, generator)
    return TrainResult(run.checkpoint_path(), run.history)
