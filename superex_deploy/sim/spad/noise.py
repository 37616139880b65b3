"""Detector noise of the SPAD simulator (:class:`~superex_deploy.spad_types.SpadNoise`): Gaussian timing jitter, then
Poisson counts over the signal plus background; and the check that a noisy scan was given a random generator.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy import ndimage

from superex_deploy.spad_types import SpadConfig

# numpy's Poisson sampler refuses means above ~1e19; beyond this the normal approximation is exact to 1e-3.
_POISSON_NORMAL_ABOVE = 1e7


def check_noise_rng(cfg: SpadConfig, rng) -> Optional[np.random.Generator]:
    """The generator the noise draws from: None when ``cfg.noise`` is disabled, else ``rng``.

    Raises:
        ValueError: noise is enabled and ``rng`` is not a :class:`numpy.random.Generator` (a noisy scan must be
            reproducible).
    """
    if not cfg.noise.enabled:
        return None
    if rng is None:
        raise ValueError("noise is enabled: pass rng=numpy.random.default_rng(seed) so scans are reproducible")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def add_noise(histograms: np.ndarray, cfg: SpadConfig, rng: np.random.Generator) -> np.ndarray:
    """Noisy counts of the noise-free histograms (float64 ``[n_rays, n_bins]``): blurred along the bins by the
    timing jitter ``cfg.noise.jitter_s``, plus ``background_per_bin``, then drawn as Poisson counts (normal above
    ``1e7``, where numpy's Poisson sampler stops). float64, same shape."""
    jitter_bins = cfg.noise.jitter_s / cfg.bin_width_s
    if jitter_bins > 0.0:
        histograms = ndimage.gaussian_filter1d(histograms, jitter_bins, axis=1, mode="constant", truncate=4.0)
    mean = np.maximum(histograms, 0.0) + cfg.noise.background_per_bin
    small = mean <= _POISSON_NORMAL_ABOVE
    noisy = np.empty_like(mean)
    noisy[small] = rng.poisson(mean[small])
    large = mean[~small]
    noisy[~small] = np.maximum(np.rint(rng.normal(large, np.sqrt(large))), 0.0)
    return noisy
