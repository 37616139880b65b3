"""Localisation error of the simulated robot: the pose an :class:`~superex_deploy.messages.Observation` carries is the
truth plus an error, as a SLAM system's estimate is.

The model (:class:`PoseNoise` configures it, :class:`PoseErrorModel` runs it; deterministic for a seed):

* **Believed pose** ``b = t + d + j``: the true pose ``t = (x, y, yaw)`` plus a slowly drifting bias ``d`` plus white
  jitter ``j``.
* **Jitter** ``j``: drawn afresh for every observation, independent Gaussians ``N(0, sigma_xy^2)`` on ``x`` and on
  ``y`` (metres) and ``N(0, sigma_yaw^2)`` on the heading.
* **Drift** ``d``: a random walk in the distance driven, per axis independently (``x``, ``y`` in the map frame, and
  the heading). Over ``D`` metres without a bound its standard deviation grows as ``r sqrt(D)`` (``r``:
  :attr:`PoseNoise.drift_xy_per_m`, metres per square-root metre; :attr:`PoseNoise.drift_yaw_deg_per_m` for the
  heading): each move of ``delta`` metres adds ``N(0, r^2 delta)``, the step variance proportional to the metres
  driven, as odometry and scan-matching errors accumulate. A SLAM system does not drift without end: loop closures
  pull the estimate back onto its map. The bias is therefore bounded: it is an Ornstein-Uhlenbeck process in the
  distance driven, with stationary standard deviation ``B`` (:attr:`PoseNoise.max_drift_xy_m`) and correlation
  length ``L = 2 B^2 / r^2``; a move of ``delta`` metres gives ``d <- a d + B sqrt(1 - a^2) N(0, 1)`` with
  ``a = exp(-delta / L)``. Its variance after ``D`` metres from the start (where the map is anchored, ``d = 0``) is
  ``B^2 (1 - exp(-2 D / L))``: ``r^2 D`` for short distances, never above ``B^2``.
* **Covariance**: the observation carries ``diag(sigma_xy^2 + var_d, sigma_xy^2 + var_d, sigma_yaw^2 + var_yaw)``
  (:class:`~superex_deploy.messages.PoseCovariance`), the model's own variance of the error at the distance driven
  (what a SLAM system's covariance estimates), not the error actually drawn.

Defaults (:meth:`PoseNoise.from_sigmas`, what ``--pose-noise SIGMA_M,SIGMA_DEG`` builds): the drift rate is
:data:`DRIFT_FRACTION_PER_SQRT_M` (0.2) of the jitter per square-root metre and the bound ``B = sqrt(3) sigma``, so
the whole error's standard deviation never exceeds ``2 sigma`` (``sqrt(sigma^2 + 3 sigma^2)``): a good SLAM system
stays within about two of its jitter's sigmas. At 5 cm: ``r = 1 cm / sqrt(m)``, ``B = 8.7 cm``, ``L = 150 m``; after
the 150 m of a 500-step episode (0.3 m per step) the drift's standard deviation is 8.1 cm and the error's 9.5 cm
(1.9 sigma).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_int, check_real
from superex_deploy.messages import Pose2D, PoseCovariance

__all__ = ["PoseNoise", "PoseErrorModel", "DRIFT_FRACTION_PER_SQRT_M", "DRIFT_BOUND_SIGMAS"]

DRIFT_FRACTION_PER_SQRT_M = 0.2
"""Default drift rate as a fraction of the jitter's sigma per square-root metre driven (:meth:`PoseNoise.from_sigmas`)."""
DRIFT_BOUND_SIGMAS = math.sqrt(3.0)
"""Default bound of the drift's standard deviation, in jitter sigmas: with it the error's standard deviation stays
below two sigmas."""
_STREAM = 0x706F7365  # "pose": keeps this generator's stream apart from the other noise sources of one seed


def _non_negative(name: str, value, allow_inf: bool = False) -> float:
    """``value`` as a finite float >= 0 (or ``inf`` with ``allow_inf``), named ``PoseNoise.NAME`` in the error."""
    if allow_inf and not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.floating)) \
            and value == math.inf:
        return math.inf
    return check_real(f"PoseNoise.{name}", value, 0.0)


