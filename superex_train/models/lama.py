"""LaMa-style map predictor (Suvorov et al., WACV 2022): a generator built from fast Fourier convolutions.

The network maps the encoded observed map ``[B, C_in, H, W]`` (float32, see
:class:`superex_deploy.onboard.prediction.inference.ModelKind` for the channels and their order) to wall logits ``[B, 1, H, W]``.
``H`` and ``W`` must be multiples of :attr:`LamaConfig.size_multiple` (``2 ** n_downsample``) and at least
``2 * size_multiple``; :class:`superex_deploy.onboard.prediction.inference.LamaEnsemble` pads and crops.

Layout (as in LaMa, without its skip-free generator's 27 M parameters):

* stem: reflect-padded 7x7 convolution to ``base_channels``, BN, ReLU, at full resolution;
* ``n_downsample`` stride-2 3x3 convolutions, doubling channels up to ``max_channels``;
* ``n_blocks`` FFC residual blocks at ``1 / 2 ** n_downsample`` resolution: each FFC splits its channels into a
  local part (3x3 convolutions) and a global part (``global_ratio`` of them) whose global-to-global path is a
  spectral transform (1x1 convolution in the 2-D Fourier domain), so every block sees the whole map;
* ``n_downsample`` stride-2 transposed convolutions back to ``base_channels``; a reflect-padded 7x7 head to one
  logit channel.

The Fourier transform is written as matrix products with DFT matrices built from the input's shape
(:func:`rfft2_ortho`, :func:`irfft2_ortho`), so the ONNX graph (opset 18) keeps dynamic height and width and
needs no ``DFT`` operator; :attr:`SpectralBackend.TORCH_FFT` uses ``torch.fft`` instead (same numbers, for
reference and for comparing the two exports).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch
from torch import nn


__all__ = ["SpectralBackend", "LamaConfig", "LamaGenerator", "FourierUnit", "SpectralTransform", "FFC",
           "FFCResBlock", "DftBasis", "dft_basis", "rfft2_ortho", "irfft2_ortho"]


class SpectralBackend(enum.Enum):
    """How the Fourier unit computes its 2-D real FFT pair."""

    MATMUL = "matmul"
    """Products with DFT matrices built from the input's shape (exports with dynamic H, W; the default)."""
    TORCH_FFT = "torch_fft"
    """``torch.fft.rfft2`` / ``irfft2`` (the reference; exports only through the dynamo exporter, as ``DFT``)."""


