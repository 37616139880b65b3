"""Losses of the two networks.

Walls are rare: in a back-projection window fewer than 1 % of the cells reflect late photons, in a floor plan
about 5-10 % of the cells are walls. An unweighted per-pixel loss is then minimised by a nearly blank output (for
L1 the best constant prediction is the median, i.e. 0), so every reconstruction loss here weighs wall cells by
``wall_weight``: with ``w`` the gradient at a wall cell is ``w`` times that at a free cell with the same error,
and ``w = n_free / n_wall`` balances the two classes exactly.

All reconstruction losses are weighted means: ``sum(weight * loss) / sum(weight)``, where ``weight`` is
``wall_weight`` on walls, 1 elsewhere, times an optional ``mask`` (cells the loss is defined on, e.g. inside the
map); they are therefore independent of the image size.
"""

from __future__ import annotations

from typing import Optional

import torch
import torch.nn.functional as F

__all__ = ["wall_weights", "wall_weighted_l1", "wall_weighted_bce", "soft_dice_loss", "gan_loss"]


def wall_weights(target: torch.Tensor, wall_weight: float, mask: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Per-cell weights: ``wall_weight`` where ``target > 0.5``, 1 elsewhere, times ``mask`` if given.

    Args:
        target: float ``[B, 1, H, W]`` wall labels in {0, 1}.
        wall_weight: weight of a wall cell relative to a free one (> 0).
        mask: optional float ``[B, 1, H, W]`` in [0, 1]; 0 removes a cell from the loss.
    """
    if not wall_weight > 0:
        raise ValueError(f"wall_weight must be > 0, got {wall_weight}")
    weights = torch.where(target > 0.5, torch.full_like(target, float(wall_weight)), torch.ones_like(target))
    if mask is not None:
        if mask.shape != target.shape:
            raise ValueError(f"mask has shape {tuple(mask.shape)}, target has {tuple(target.shape)}")
        weights = weights * mask
    return weights


def _weighted_mean(values: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    return (values * weights).sum() / weights.sum().clamp_min(1e-12)


def wall_weighted_l1(probability: torch.Tensor, target: torch.Tensor, wall_weight: float,
                     mask: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Weighted mean of ``|probability - target|`` (see the module docstring). Shapes ``[B, 1, H, W]``."""
    if probability.shape != target.shape:
        raise ValueError(f"probability has shape {tuple(probability.shape)}, target has {tuple(target.shape)}")
    return _weighted_mean((probability - target).abs(), wall_weights(target, wall_weight, mask))


def wall_weighted_bce(logits: torch.Tensor, target: torch.Tensor, wall_weight: float, focal_gamma: float = 0.0,
                      mask: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Weighted mean of the binary cross-entropy of ``sigmoid(logits)`` against ``target``, optionally focal.

    With ``focal_gamma > 0`` each cell's term is multiplied by ``(1 - p_t) ** focal_gamma`` (Lin et al. 2017),
    ``p_t`` being the probability given to the true class, so confidently right cells stop dominating.

    Args:
        logits: float ``[B, 1, H, W]``.
        target: float ``[B, 1, H, W]`` in {0, 1}.
        wall_weight: see :func:`wall_weights`.
        focal_gamma: focusing exponent (>= 0; 0 is plain weighted BCE).
        mask: optional float ``[B, 1, H, W]``.
    """
    if logits.shape != target.shape:
        raise ValueError(f"logits have shape {tuple(logits.shape)}, target has {tuple(target.shape)}")
    if not focal_gamma >= 0:
        raise ValueError(f"focal_gamma must be >= 0, got {focal_gamma}")
    per_cell = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    if focal_gamma > 0:
        p_true = torch.exp(-per_cell)  # exp(-BCE) is the probability of the true class
        per_cell = per_cell * (1.0 - p_true) ** focal_gamma
    return _weighted_mean(per_cell, wall_weights(target, wall_weight, mask))


def soft_dice_loss(probability: torch.Tensor, target: torch.Tensor, mask: Optional[torch.Tensor] = None,
                   smooth: float = 1.0) -> torch.Tensor:
    """``1 - Dice`` of the wall probabilities against the labels, pooled over the whole batch (Milletari et
    al. 2016): ``1 - (2 sum(p y) + smooth) / (sum(p) + sum(y) + smooth)`` over the cells of ``mask``.

    Pooled rather than per image, as the filter's IoU is scored: windows without hidden walls then neither
    dominate nor vanish. Class imbalance needs no weight here (both sums count walls only). Shapes
    ``[B, 1, H, W]``; ``smooth`` (cells) keeps the loss defined when neither predicts nor holds a wall.
    """
    if probability.shape != target.shape:
        raise ValueError(f"probability has shape {tuple(probability.shape)}, target has {tuple(target.shape)}")
    if mask is not None:
        if mask.shape != target.shape:
            raise ValueError(f"mask has shape {tuple(mask.shape)}, target has {tuple(target.shape)}")
        probability, target = probability * mask, target * mask
    if not smooth > 0:
        raise ValueError(f"smooth must be > 0, got {smooth}")
    overlap = (probability * target).sum()
    return 1.0 - (2.0 * overlap + smooth) / (probability.sum() + target.sum() + smooth)


def gan_loss(discriminator_logits: torch.Tensor, real: bool) -> torch.Tensor:
    """Pix2Pix's adversarial loss: BCE of the patch logits against all-real (1) or all-fake (0) labels."""
    labels = torch.ones_like(discriminator_logits) if real else torch.zeros_like(discriminator_logits)
    return F.binary_cross_entropy_with_logits(discriminator_logits, labels)
