"""The SPAD LiDAR's sensor model and its histograms: what the simulator writes and the onboard processing reads.

Shared by both sides: no ground truth here (a :class:`SpadScan` from the simulator carries the simulator's truth in
:attr:`SpadScan.truth`, described by :class:`ScanTruth`; a measured one carries None).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Optional, Protocol, Union

import numba
import numpy as np

from superex_deploy.configs import JsonConfig

__all__ = ["SpadNoise", "SpadConfig", "PhotonBudget", "SPAD_PRESETS", "spad_preset", "SparseHistograms", "ScanTruth",
           "SpadScan", "SPEED_OF_LIGHT", "PLANCK"]

SPEED_OF_LIGHT = 299_792_458.0  # m/s
PLANCK = 6.626_070_15e-34  # J s


def _real(name: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    return float(value)


def _check_reals(owner: str, obj, names, positive: bool = False) -> None:
    """Each field ``names`` of ``obj`` a finite real number, ``>= 0`` (or ``> 0`` with ``positive``)."""
    for name in names:
        value = _real(f"{owner}.{name}", getattr(obj, name))
        if not (np.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
            raise ValueError(f"{owner}.{name} must be {'positive and finite' if positive else 'finite and >= 0'}, "
                             f"got {value}")


@dataclass(frozen=True)
class SpadNoise(JsonConfig):
    """Detector noise. Disabled by default (the paper simulates noise-free histograms).

    Attributes:
        enabled: draw Poisson counts and add the background below.
        ambient_per_bin: mean ambient-light photon counts per bin.
        dark_per_bin: mean dark counts per bin.
        jitter_s: standard deviation of the Gaussian timing jitter (seconds), applied before Poisson sampling.
    """

    enabled: bool = False
    ambient_per_bin: float = 1.0
    dark_per_bin: float = 0.01
    jitter_s: float = 50e-12

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise ValueError(f"SpadNoise.enabled must be a bool, got {self.enabled!r}")
        _check_reals("SpadNoise", self, ("ambient_per_bin", "dark_per_bin", "jitter_s"))

    @property
    def background_per_bin(self) -> float:
        """Mean background counts per bin (ambient + dark)."""
        return self.ambient_per_bin + self.dark_per_bin if self.enabled else 0.0


@dataclass(frozen=True)
class SpadConfig(JsonConfig):
    """SPAD LiDAR parameters.

    Attributes:
        n_rays: primary rays over 360 degrees.
        range_m: maximum range of primary and secondary rays (metres).
        bin_width_s: histogram bin width (seconds); see :attr:`bin_path_m`.
        n_secondary: secondary rays per wall hit, spread over [-90, 90] degrees about the normal. The carving's
            radius cap grows with it (``onboard.nlos.carve_radius_cap_m``: 8.1 m at 256, 2.0 m at 64): 256 rays
            carve more than 64 (docs/benchmarks/spad.md, "Carving nearer its bound") and cost the simulator 2-3x
            the time per scan with the fan cache (benchmarks/carving/). The count shapes the histograms (4x the
            late photons of 64 rays, about 2x the non-zero late bins), so the Pix2Pix filter and LaMa-BP are
            trained on scans of this default (``scripts/train_models.sh``).
        reflectance: Lambertian surface reflectance rho in (0, 1].
        detector_efficiency: photon detection efficiency alpha in (0, 1].
        pulse_energy_j: laser pulse energy E (joules).
        wavelength_m: laser wavelength lambda (metres; 905 nm, a common LiDAR diode).
        noise: detector noise model.
    """

    n_rays: int = 2500
    range_m: float = 20.0
    bin_width_s: float = 0.1 / SPEED_OF_LIGHT
    n_secondary: int = 256
    reflectance: float = 0.5
    detector_efficiency: float = 0.3
    pulse_energy_j: float = 1e-9
    wavelength_m: float = 905e-9
    noise: SpadNoise = field(default_factory=SpadNoise)

    def __post_init__(self) -> None:
        for name in ("n_rays", "n_secondary"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"SpadConfig.{name} must be a positive integer, got {value!r}")
        for name in ("range_m", "bin_width_s", "pulse_energy_j", "wavelength_m"):
            value = _real(f"SpadConfig.{name}", getattr(self, name))
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"SpadConfig.{name} must be positive and finite, got {value}")
        for name in ("reflectance", "detector_efficiency"):
            value = _real(f"SpadConfig.{name}", getattr(self, name))
            if not (np.isfinite(value) and 0.0 < value <= 1.0):
                raise ValueError(f"SpadConfig.{name} must lie in (0, 1], got {value}")
        if not isinstance(self.noise, SpadNoise):
            raise ValueError(f"SpadConfig.noise must be a SpadNoise, got {type(self.noise).__name__}")
        if not np.isfinite(self.direct_counts):
            raise ValueError(f"SpadConfig.pulse_energy_j = {self.pulse_energy_j} J gives an infinite photon count")
        if self.n_bins > 200_000:
            raise ValueError(f"SpadConfig gives {self.n_bins} bins (4 * range_m / bin_path_m); widen the bins")

    @property
    def bin_path_m(self) -> float:
        """Round-trip path length covered by one bin (metres): ``c * bin_width_s``."""
        return SPEED_OF_LIGHT * self.bin_width_s

    @property
    def n_bins(self) -> int:
        """Bins covering the longest three-bounce path, ``4 * range_m``."""
        return int(np.ceil(4.0 * self.range_m / self.bin_path_m)) + 1

    @property
    def photons_per_joule(self) -> float:
        """``lambda / (h c)``."""
        return self.wavelength_m / (PLANCK * SPEED_OF_LIGHT)

    @property
    def direct_counts(self) -> float:
        """Eq. (1): photons of the direct return, ``alpha E rho / pi * lambda / (h c)``."""
        return (self.detector_efficiency * self.pulse_energy_j * self.reflectance / np.pi
                * self.photons_per_joule)

    def three_bounce_scale(self, resolution_m: float) -> float:
        """Eq. (2) without its geometric factor: ``E rho^3 s^2 alpha / pi^3 * lambda / (h c)``; multiply by
        ``cos(theta1) cos(theta2) / (d1 d2^2)`` (metres) for one secondary ray."""
        return (self.pulse_energy_j * self.reflectance ** 3 * resolution_m ** 2 * self.detector_efficiency
                / np.pi ** 3 * self.photons_per_joule)


@dataclass(frozen=True)
class PhotonBudget(JsonConfig):
    """A SPAD LiDAR's photon budget in physical units, turned into the simulator's sensor model
    (:meth:`sensor`): the signal's scale (the model's pulse energy) and the noise (:class:`SpadNoise`).

    The model's eqs. (1) and (2) (see :class:`SpadConfig`) count the photons of one pulse returned by Lambertian
    walls, without the receiver: no aperture and no fall-off of the last bounce towards the detector. A real
    receiver of aperture ``A`` collects the fraction ``A / d^2`` (a solid angle) of what a wall at ``d`` returns
    towards it, and a histogram accumulates ``n`` pulses. The budget therefore sets the model's pulse energy to
    ``E n A / d_ref^2``: eq. (1) is then the direct return's detected photons of a wall at ``d_ref``, and eq. (2)
    scales with it. Background counts per bin: ``(ambient_rate + dark_count_rate) * bin_width * n``.

    Attributes:
        pulse_energy_j: energy of one laser pulse (joules).
        pulses_per_histogram: laser pulses accumulated in one ray's histogram.
        aperture_m2: receiver aperture area (square metres).
        reference_range_m: range at which the receiver's collection is evaluated (metres).
        ambient_rate_hz: ambient-light photon detections per second, after the optical band-pass filter.
        dark_count_rate_hz: the SPAD's dark count rate (counts per second).
        jitter_s: timing jitter (RMS seconds) of laser pulse, SPAD and time-to-digital converter together.
    """

    pulse_energy_j: float
    pulses_per_histogram: int
    aperture_m2: float
    reference_range_m: float
    ambient_rate_hz: float
    dark_count_rate_hz: float
    jitter_s: float

    def __post_init__(self) -> None:
        if isinstance(self.pulses_per_histogram, (bool, np.bool_)) or \
                not isinstance(self.pulses_per_histogram, (int, np.integer)) or self.pulses_per_histogram < 1:
            raise ValueError(f"PhotonBudget.pulses_per_histogram must be a positive integer, got "
                             f"{self.pulses_per_histogram!r}")
        _check_reals("PhotonBudget", self, ("pulse_energy_j", "aperture_m2", "reference_range_m"), positive=True)
        _check_reals("PhotonBudget", self, ("ambient_rate_hz", "dark_count_rate_hz", "jitter_s"))

    @property
    def model_pulse_energy_j(self) -> float:
        """The model's pulse energy ``E n A / d_ref^2`` (joules)."""
        return (self.pulse_energy_j * self.pulses_per_histogram * self.aperture_m2
                / self.reference_range_m ** 2)

    def noise(self, bin_width_s: float) -> SpadNoise:
        """The detector noise of histograms with bins ``bin_width_s`` seconds wide."""
        exposure = bin_width_s * self.pulses_per_histogram
        return SpadNoise(enabled=True, ambient_per_bin=self.ambient_rate_hz * exposure,
                         dark_per_bin=self.dark_count_rate_hz * exposure, jitter_s=self.jitter_s)

    def sensor(self, base: Optional["SpadConfig"] = None) -> "SpadConfig":
        """``base`` (default :class:`SpadConfig`) with this budget's pulse energy and noise."""
        base = SpadConfig() if base is None else base
        return replace(base, pulse_energy_j=self.model_pulse_energy_j, noise=self.noise(base.bin_width_s))