@dataclass(frozen=True)
class LamaConfig:
    """Architecture of :class:`LamaGenerator`.

    Attributes:
        in_channels: input channels (3 with the back-projection channel, 2 for the line-of-sight variant).
        base_channels: channels of the full-resolution stem and head.
        n_downsample: stride-2 stages; the FFC blocks run at ``1 / 2 ** n_downsample`` of the map's resolution.
        max_channels: cap on the channels of the down-sampling stages and of the FFC blocks.
        n_blocks: FFC residual blocks.
        global_ratio: share of the FFC blocks' channels in the global (Fourier) branch, in (0, 1).
        spectral: :class:`SpectralBackend` of the Fourier units.
    """

    in_channels: int = 3
    base_channels: int = 16
    n_downsample: int = 3
    max_channels: int = 96
    n_blocks: int = 5
    global_ratio: float = 0.75
    spectral: SpectralBackend = SpectralBackend.MATMUL

    def __post_init__(self) -> None:
        for name in ("in_channels", "base_channels", "n_downsample", "max_channels", "n_blocks"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"LamaConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not 0.0 < self.global_ratio < 1.0:
            raise ValueError(f"LamaConfig.global_ratio must lie in (0, 1), got {self.global_ratio}")
        if not isinstance(self.spectral, SpectralBackend):
            raise ValueError(f"LamaConfig.spectral must be a SpectralBackend, got {self.spectral!r}")
        global_channels = int(round(self.body_channels * self.global_ratio))
        if global_channels < 2 or self.body_channels - global_channels < 1:
            raise ValueError(f"LamaConfig: {self.body_channels} body channels at global_ratio "
                             f"{self.global_ratio} leave no room for both branches")

    @property
    def size_multiple(self) -> int:
        """Height and width of the input must be multiples of this (cells)."""
        return 2 ** self.n_downsample

    @property
    def body_channels(self) -> int:
        """Channels of the FFC blocks."""
        return min(self.base_channels * 2 ** self.n_downsample, self.max_channels)

    def to_dict(self) -> dict:
        return {"in_channels": self.in_channels, "base_channels": self.base_channels,
                "n_downsample": self.n_downsample, "max_channels": self.max_channels, "n_blocks": self.n_blocks,
                "global_ratio": self.global_ratio, "spectral": self.spectral.value}

    @classmethod
    def from_dict(cls, values: dict) -> "LamaConfig":
        values = dict(values)
        values["spectral"] = SpectralBackend(values.get("spectral", SpectralBackend.MATMUL.value))
        return cls(**values)


def _dft_cos_sin(n_rows: int, n_cols: int, period, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``cos`` and ``sin`` of ``2 pi / period * ((k * n) mod period)`` for ``k < n_rows``, ``n < n_cols``.

    The product is reduced modulo the period in integers before it becomes an angle: ``2 pi k n / N`` in
    float32 loses about ``k n`` ulps of ``2 pi / N``, which costs 1e-4 at N ~ 200.
    """
    k = torch.arange(n_rows, device=like.device)
    n = torch.arange(n_cols, device=like.device)
    # The period as a 0-d tensor: the dynamo exporter cannot take the remainder by a symbolic integer.
    period = torch.full((), period, dtype=torch.int64, device=like.device)
    reduced = torch.remainder(k[:, None] * n[None, :], period)
    angle = reduced.to(like.dtype) * (2.0 * math.pi) / period.to(like.dtype)
    return torch.cos(angle), torch.sin(angle)


class DftBasis(NamedTuple):
    """The matrices :func:`rfft2_ortho` and :func:`irfft2_ortho` multiply by, for one ``(H, W)``.

    Attributes:
        forward_w: ``[W, 2 Wf]`` = ``[cos | -sin]`` (real FFT along W, ``Wf = W // 2 + 1``).
        along_h: ``[2 H, H]`` = ``[cos; sin]`` (full FFT along H; its inverse uses the same blocks).
        inverse_w: ``[2 Wf, W]`` = ``[a cos; -a sin]`` with ``a_k`` = 1 at k = 0 and at the Nyquist column of an
            even W, 2 elsewhere (complex-to-real along W: the conjugate half of the spectrum).
        scale: ``1 / sqrt(H W)`` (orthonormal scaling, applied once per direction).
    """

    forward_w: torch.Tensor
    along_h: torch.Tensor
    inverse_w: torch.Tensor
    scale: torch.Tensor


def dft_basis(height: int, width: int, like: torch.Tensor) -> DftBasis:
    """The :class:`DftBasis` of an ``(height, width)`` signal, in ``like``'s dtype and device. Built from the
    shape inside the graph, so exported models keep dynamic height and width; a network computes it once per
    forward pass and hands it to all its Fourier units."""
    half = width // 2 + 1
    cos_w, sin_w = _dft_cos_sin(width, half, width, like)            # [W, Wf]
    cos_h, sin_h = _dft_cos_sin(height, height, height, like)        # [H, H]
    k = torch.arange(half, device=like.device)
    single = (k == 0) | (2 * k == width)
    weight = torch.where(single, torch.ones_like(k), 2 * torch.ones_like(k)).to(like.dtype)[:, None]
    cos_w_t, sin_w_t = cos_w.transpose(0, 1), sin_w.transpose(0, 1)  # [Wf, W]
    scale = 1.0 / torch.sqrt(torch.ones((), dtype=like.dtype, device=like.device) * height * width)
    return DftBasis(forward_w=torch.cat([cos_w, -sin_w], dim=1), along_h=torch.cat([cos_h, sin_h], dim=0),
                    inverse_w=torch.cat([cos_w_t * weight, -sin_w_t * weight], dim=0), scale=scale)


def rfft2_ortho(x: torch.Tensor, basis: Optional[DftBasis] = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Real 2-D FFT over the last two axes with orthonormal scaling, as DFT-matrix products.

    Args:
        x: float ``[..., H, W]``.
        basis: ``dft_basis(H, W, x)`` if already computed.

    Returns:
        ``(real, imag)``, each ``[..., H, W // 2 + 1]``; equal to ``torch.fft.rfft2(x, norm="ortho")``.
    """
    height, width = x.shape[-2], x.shape[-1]
    half = width // 2 + 1
    if basis is None:
        basis = dft_basis(height, width, x)
    # Along W: x @ (cos - i sin), both halves in one product: [..., H, 2 Wf] = [Xr | Xi]. Along H:
    # (cos - i sin) @ (Xr + i Xi); one product gives the blocks [[cos Xr, cos Xi], [sin Xr, sin Xi]].
    blocks = torch.matmul(basis.along_h, torch.matmul(x, basis.forward_w))
    cos_re, cos_im = blocks[..., :height, :half], blocks[..., :height, half:]
    sin_re, sin_im = blocks[..., height:, :half], blocks[..., height:, half:]
    return (cos_re + sin_im) * basis.scale, (cos_im - sin_re) * basis.scale


def irfft2_ortho(real: torch.Tensor, imag: torch.Tensor, width: int, basis: Optional[DftBasis] = None
                 ) -> torch.Tensor:
    """Inverse of :func:`rfft2_ortho`: ``torch.fft.irfft2(real + i imag, s=(H, width), norm="ortho")``.

    Args:
        real, imag: float ``[..., H, width // 2 + 1]``.
        width: length of the real signal's last axis (the half spectrum does not say whether it was odd).
        basis: ``dft_basis(H, width, real)`` if already computed.

    Returns:
        float ``[..., H, width]``. As in ``torch.fft``, the imaginary parts of the zero and Nyquist columns are
        ignored.
    """
    height, half = real.shape[-2], real.shape[-1]
    if basis is None:
        basis = dft_basis(height, width, real)
    # Along H: (cos + i sin) @ (Zr + i Zi).
    blocks = torch.matmul(basis.along_h, torch.cat([real, imag], dim=-1))
    cos_re, cos_im = blocks[..., :height, :half], blocks[..., :height, half:]
    sin_re, sin_im = blocks[..., height:, :half], blocks[..., height:, half:]
    g_re, g_im = cos_re - sin_im, cos_im + sin_re
    # Along W, complex to real: x[n] = sum_k a_k (Re G_k cos - Im G_k sin).
    return torch.matmul(torch.cat([g_re, g_im], dim=-1), basis.inverse_w) * basis.scale


class FourierUnit(nn.Module):
    """1x1 convolution (+BN, ReLU) on the real and imaginary parts of the 2-D spectrum; ``[B, C, H, W]`` in
    and out (``out_channels`` out)."""

    def __init__(self, in_channels: int, out_channels: int, spectral: SpectralBackend = SpectralBackend.MATMUL):
        super().__init__()
        self.spectral = spectral
        self.conv = nn.Conv2d(2 * in_channels, 2 * out_channels, 1, bias=False)
        self.norm = nn.BatchNorm2d(2 * out_channels)
        self.act = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor, basis: Optional[DftBasis] = None) -> torch.Tensor:
        height, width = x.shape[-2], x.shape[-1]
        if self.spectral is SpectralBackend.MATMUL:
            real, imag = rfft2_ortho(x, basis)
        else:
            spectrum = torch.fft.rfft2(x, norm="ortho")
            real, imag = spectrum.real, spectrum.imag
        y = self.act(self.norm(self.conv(torch.cat([real, imag], dim=1))))
        y_re, y_im = torch.chunk(y, 2, dim=1)
        if self.spectral is SpectralBackend.MATMUL:
            return irfft2_ortho(y_re, y_im, width, basis)
        return torch.fft.irfft2(torch.complex(y_re, y_im), s=(height, width), norm="ortho")


class SpectralTransform(nn.Module):
    """LaMa's global-to-global path: 1x1 reduction, Fourier unit with a residual, 1x1 expansion."""

    def __init__(self, in_channels: int, out_channels: int, spectral: SpectralBackend):
        super().__init__()
        hidden = max(out_channels // 2, 1)
        self.reduce = nn.Sequential(nn.Conv2d(in_channels, hidden, 1, bias=False), nn.BatchNorm2d(hidden),
                                    nn.ReLU(inplace=True))
        self.fourier = FourierUnit(hidden, hidden, spectral)
        self.expand = nn.Conv2d(hidden, out_channels, 1, bias=False)

    def forward(self, x: torch.Tensor, basis: Optional[DftBasis] = None) -> torch.Tensor:
        x = self.reduce(x)
        return self.expand(x + self.fourier(x, basis))


class FFC(nn.Module):
    """Fast Fourier convolution with BN and ReLU on ``(local, global)`` channel groups of equal sizes in and
    out: ``local' = l2l(local) + g2l(global)``, ``global' = l2g(local) + spectral(global)``."""

    def __init__(self, local_channels: int, global_channels: int, spectral: SpectralBackend):
        super().__init__()

        def conv3(cin: int, cout: int) -> nn.Conv2d:
            return nn.Conv2d(cin, cout, 3, padding=1, padding_mode="reflect", bias=False)

        self.l2l = conv3(local_channels, local_channels)
        self.g2l = conv3(global_channels, local_channels)
        self.l2g = conv3(local_channels, global_channels)
        self.g2g = SpectralTransform(global_channels, global_channels, spectral)
        self.norm_local = nn.BatchNorm2d(local_channels)
        self.norm_global = nn.BatchNorm2d(global_channels)
        self.act = nn.ReLU(inplace=True)

    def forward(self, local: torch.Tensor, global_: torch.Tensor, basis: Optional[DftBasis] = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        out_local = self.act(self.norm_local(self.l2l(local) + self.g2l(global_)))
        out_global = self.act(self.norm_global(self.l2g(local) + self.g2g(global_, basis)))
        return out_local, out_global


class FFCResBlock(nn.Module):
    """Two FFCs with a residual connection on both channel groups."""

    def __init__(self, local_channels: int, global_channels: int, spectral: SpectralBackend):
        super().__init__()
        self.first = FFC(local_channels, global_channels, spectral)
        self.second = FFC(local_channels, global_channels, spectral)

    def forward(self, local: torch.Tensor, global_: torch.Tensor, basis: Optional[DftBasis] = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        out_local, out_global = self.second(*self.first(local, global_, basis), basis)
        return local + out_local, global_ + out_global


class LamaGenerator(nn.Module):
    """The map predictor: ``[B, in_channels, H, W]`` float32 -> wall logits ``[B, 1, H, W]`` (see the module
    docstring for the layout and the size constraint)."""

    def __init__(self, cfg: LamaConfig = LamaConfig()):
        super().__init__()
        self.cfg = cfg
        channels = [min(cfg.base_channels * 2 ** i, cfg.max_channels) for i in range(cfg.n_downsample + 1)]
        self.stem = nn.Sequential(nn.ReflectionPad2d(3), nn.Conv2d(cfg.in_channels, channels[0], 7, bias=False),
                                  nn.BatchNorm2d(channels[0]), nn.ReLU(inplace=True))
        self.down = nn.Sequential(*[
            nn.Sequential(nn.Conv2d(channels[i], channels[i + 1], 3, stride=2, padding=1, bias=False),
                          nn.BatchNorm2d(channels[i + 1]), nn.ReLU(inplace=True))
            for i in range(cfg.n_downsample)])
        body = cfg.body_channels
        self.global_channels = int(round(body * cfg.global_ratio))
        self.local_channels = body - self.global_channels
        self.blocks = nn.ModuleList([FFCResBlock(self.local_channels, self.global_channels, cfg.spectral)
                                     for _ in range(cfg.n_blocks)])
        self.up = nn.Sequential(*[
            nn.Sequential(nn.ConvTranspose2d(channels[i + 1], channels[i], 3, stride=2, padding=1,
                                             output_padding=1, bias=False),
                          nn.BatchNorm2d(channels[i]), nn.ReLU(inplace=True))
            for i in reversed(range(cfg.n_downsample))])
        self.head = nn.Sequential(nn.ReflectionPad2d(3), nn.Conv2d(channels[0], 1, 7))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.down(self.stem(x))
        local, global_ = x[:, :self.local_channels], x[:, self.local_channels:]
        # One DFT basis for every Fourier unit (they all work at this resolution).
        basis = (dft_basis(x.shape[-2], x.shape[-1], x) if self.cfg.spectral is SpectralBackend.MATMUL
                 else None)
        for block in self.blocks:
            local, global_ = block(local, global_, basis)
        return self.head(self.up(torch.cat([local, global_], dim=1)))
