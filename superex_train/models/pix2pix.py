"""Pix2Pix (Isola et al., CVPR 2017) for filtering back-projection: U-Net generator and PatchGAN discriminator.

The generator reads one robot-centred window of the raw back-projection (``superex_deploy.onboard.nlos.back_project``,
in [0, 1], mapped to [-1, 1] by ``2 x - 1``) as float32 ``[B, 1, S, S]`` and returns wall logits
``[B, 1, S, S]`` (``sigmoid`` gives the probability that a hidden wall reflected late photons from the cell).
The default window is ``S = 160`` cells = 16.0 m at 0.1 m/cell: the back-projection is computed within
``NlosConfig.window_m = 8 m`` of the robot, i.e. on 161 x 161 cells, and a power-of-two multiple is needed by
the U-Net; the robot sits at cell ``(S // 2, S // 2)`` of the window, so the 161st row and column (exactly 8 m
below / right of the robot) fall outside it.

Generator: ``len(channels)`` stride-2 4x4 convolutions (LeakyReLU 0.2, BN except on the first) down to
``S / 2 ** len(channels)``, mirrored by stride-2 4x4 transposed convolutions (ReLU, BN, dropout 0.5 on the
``dropout_layers`` innermost ones while training, as in the paper's noise-free conditional GAN) with skip
connections, and a last transposed convolution to one logit channel.

Discriminator: 70 x 70 PatchGAN on the pair (input window, wall probability mapped to [-1, 1]): three stride-2
and two stride-1 4x4 convolutions, one logit per overlapping patch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

__all__ = ["Pix2PixConfig", "UNetGenerator", "PatchDiscriminator"]


@dataclass(frozen=True)
class Pix2PixConfig:
    """Architecture of the Pix2Pix pair.

    Attributes:
        window_cells: side ``S`` of the square input window (cells); a multiple of ``2 ** len(channels)``.
        channels: generator encoder channels, one entry per stride-2 stage (the decoder mirrors them).
        dropout_layers: innermost decoder stages with dropout 0.5 while training.
        discriminator_channels: channels of the discriminator's first layer (doubled twice).
    """

    window_cells: int = 160
    channels: tuple[int, ...] = (16, 32, 64, 96, 96)
    dropout_layers: int = 2
    discriminator_channels: int = 32

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", tuple(int(c) for c in self.channels))
        if len(self.channels) < 2 or min(self.channels) < 1:
            raise ValueError(f"Pix2PixConfig.channels needs at least 2 positive entries, got {self.channels}")
        step = 2 ** len(self.channels)
        if self.window_cells < step or self.window_cells % step:
            raise ValueError(f"Pix2PixConfig.window_cells must be a positive multiple of {step} "
                             f"(2 ** len(channels)), got {self.window_cells}")
        if not 0 <= self.dropout_layers < len(self.channels):
            raise ValueError(f"Pix2PixConfig.dropout_layers must lie in [0, {len(self.channels) - 1}], got "
                             f"{self.dropout_layers}")
        if self.discriminator_channels < 1:
            raise ValueError(f"Pix2PixConfig.discriminator_channels must be >= 1, got {self.discriminator_channels}")

    def to_dict(self) -> dict:
        return {"window_cells": self.window_cells, "channels": list(self.channels),
                "dropout_layers": self.dropout_layers, "discriminator_channels": self.discriminator_channels}

    @classmethod
    def from_dict(cls, values: dict) -> "Pix2PixConfig":
        values = dict(values)
        values["channels"] = tuple(values["channels"])
        return cls(**values)


class UNetGenerator(nn.Module):
    """``[B, 1, S, S]`` back-projection window in [-1, 1] -> wall logits ``[B, 1, S, S]``."""

    def __init__(self, cfg: Pix2PixConfig = Pix2PixConfig()):
        super().__init__()
        self.cfg = cfg
        channels = cfg.channels
        self.encoder = nn.ModuleList()
        previous = 1
        for i, width in enumerate(channels):
            layers: list[nn.Module] = [] if i == 0 else [nn.LeakyReLU(0.2, inplace=False)]
            layers.append(nn.Conv2d(previous, width, 4, stride=2, padding=1, bias=i == 0))
            if i > 0:
                layers.append(nn.BatchNorm2d(width))
            self.encoder.append(nn.Sequential(*layers))
            previous = width
        self.decoder = nn.ModuleList()
        depth = len(channels)
        for i in reversed(range(1, depth)):
            # Decoder stage i maps encoder stage i's output (concatenated with the skip, except innermost) to
            # encoder stage i-1's width.
            in_width = channels[i] if i == depth - 1 else 2 * channels[i]
            layers = [nn.ReLU(inplace=False),
                      nn.ConvTranspose2d(in_width, channels[i - 1], 4, stride=2, padding=1, bias=False),
                      nn.BatchNorm2d(channels[i - 1])]
            if depth - 1 - i < cfg.dropout_layers:
                layers.append(nn.Dropout(0.5))
            self.decoder.append(nn.Sequential(*layers))
        self.head = nn.Sequential(nn.ReLU(inplace=False), nn.ConvTranspose2d(2 * channels[0], 1, 4, stride=2,
                                                                             padding=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for stage in self.encoder:
            x = stage(x)
            skips.append(x)
        x = skips.pop()
        for stage in self.decoder:
            x = torch.cat([stage(x), skips.pop()], dim=1)
        return self.head(x)


class PatchDiscriminator(nn.Module):
    """PatchGAN: ``(window [B, 1, S, S], wall map [B, 1, S, S])``, both in [-1, 1] -> patch logits
    ``[B, 1, S / 8 - 2, S / 8 - 2]`` (70 x 70-cell receptive fields)."""

    def __init__(self, cfg: Pix2PixConfig = Pix2PixConfig()):
        super().__init__()
        width = cfg.discriminator_channels
        self.net = nn.Sequential(
            nn.Conv2d(2, width, 4, stride=2, padding=1), nn.LeakyReLU(0.2, inplace=True),
            nn.Conv2d(width, 2 * width, 4, stride=2, padding=1, bias=False), nn.BatchNorm2d(2 * width),
            nn.LeakyReLU(0.2, inplace=True),
            nn.Conv2d(2 * width, 4 * width, 4, stride=2, padding=1, bias=False), nn.BatchNorm2d(4 * width),
            nn.LeakyReLU(0.2, inplace=True),
            nn.Conv2d(4 * width, 4 * width, 4, stride=1, padding=1, bias=False), nn.BatchNorm2d(4 * width),
            nn.LeakyReLU(0.2, inplace=True),
            nn.Conv2d(4 * width, 1, 4, stride=1, padding=1))

    def forward(self, window: torch.Tensor, walls: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([window, walls], dim=1))