SPAD_PRESETS: dict[str, Optional[PhotonBudget]] = {
    "off": None,
    "realistic": PhotonBudget(pulse_energy_j=50e-9, pulses_per_histogram=400, aperture_m2=1e-4,
                              reference_range_m=5.0, ambient_rate_hz=1e5, dark_count_rate_hz=1e3, jitter_s=80e-12),
    "low": PhotonBudget(pulse_energy_j=5e-9, pulses_per_histogram=100, aperture_m2=0.5e-4,
                        reference_range_m=5.0, ambient_rate_hz=5e6, dark_count_rate_hz=1e4, jitter_s=250e-12),
}
"""Named photon budgets, from ideal to low light (``--spad-noise``); orders of magnitude of SPAD LiDAR datasheets
and NLOS set-ups:

* ``off``: the paper's noise-free model (:class:`SpadConfig` as it is: 1 nJ, no background, no jitter).
* ``realistic``: a picosecond-pulsed 905 nm laser of 0.5 W average at 10 MHz (50 nJ per pulse), 400 pulses per ray
  (the 40 microseconds a ray gets when 2,500 rays share a 0.1 s step), a 1 cm^2 receiver (11 mm aperture), indoor
  ambient light through a narrow band-pass filter (1e5 detections per second), a room-temperature SPAD's dark
  count rate (1 kHz) and 80 ps RMS jitter (SPAD, laser and TDC). Model pulse energy 8e-11 J (0.08 of the paper's),
  background 0.013 counts per 0.1 m bin; a three-bounce return of a wall 5 m away seen 3 m behind the corner still
  holds tens of photons, one 10 m away and 8 m behind a few.
* ``low``: an eye-safe, low-power diode (5 nJ), 100 pulses per ray, a 0.5 cm^2 receiver, daylight through the
  windows leaking through the filter (5e6 per second), a warm detector (10 kHz) and 250 ps jitter (a nanosecond
  diode's pulse edge). Model pulse energy 1e-12 J (0.001 of the paper's), background 0.17 counts per bin: only
  nearby hidden walls stay above the detection threshold.

The onboard detection threshold follows the preset: the sensor model (:class:`SpadConfig`, the same on both
sides) carries the background, from which the NLOS processing sets its late-bin threshold at its false-alarm rate
(``superex_deploy.onboard.nlos.los``). Not modelled: SPAD pile-up and dead time (the direct return's photons would
saturate a single SPAD; the processing reads the earliest detection, which pile-up moves earlier, not later).
"""


