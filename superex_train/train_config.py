"""Configuration of the training loops (:mod:`superex_train.training`): the settings both loops share
(:class:`RunSettings`) and one frozen dataclass per loop, validated on construction."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from superex_deploy.onboard.prediction.inference import MODEL_CHANNELS, BpEncoding, ModelKind
from superex_train.models import LamaConfig, Pix2PixConfig

__all__ = ["RunSettings", "Pix2PixTrainConfig", "LamaTrainConfig", "LR_SCHEDULES", "RUN_ONLY_FIELDS", "config_dict"]

LR_SCHEDULES = ("constant", "cosine")
RUN_ONLY_FIELDS = ("epochs", "threads", "progress", "device")
"""Settings a resumed run may change (the others must equal the checkpoint's)."""


@dataclass(frozen=True, kw_only=True)
class RunSettings:
    """What both training loops share: data, output, validation split, randomness, hardware, reporting.

    Attributes:
        data_dir: the dataset folder (:mod:`superex_train.datasets` format).
        out_dir: where ``checkpoint.pt`` and ``history.json`` go.
        val_fraction: share of the samples (whole buildings) held out for validation when ``val_groups`` is
            empty.
        val_groups: building ids held out for validation (``superex_train.generate.heldout_buildings()`` for
            the KTH data); overrides ``val_fraction``.
        augment: random dihedral transforms (one of the 8 rotations / reflections per batch).
        seed: seeds everything.
        threads: torch CPU threads.
        device: torch device (``"cpu"``, ``"cuda[:n]"``, or ``"auto"``: CUDA when available).
        max_batches: stop each epoch after this many batches (0: the whole split; for quick runs).
        progress: show a tqdm bar.
        lr_schedule: ``"constant"`` or ``"cosine"`` (per epoch: ``lr * (1 + cos(pi * epoch / epochs)) / 2``;
            changing ``epochs`` on resume reshapes the remaining schedule).
    """

    data_dir: str
    out_dir: str
    val_fraction: float = 0.1
    val_groups: tuple[int, ...] = ()
    augment: bool = True
    seed: int = 0
    threads: int = 2
    device: str = "cpu"
    max_batches: int = 0
    progress: bool = True
    lr_schedule: str = "constant"

    def __post_init__(self) -> None:
        _check_common(self)


@dataclass(frozen=True, kw_only=True)
class Pix2PixTrainConfig(RunSettings):
    """Training of the Pix2Pix filter (keyword arguments only; the shared ones are :class:`RunSettings`').

    Attributes:
        model: the architecture (the dataset's tiles must be ``model.window_cells`` square).
        epochs: passes over the training split (with ``lr_schedule`` cosine by default: held-out IoU rose
            through the decay, 0.092 after the first of 8 epochs to 0.137 after the last).
        batch_size: windows per step.
        lr, beta1: Adam settings of both networks (beta1 0.5 as the paper; its lr 2e-4 learned about 3x slower
            here).
        l1_weight: weight of the wall-weighted L1 term (the paper's lambda = 100 with adversarial weight 1; the
            defaults keep the same 100:1 ratio of L1 to adversarial term and add the BCE term, which with the log
            encoding raised held-out wall IoU from 0.021 to 0.096; see docs/models.md).
        wall_weight: weight of a wall cell in the L1 term relative to a free cell (hidden walls are ~2 % of the
            unknown cells of a window).
        adversarial: train against the PatchGAN discriminator (False: reconstruction terms only).
        adversarial_weight: weight of the generator's adversarial term.
        bce_weight: weight of a wall-weighted binary cross-entropy term on the logits (0: none).
        dice_weight: weight of a soft Dice term over each batch (0: none); Dice is ``2 IoU / (1 + IoU)``, so
            this term aims at the pooled wall IoU the filter is scored by, which the per-cell terms reach only
            through the choice of ``wall_weight``.
        input_encoding: :class:`~superex_deploy.onboard.prediction.inference.BpEncoding` value the generator reads; datasets
            store ``linear`` windows, re-encoded per batch, and the export declares this encoding.
    """

    model: Pix2PixConfig = field(default_factory=Pix2PixConfig)
    epochs: int = 8
    lr_schedule: str = "cosine"
    batch_size: int = 16
    lr: float = 1e-3
    beta1: float = 0.5
    l1_weight: float = 1.0
    wall_weight: float = 12.0
    adversarial: bool = True
    adversarial_weight: float = 0.01
    bce_weight: float = 1.0
    dice_weight: float = 1.0
    input_encoding: str = "log"

    def __post_init__(self) -> None:
        super().__post_init__()
        BpEncoding(self.input_encoding)  # ValueError for an unknown encoding
        if self.adversarial_weight < 0 or self.bce_weight < 0 or self.dice_weight < 0:
            raise ValueError("Pix2PixTrainConfig: adversarial_weight, bce_weight and dice_weight must be >= 0")


@dataclass(frozen=True, kw_only=True)
class LamaTrainConfig(RunSettings):
    """Training of one LaMa ensemble member (keyword arguments only; the shared ones are
    :class:`RunSettings`').

    Attributes:
        kind: LAMA_BP or LAMA_LOS; must match the dataset and ``model.in_channels``.
        model: the architecture (the dataset's tiles must be multiples of ``model.size_multiple``).
        member: ensemble member index (members differ by seed and by training subset).
        epochs, batch_size, lr: as usual (Adam, betas (0.9, 0.999)).
        wall_weight: weight of a wall cell in both terms relative to a free cell.
        focal_gamma: focal exponent of the BCE term (0: plain BCE).
        l1_weight: weight of the wall-weighted L1 term on the probabilities.
        known_weight: loss weight of observed cells relative to unknown ones.
        subsets: the training split is partitioned (seeded, the same for every member) into this many disjoint
            parts and the member trains on part ``member % subsets`` (1: the whole split).
        init_from: a LaMa checkpoint (file or run folder) whose generator weights start the run instead of a
            random initialisation; ``{member}`` in it is replaced by the member index. Its architecture must
            equal ``model`` except for the input channels, which are matched by name
            (:data:`~superex_deploy.onboard.prediction.inference.MODEL_CHANNELS`): a channel the source lacks gets zero stem weights,
            so a LaMa-BP member started from a LaMa-LOS one first predicts exactly what the LOS member does and
            learns to read the evidence channel from there. Empty: random initialisation.
    """

    kind: ModelKind = ModelKind.LAMA_BP
    model: LamaConfig = field(default_factory=LamaConfig)
    member: int = 0
    epochs: int = 16
    batch_size: int = 16
    lr: float = 1e-3
    wall_weight: float = 10.0
    focal_gamma: float = 0.0
    l1_weight: float = 1.0
    known_weight: float = 0.1
    subsets: int = 1
    init_from: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kind not in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS):
            raise ValueError(f"LamaTrainConfig.kind must be LAMA_BP or LAMA_LOS, got {self.kind}")
        if self.model.in_channels != len(MODEL_CHANNELS[self.kind]):
            raise ValueError(f"a {self.kind.value} model takes {len(MODEL_CHANNELS[self.kind])} channels, "
                             f"LamaConfig.in_channels is {self.model.in_channels}")
        if self.member < 0 or self.focal_gamma < 0 or not 0 <= self.known_weight <= 1 or self.subsets < 1:
            raise ValueError("member and focal_gamma must be >= 0, subsets >= 1 and known_weight in [0, 1]")

    @property
    def init_checkpoint(self) -> Optional[Path]:
        """The checkpoint ``init_from`` names for this member (None: random initialisation)."""
        return Path(self.init_from.replace("{member}", str(self.member))) if self.init_from else None