@dataclass(frozen=True)
class PoseNoise(JsonConfig):
    """Localisation error of the simulated robot (see the module docstring for the model).

    Attributes:
        sigma_xy_m: standard deviation of the white jitter on ``x`` and on ``y`` (metres).
        sigma_yaw_deg: standard deviation of the white jitter on the heading (degrees).
        drift_xy_per_m: drift rate of the position bias (metres per square-root metre driven: over ``D`` metres an
            unbounded drift has standard deviation ``drift_xy_per_m * sqrt(D)`` per axis).
        drift_yaw_deg_per_m: drift rate of the heading bias (degrees per square-root metre driven).
        seed: seed of the error's random generator.
        max_drift_xy_m: bound ``B`` of the position bias (its stationary standard deviation, metres); None:
            ``sqrt(3) * sigma_xy_m`` (``inf`` when ``sigma_xy_m`` is 0), ``inf``: an unbounded random walk.
        max_drift_yaw_deg: the same for the heading bias (degrees).
    """

    sigma_xy_m: float = 0.0
    sigma_yaw_deg: float = 0.0
    drift_xy_per_m: float = 0.0
    drift_yaw_deg_per_m: float = 0.0
    seed: int = 0
    max_drift_xy_m: Optional[float] = None
    max_drift_yaw_deg: Optional[float] = None

    def __post_init__(self) -> None:
        for name in ("sigma_xy_m", "sigma_yaw_deg", "drift_xy_per_m", "drift_yaw_deg_per_m"):
            object.__setattr__(self, name, _non_negative(name, getattr(self, name)))
        for name in ("max_drift_xy_m", "max_drift_yaw_deg"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _non_negative(name, getattr(self, name), allow_inf=True))
        object.__setattr__(self, "seed", check_int("PoseNoise.seed", self.seed, 0))

    @classmethod
    def from_sigmas(cls, sigma_xy_m: float, sigma_yaw_deg: float, seed: int = 0) -> "PoseNoise":
        """The default model of a localisation with jitter ``sigma_xy_m`` / ``sigma_yaw_deg``: drift at
        :data:`DRIFT_FRACTION_PER_SQRT_M` of the jitter per square-root metre, bounded at
        :data:`DRIFT_BOUND_SIGMAS` jitter sigmas."""
        sigma_xy_m = _non_negative("sigma_xy_m", sigma_xy_m)
        sigma_yaw_deg = _non_negative("sigma_yaw_deg", sigma_yaw_deg)
        return cls(sigma_xy_m=sigma_xy_m, sigma_yaw_deg=sigma_yaw_deg,
                   drift_xy_per_m=DRIFT_FRACTION_PER_SQRT_M * sigma_xy_m,
                   drift_yaw_deg_per_m=DRIFT_FRACTION_PER_SQRT_M * sigma_yaw_deg, seed=seed,
                   max_drift_xy_m=DRIFT_BOUND_SIGMAS * sigma_xy_m, max_drift_yaw_deg=DRIFT_BOUND_SIGMAS * sigma_yaw_deg)

    @property
    def drift_bound_xy_m(self) -> float:
        """The position bias's bound ``B`` in use (metres; ``inf``: unbounded)."""
        return _bound(self.max_drift_xy_m, self.sigma_xy_m)

    @property
    def drift_bound_yaw_deg(self) -> float:
        """The heading bias's bound in use (degrees; ``inf``: unbounded)."""
        return _bound(self.max_drift_yaw_deg, self.sigma_yaw_deg)

    def drift_variance(self, distance_m: float) -> tuple[float, float]:
        """The model's variance of the position bias (per axis, m^2) and of the heading bias (rad^2) after
        ``distance_m`` metres driven from the start."""
        distance_m = max(float(distance_m), 0.0)
        xy = _drift_variance(self.drift_xy_per_m, self.drift_bound_xy_m, distance_m)
        yaw = _drift_variance(math.radians(self.drift_yaw_deg_per_m), math.radians(self.drift_bound_yaw_deg),
                              distance_m)
        return xy, yaw