def spad_preset(name: str, base: Optional["SpadConfig"] = None) -> "SpadConfig":
    """The sensor model of the preset ``name`` of :data:`SPAD_PRESETS`, on ``base`` (default :class:`SpadConfig`).

    Raises:
        ValueError: an unknown name.
    """
    if name not in SPAD_PRESETS:
        raise ValueError(f"unknown SPAD noise preset {name!r}; choose from {', '.join(SPAD_PRESETS)}")
    budget = SPAD_PRESETS[name]
    base = SpadConfig() if base is None else base
    return base if budget is None else budget.sensor(base)


@numba.njit(cache=True)
def _sparse_to_dense(row_start, bins, counts, out):
    for i in range(row_start.shape[0] - 1):
        for j in range(row_start[i], row_start[i + 1]):
            out[i, bins[j]] = counts[j]


@numba.njit(cache=True)
def _dense_to_sparse(histograms, threshold):
    n_rays, n_bins = histograms.shape
    row_start = np.zeros(n_rays + 1, np.int64)
    for i in range(n_rays):
        n = 0
        for b in range(n_bins):
            if histograms[i, b] > threshold:
                n += 1
        row_start[i + 1] = row_start[i] + n
    bins = np.empty(row_start[n_rays], np.int32)
    counts = np.empty(row_start[n_rays], np.float32)
    for i in range(n_rays):
        j = row_start[i]
        for b in range(n_bins):
            if histograms[i, b] > threshold:
                bins[j] = b
                counts[j] = histograms[i, b]
                j += 1
    return row_start, bins, counts


