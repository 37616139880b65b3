"""Helpers shared by the networks."""

from __future__ import annotations

from typing import Iterable

import torch
from torch import nn

__all__ = ["count_parameters", "calibrate_batchnorm"]


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def calibrate_batchnorm(module: nn.Module, batches: Iterable[torch.Tensor]) -> nn.Module:
    """Reset every BatchNorm's running statistics to the plain average of the batch statistics over
    ``batches`` (forward passes in train mode, no gradients) and return the module in eval mode.

    A freshly initialised network's running statistics (mean 0, variance 1) do not match its activations, and
    its eval-mode output is then nearly constant; calibrated, it varies like a trained one's, which is what
    export parity checks need to be meaningful.
    """
    for layer in module.modules():
        if isinstance(layer, nn.modules.batchnorm._BatchNorm):
            layer.reset_running_stats()
            layer.momentum = None
    module.train()
    with torch.no_grad():
        for batch in batches:
            module(batch)
    return module.eval()
