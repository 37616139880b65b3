"""Noise of the simulated line-of-sight LiDAR (:class:`LidarNoise`, applied by :func:`noisy_ranges`).

Per ray, from the exact first-hit range ``r`` (metres; ``inf`` where the ray returns nothing within range):

* **range noise**: a return becomes ``r + N(0, sigma_m^2)`` (a 2-D time-of-flight LiDAR's range noise: 1-3 cm for
  the Hokuyo UST / SICK TiM class); a ray without a return stays without one;
* **spurious short return**, with probability ``spurious_prob``: a range drawn uniformly in ``[range_min, r)``
  (``[range_min, range_max)`` without a return): dust, a mixed pixel at an edge, a cross-talk pulse;
* **dropout**, with probability ``dropout_prob`` (drawn last, it wins over the two above): NaN, REP 117's "no
  measurement" (a black or specular surface, glass), which the mapper skips.

With noise the scan's ``range_min`` is :attr:`LidarNoise.range_min_m` (5 cm, the order of such scanners' minimum
range), so a return inside the robot's own cell is an invalid reading rather than a wall under the robot. Every scan
draws the same number of random values whatever the probabilities, from a generator of its own (deterministic for
a seed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_int, check_real

__all__ = ["LidarNoise", "noisy_ranges", "DEFAULT_DROPOUT_PROB", "DEFAULT_SPURIOUS_PROB"]

DEFAULT_DROPOUT_PROB = 0.01
"""Default dropout probability per ray (:meth:`LidarNoise.from_sigma`): about 1 % of a 2-D LiDAR's rays return
nothing indoors (dark, specular and glass surfaces)."""
DEFAULT_SPURIOUS_PROB = 0.001
"""Default probability of a spurious short return per ray (:meth:`LidarNoise.from_sigma`)."""
_STREAM = 0x6C696461  # "lida": keeps this generator's stream apart from the other noise sources of one seed


@dataclass(frozen=True)
class LidarNoise(JsonConfig):
    """Noise of the simulated LiDAR (see the module docstring).

    Attributes:
        sigma_m: standard deviation of the Gaussian range noise (metres, >= 0).
        dropout_prob: probability that a ray reads NaN (no measurement), in [0, 1).
        spurious_prob: probability of a spurious short return, in [0, 1).
        seed: seed of the noise's random generator.
        range_min_m: the scan's minimum valid range (metres, >= 0).
    """

    sigma_m: float = 0.0
    dropout_prob: float = 0.0
    spurious_prob: float = 0.0
    seed: int = 0
    range_min_m: float = 0.05

    def __post_init__(self) -> None:
        for name in ("sigma_m", "range_min_m"):
            object.__setattr__(self, name, check_real(f"LidarNoise.{name}", getattr(self, name), 0.0))
        for name in ("dropout_prob", "spurious_prob"):
            object.__setattr__(self, name, check_real(f"LidarNoise.{name}", getattr(self, name), 0.0, 1.0,
                                                      high_open=True))
        object.__setattr__(self, "seed", check_int("LidarNoise.seed", self.seed, 0))

    @classmethod
    def from_sigma(cls, sigma_m: float, seed: int = 0) -> "LidarNoise":
        """Range noise ``sigma_m`` with the default dropout and spurious-return rates
        (:data:`DEFAULT_DROPOUT_PROB`, :data:`DEFAULT_SPURIOUS_PROB`)."""
        return cls(sigma_m=sigma_m, dropout_prob=DEFAULT_DROPOUT_PROB, spurious_prob=DEFAULT_SPURIOUS_PROB, seed=seed)

    def generator(self) -> np.random.Generator:
        """A fresh generator of this noise's stream (one per episode)."""
        return np.random.default_rng([_STREAM, int(self.seed)])


def noisy_ranges(ranges_m: np.ndarray, noise: LidarNoise, range_max_m: float,
                 rng: np.random.Generator) -> np.ndarray:
    """The noisy ranges of exact ones.

    Args:
        ranges_m: float ``[N]`` exact first-hit ranges (metres, ``inf`` where no return).
        noise: the noise model.
        range_max_m: the scanner's maximum range (metres; spurious returns of rays without a return lie below it).
        rng: the episode's generator (:meth:`LidarNoise.generator`); four ``[N]`` draws per call.

    Returns:
        float32 ``[N]`` ranges (metres; ``inf`` no return, NaN dropout).
    """
    exact = np.asarray(ranges_m, np.float64)
    if exact.ndim != 1 or np.any(np.isnan(exact)) or np.any(exact < 0.0):
        raise ValueError("ranges_m must be a 1-D array of non-negative ranges (inf: no return)")
    n = exact.shape[0]
    gauss = rng.standard_normal(n)
    spurious_draw, spurious_at, dropout_draw = rng.random(n), rng.random(n), rng.random(n)
    out = exact + noise.sigma_m * gauss  # inf stays inf: no return
    low = noise.range_min_m
    high = np.where(np.isfinite(exact), exact, float(range_max_m))
    spurious = (spurious_draw < noise.spurious_prob) & (high > low)
    out[spurious] = low + spurious_at[spurious] * (high[spurious] - low)
    out[dropout_draw < noise.dropout_prob] = np.nan
    return out.astype(np.float32)