def _bound(given: Optional[float], sigma: float) -> float:
    if given is not None:
        return given
    return DRIFT_BOUND_SIGMAS * sigma if sigma > 0.0 else math.inf


def _drift_variance(rate: float, bound: float, distance_m: float) -> float:
    if rate == 0.0 or bound == 0.0:
        return 0.0
    if math.isinf(bound):
        return rate * rate * distance_m
    length = 2.0 * bound * bound / (rate * rate)
    return bound * bound * -math.expm1(-2.0 * distance_m / length)


def _drift_step(rng: np.random.Generator, bias: np.ndarray, rate: float, bound: float, metres: float) -> None:
    """Advance ``bias`` (float64 ``[k]``, in place) by ``metres`` driven (see the module docstring)."""
    noise = rng.standard_normal(bias.shape[0])
    if rate == 0.0 or bound == 0.0:
        return
    if math.isinf(bound):
        bias += rate * math.sqrt(metres) * noise
        return
    keep = math.exp(-metres * rate * rate / (2.0 * bound * bound))
    bias *= keep
    bias += bound * math.sqrt(max(0.0, 1.0 - keep * keep)) * noise


class PoseErrorModel:
    """The running localisation error of one episode (:class:`PoseNoise` configures it).

    Args:
        noise: the error model.

    Attributes:
        noise: as given.
        bias_xy_m: float64 ``[2]`` the current position bias (metres, map frame).
        bias_yaw_rad: the current heading bias (radians).
        distance_m: metres driven so far (the drift's clock).
    """

    def __init__(self, noise: PoseNoise):
        if not isinstance(noise, PoseNoise):
            raise ValueError(f"noise must be a PoseNoise, got {type(noise).__name__}")
        self.noise = noise
        self._rng = np.random.default_rng([_STREAM, int(noise.seed)])
        self.bias_xy_m = np.zeros(2)
        self._bias_yaw = np.zeros(1)
        self.distance_m = 0.0

    @property
    def bias_yaw_rad(self) -> float:
        return float(self._bias_yaw[0])

    def drive(self, metres: float) -> None:
        """Let the bias drift over ``metres`` driven (>= 0; nothing happens for 0)."""
        metres = float(metres)
        if not (metres >= 0.0 and np.isfinite(metres)):
            raise ValueError(f"metres driven must be finite and >= 0, got {metres}")
        if metres == 0.0:
            return
        noise = self.noise
        _drift_step(self._rng, self.bias_xy_m, noise.drift_xy_per_m, noise.drift_bound_xy_m, metres)
        _drift_step(self._rng, self._bias_yaw, math.radians(noise.drift_yaw_deg_per_m),
                    math.radians(noise.drift_bound_yaw_deg), metres)
        self.distance_m += metres

    def covariance(self) -> PoseCovariance:
        """The error's covariance at the distance driven so far: jitter plus the drift's model variance."""
        drift_xy, drift_yaw = self.noise.drift_variance(self.distance_m)
        xy = self.noise.sigma_xy_m ** 2 + drift_xy
        yaw = math.radians(self.noise.sigma_yaw_deg) ** 2 + drift_yaw
        return PoseCovariance(np.diag([xy, xy, yaw]))

    def believe(self, truth: Pose2D) -> Pose2D:
        """The believed pose of the true pose ``truth``: truth + bias + fresh jitter (three draws per call)."""
        jitter = self._rng.standard_normal(3)
        x = truth.x + self.bias_xy_m[0] + self.noise.sigma_xy_m * jitter[0]
        y = truth.y + self.bias_xy_m[1] + self.noise.sigma_xy_m * jitter[1]
        yaw = truth.yaw + self._bias_yaw[0] + math.radians(self.noise.sigma_yaw_deg) * jitter[2]
        return Pose2D(x, y, math.remainder(yaw, 2.0 * math.pi))