@dataclass(frozen=True, eq=False)
class SparseHistograms:
    """Histograms stored by their non-zero bins, ray by ray (compressed sparse rows).

    A noise-free SPAD histogram has at most ``1 + n_secondary`` non-zero bins of ``n_bins`` (257 of 801 at the
    defaults): the simulator writes this form and the NLOS processing reads it, neither touches the zeros.

    Attributes:
        row_start: int64 ``[n_rays + 1]``; ray ``i``'s entries are ``row_start[i]:row_start[i + 1]``.
        bins: int32 ``[nnz]`` bin indices, strictly increasing within a ray, in ``[0, n_bins)``.
        counts: float32 ``[nnz]`` photon counts of those bins.
        n_bins: bins per ray.
    """

    row_start: np.ndarray
    bins: np.ndarray
    counts: np.ndarray
    n_bins: int

    @property
    def n_rays(self) -> int:
        return self.row_start.shape[0] - 1

    def to_dense(self) -> np.ndarray:
        """float32 ``[n_rays, n_bins]``."""
        out = np.zeros((self.n_rays, self.n_bins), np.float32)
        _sparse_to_dense(self.row_start, self.bins, self.counts, out)
        return out

    @classmethod
    def from_dense(cls, histograms: np.ndarray, threshold: float = 0.0) -> "SparseHistograms":
        """The bins of float32 ``[n_rays, n_bins]`` ``histograms`` whose count exceeds ``threshold``."""
        histograms = np.asarray(histograms)
        if histograms.dtype != np.float32 or histograms.ndim != 2:
            raise ValueError(f"histograms must be float32 [n_rays, n_bins], got {histograms.dtype} "
                             f"{histograms.shape}")
        row_start, bins, counts = _dense_to_sparse(np.ascontiguousarray(histograms), float(threshold))
        return cls(row_start, bins, counts, histograms.shape[1])


class ScanTruth(Protocol):
    """What the simulator's ground truth of a scan carries (the simulator's own type provides more; labels and tests
    read it, the NLOS processing never does)."""

    @property
    def h1_rc(self) -> np.ndarray:
        """int32 ``[n_rays, 2]`` first wall cell of each primary ray, -1 where none within range."""
        ...

    @property
    def d1_m(self) -> np.ndarray:
        """float64 ``[n_rays]`` distance to ``h1`` (metres; NaN where no hit)."""
        ...

    @property
    def h2_rc(self) -> np.ndarray:
        """int32 ``[M, 2]``: the cell every three-bounce path reflected from (its secondary hit)."""
        ...

    @property
    def h2_counts(self) -> np.ndarray:
        """float64 ``[M]``: expected photons of every three-bounce path (aligned with :attr:`h2_rc`)."""
        ...


@dataclass(frozen=True, eq=False)
class SpadScan:
    """One SPAD scan.

    The counts are held in the form they were made in: sparse for the noise-free model (what the simulator
    writes), dense for noisy scans, whose background fills every bin. :attr:`histograms` and :attr:`sparse` give
    either form, converting once on first access.

    Attributes:
        angles: float64 ``[n_rays]`` ray angles (radians; ``superex_deploy.geometry`` convention).
        origin_yx: sensor position (cells): the centre of ``pose_rc``.
        pose_rc: robot cell (row, col).
        bin_path_m: round-trip path per bin (metres).
        resolution_m: grid resolution (metres per cell).
        grid_shape: ``(rows, cols)`` of the map the scan was taken in.
        config: the sensor configuration.
        stored: the counts as made: :class:`SparseHistograms`, or float32 ``[n_rays, n_bins]``.
        truth: the simulator's truth (see :class:`ScanTruth`), None on measured scans (the onboard explorer
            builds its scans from :class:`~superex_deploy.messages.SpadFrame` messages, which carry none).
    """

    angles: np.ndarray
    origin_yx: tuple[float, float]
    pose_rc: tuple[int, int]
    bin_path_m: float
    resolution_m: float
    grid_shape: tuple[int, int]
    config: SpadConfig
    stored: Union[SparseHistograms, np.ndarray]
    truth: Optional[ScanTruth] = None

    @property
    def n_bins(self) -> int:
        return self.stored.n_bins if self.is_sparse else self.stored.shape[1]

    @property
    def is_sparse(self) -> bool:
        """True when the counts are held sparse (reading :attr:`sparse` costs nothing)."""
        return isinstance(self.stored, SparseHistograms)

    @cached_property
    def histograms(self) -> np.ndarray:
        """float32 ``[n_rays, n_bins]`` photon counts per ray and time bin."""
        return self.stored.to_dense() if self.is_sparse else self.stored

    @cached_property
    def sparse(self) -> SparseHistograms:
        """The non-zero bins (:class:`SparseHistograms`)."""
        return self.stored if self.is_sparse else SparseHistograms.from_dense(self.stored, 0.0)