def _check_common(cfg) -> None:
    for name in ("epochs", "batch_size", "threads"):
        if int(getattr(cfg, name)) < 1:
            raise ValueError(f"{type(cfg).__name__}.{name} must be >= 1, got {getattr(cfg, name)}")
    if cfg.lr <= 0 or cfg.wall_weight <= 0 or cfg.max_batches < 0:
        raise ValueError(f"{type(cfg).__name__}: lr and wall_weight must be > 0 and max_batches >= 0")
    object.__setattr__(cfg, "val_groups", tuple(int(g) for g in cfg.val_groups))
    if cfg.device not in ("cpu", "cuda", "auto") and not str(cfg.device).startswith("cuda:"):
        raise ValueError(f"{type(cfg).__name__}.device must be 'cpu', 'cuda[:n]' or 'auto', got {cfg.device!r}")
    if not 0 <= cfg.val_fraction < 1:
        raise ValueError(f"{type(cfg).__name__}.val_fraction must lie in [0, 1), got {cfg.val_fraction}")
    if cfg.lr_schedule not in LR_SCHEDULES:
        raise ValueError(f"{type(cfg).__name__}.lr_schedule must be one of {LR_SCHEDULES}, got {cfg.lr_schedule!r}")


def config_dict(cfg) -> dict:
    """A training config as a JSON-ready dict (nested configs by ``to_dict``, enums by value)."""
    out = {}
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if hasattr(value, "to_dict"):
            value = value.to_dict()
        elif isinstance(value, enum.Enum):
            value = value.value
        out[f.name] = value
    return out
