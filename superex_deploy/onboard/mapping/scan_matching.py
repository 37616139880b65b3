"""Correlative scan-to-map matching: the believed pose corrected against the explorer's own map before a scan is
integrated (Olson 2009, "Real-time correlative scan matching"; the front end of Cartographer, Hector and Karto).

A localisation's pose is off by its error; a scan integrated at it smears walls across the map, and rays near their
ends cross true wall faces (the map then holds true walls free). Before integrating, :class:`ScanMatcher` searches a
window around the believed pose for the pose at which the scan's returns best fit the walls already in the map:

* **Likelihood field**: the map's occupied cells (line of sight, ``log_odds >= occupied_threshold``) become a smooth
  field ``exp(-d^2 / (2 s^2))``, ``d`` the Euclidean distance (cells) to the nearest occupied cell (``s``:
  :attr:`ScanMatchingConfig.field_sigma_m` in cells), computed on a crop around the robot. A pose's **fit** is the mean
  field value (bilinear) at the scan's returns placed from that pose: 1 when every return lies on a wall of the
  map, near 0 when none is near one.
* **Window**: ``+-window_sigmas`` standard deviations of the observation's pose covariance in ``x``, ``y`` and yaw
  (the covariance's diagonal), at least one cell and capped at ``max_window_m`` / ``max_window_deg``.
* **Coarse to fine**: every pose of the window's lattice (one cell; the yaw step that moves the farthest return by
  one cell) is scored on a wider field (``coarse_sigma_m``: wide basins, so the right pose need not lie on the
  lattice); from the ``starts`` best, hill-climbing on the narrow field over the 3 x 3 x 3 poses around the
  current one, at the lattice's steps and then ``refine_levels`` times at half the previous steps (1/8 cell at 3).
* **Prior**: the search maximises ``fit - prior_weight * m^2 / 2`` (``m``: the Mahalanobis distance of the offset
  under the covariance), so a scan that constrains a pose poorly (a corridor along its axis) stays near the belief.
* **Acceptance rule** (a wrong correction is worse than none): the corrected pose is used only when the map holds
  at least ``min_map_wall_m`` of occupied cells (their count times the cell size) near the robot, the scan has at least ``min_points`` returns, the best
  fit is at least ``min_fit`` and beats the fit at the believed pose by at least ``min_gain``, and the corrected
  cell is not held occupied; otherwise the believed pose is kept unchanged.

Without a pose covariance nothing is searched: the pose is exact, and the noise-free protocol is untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from superex_deploy.configs import JsonConfig
from superex_deploy.messages import LaserScan, MapFrame, Pose2D, PoseCovariance
from superex_deploy.onboard.checks import cells_at_least, in_cells

__all__ = ["ScanMatchingConfig", "ScanMatch", "ScanMatcher", "score_poses", "likelihood_field"]

_CLIMB_MOVES = 4
"""Hill-climbing moves per refinement level at most (a start is already near its optimum)."""
_FACE_TO_CENTRE_CELLS = 0.5
"""Added to each return's range (cells) before scoring: from the wall's face to its cell's centre, along the ray."""


@dataclass(frozen=True)
class ScanMatchingConfig(JsonConfig):
    """Parameters of the correlative scan matcher (see the module docstring; fixed on train floors).

    Attributes:
        enabled: match scans that come with a pose covariance (never without one).
        window_sigmas: half-width of the search window in standard deviations of the pose covariance.
        max_window_m: cap on the translational half-width (metres).
        max_window_deg: cap on the rotational half-width (degrees).
        field_sigma_m: smoothing ``s`` of the likelihood field the fit is read on (metres; one cell of 0.1 m).
        coarse_sigma_m: the wider field the lattice is scored on (metres).
        starts: the best lattice poses refined on the narrow field.
        max_points: returns used at most (evenly spaced over the scan), for speed.
        max_point_range_m: returns farther than this are not used (their angular leverage makes the yaw lattice
            fine, and far walls are the least certain in the map).
        min_points: fewer usable returns: no correction.
        min_map_wall_m: fewer occupied map cells in the field's crop than this many metres of them (their count
            times the cell size, about the length of wall seen; 50 cells of 0.1 m): no correction.
        min_fit: the best pose's fit must reach this.
        min_gain: ... and beat the believed pose's fit by this much.
        prior_weight: weight of the Mahalanobis prior (fit units per unit of ``m^2 / 2``). It trades a single
            match's accuracy for the map's anchoring: a weaker prior follows the map, a stronger one the belief.
            Fixed on train floors by the true walls the map holds free (measured in docs/on-a-robot.md, "What was
            tried").
        refine_levels: fine search levels after the lattice (each halves the steps).

    Fusing an accepted match with the belief and matching only after the first scans were measured and retired
    (docs/on-a-robot.md, "What was tried").
    """

    enabled: bool = True
    window_sigmas: float = 3.0
    max_window_m: float = 0.8
    max_window_deg: float = 10.0
    field_sigma_m: float = 0.1
    coarse_sigma_m: float = 0.2
    starts: int = 4
    max_points: int = 400
    max_point_range_m: float = 10.0
    min_points: int = 30
    min_map_wall_m: float = 5.0
    min_fit: float = 0.4
    min_gain: float = 0.02
    prior_weight: float = 0.01
    refine_levels: int = 3

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise ValueError(f"ScanMatchingConfig.enabled must be a bool, got {self.enabled!r}")
        for name in ("window_sigmas", "max_window_m", "max_window_deg", "field_sigma_m", "coarse_sigma_m",
                     "max_point_range_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not (np.isfinite(value) and value > 0):
                raise ValueError(f"ScanMatchingConfig.{name} must be a finite number > 0, got {value!r}")
        for name in ("min_fit", "min_gain", "prior_weight", "min_map_wall_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not (np.isfinite(value) and value >= 0):
                raise ValueError(f"ScanMatchingConfig.{name} must be a finite number >= 0, got {value!r}")
        for name, low in (("max_points", 1), ("starts", 1), ("min_points", 1), ("refine_levels", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"ScanMatchingConfig.{name} must be an integer >= {low}, got {value!r}")
        if self.min_points > self.max_points:
            raise ValueError(f"ScanMatchingConfig: min_points ({self.min_points}) exceeds max_points "
                             f"({self.max_points})")


@dataclass(frozen=True)
class ScanMatch:
    """One matching's outcome.

    Attributes:
        pose: the pose to integrate the scan at (the corrected one when ``accepted``, else the believed one).
        accepted: whether the correction passed the acceptance rule.
        fit: the best pose's fit (NaN when nothing was searched).
        believed_fit: the believed pose's fit (NaN when nothing was searched).
        reason: why not accepted ("" when accepted).
    """

    pose: Pose2D
    accepted: bool
    fit: float
    believed_fit: float
    reason: str


@numba.njit(cache=True)
def _score_poses(field, rho, angle, gy0, gx0, yaw0, offsets, scores):
    n_rows, n_cols = field.shape
    n = rho.shape[0]
    for k in range(offsets.shape[0]):
        yaw = yaw0 + offsets[k, 2]
        by, bx = gy0 + offsets[k, 0], gx0 + offsets[k, 1]
        total = 0.0
        for i in range(n):
            heading = yaw + angle[i]
            # Map frame y points up, the grid's rows down: the return's row offset is -rho sin.
            u = by - rho[i] * math.sin(heading) - 0.5
            v = bx + rho[i] * math.cos(heading) - 0.5
            r0, c0 = int(math.floor(u)), int(math.floor(v))
            if r0 < 0 or c0 < 0 or r0 + 1 >= n_rows or c0 + 1 >= n_cols:
                continue
            fu, fv = u - r0, v - c0
            total += ((1.0 - fu) * ((1.0 - fv) * field[r0, c0] + fv * field[r0, c0 + 1])
                      + fu * ((1.0 - fv) * field[r0 + 1, c0] + fv * field[r0 + 1, c0 + 1]))
        scores[k] = total / n


def score_poses(field: np.ndarray, rho_cells: np.ndarray, robot_angles: np.ndarray, origin_yx, yaw: float,
                offsets: np.ndarray) -> np.ndarray:
    """The fit of a scan at each candidate pose: the mean of ``field`` (bilinear between cell centres; 0 outside
    the grid's interior) at the returns placed from the pose.

    Args:
        field: float64 ``[H, W]`` likelihood field on the grid.
        rho_cells: float64 ``[N]`` return ranges (cells), N >= 1.
        robot_angles: float64 ``[N]`` return angles (radians, counter-clockwise from the heading).
        origin_yx: the base pose's grid position ``(y down, x right)`` in cells.
        yaw: the base pose's map-frame heading (radians, counter-clockwise).
        offsets: float64 ``[K, 3]`` candidate offsets ``(dy cells down, dx cells right, dyaw radians)``.

    Returns:
        float64 ``[K]`` fits in ``[0, 1]`` for a field in ``[0, 1]``.

    Raises:
        ValueError: bad dtype, shape or non-finite values.
    """
    field = np.ascontiguousarray(field, np.float64)
    rho = np.ascontiguousarray(rho_cells, np.float64).ravel()
    angles = np.ascontiguousarray(robot_angles, np.float64).ravel()
    offsets = np.ascontiguousarray(offsets, np.float64)
    if field.ndim != 2 or min(field.shape) < 2:
        raise ValueError(f"field must be [H, W] with H, W >= 2, got shape {field.shape}")
    if rho.shape != angles.shape or rho.shape[0] < 1:
        raise ValueError(f"rho_cells and robot_angles must be [N] of one length N >= 1, got {rho.shape} and "
                         f"{angles.shape}")
    if offsets.ndim != 2 or offsets.shape[1] != 3:
        raise ValueError(f"offsets must be [K, 3], got shape {offsets.shape}")
    values = (rho, angles, offsets, np.asarray([origin_yx[0], origin_yx[1], yaw], np.float64))
    if not all(np.all(np.isfinite(v)) for v in values):
        raise ValueError("score_poses needs finite ranges, angles, offsets and pose")
    scores = np.empty(offsets.shape[0], np.float64)
    _score_poses(field, rho, angles, float(origin_yx[0]), float(origin_yx[1]), float(yaw), offsets, scores)
    return scores


def likelihood_field(walls: np.ndarray, sigma_cells: float) -> np.ndarray:
    """float64 ``[H, W]`` ``exp(-d^2 / (2 sigma^2))`` with ``d`` the Euclidean distance (cells) from each cell's
    centre to the nearest ``True`` cell of bool ``[H, W]`` ``walls`` (all zeros without walls)."""
    return likelihood_fields(walls, (sigma_cells,))[0]


def likelihood_fields(walls: np.ndarray, sigmas_cells) -> list[np.ndarray]:
    """:func:`likelihood_field` for each of ``sigmas_cells``, from one distance transform."""
    walls = np.asarray(walls, bool)
    if not walls.any():
        return [np.zeros(walls.shape, np.float64) for _ in sigmas_cells]
    distance = distance_transform_edt(~walls)
    return [np.exp(-0.5 * (distance / float(sigma)) ** 2) for sigma in sigmas_cells]


def _lattice(half: float, step: float) -> np.ndarray:
    count = int(math.floor(half / step + 1e-9))
    return np.arange(-count, count + 1, dtype=np.float64) * step


class ScanMatcher:
    """Corrects believed poses against a map (see the module docstring).

    Args:
        cfg: the matcher's parameters.
    """

    def __init__(self, cfg: ScanMatchingConfig = ScanMatchingConfig()):
        if not isinstance(cfg, ScanMatchingConfig):
            raise ValueError(f"cfg must be a ScanMatchingConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self.scans_seen = 0  # scans offered to match() with a covariance

    def returns(self, scan: LaserScan, resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The usable returns of ``scan``: float64 ``[N]`` ranges (cells) and robot-frame angles (radians), at most
        ``max_points`` evenly spaced over the scan's valid returns within ``max_point_range_m``."""
        ranges = scan.ranges.astype(np.float64)
        ok = ~np.isnan(ranges) & (ranges >= scan.range_min) & (ranges < scan.range_max) \
            & (ranges <= self.cfg.max_point_range_m)
        index = np.flatnonzero(ok)
        if index.size > self.cfg.max_points:
            index = index[np.linspace(0, index.size - 1, self.cfg.max_points).round().astype(np.int64)]
        # A return lies on a wall's face, the map's wall cell half a cell beyond it: scored there, the truth is
        # not pulled half a cell towards the walls.
        return ranges[index] / resolution_m + _FACE_TO_CENTRE_CELLS, scan.angles()[index].astype(np.float64)

    def match(self, frame: MapFrame, walls: np.ndarray, pose: Pose2D, covariance: Optional[PoseCovariance],
              scan: LaserScan) -> ScanMatch:
        """Match ``scan`` taken at the believed ``pose`` against the occupied cells ``walls`` (bool ``[H, W]`` on
        ``frame``); the believed pose comes back unchanged without a covariance, when matching is disabled, or when
        the acceptance rule fails (the outcome's ``reason`` says which)."""
        nan = float("nan")
        if covariance is None or not self.cfg.enabled:
            return ScanMatch(pose, False, nan, nan, "no covariance" if covariance is None else "disabled")
        cfg, res = self.cfg, frame.resolution_m
        self.scans_seen += 1
        rho, angles = self.returns(scan, res)
        if rho.size < cfg.min_points:
            return ScanMatch(pose, False, nan, nan, "too few returns")
        variances = np.diag(np.asarray(covariance.matrix, np.float64))[[0, 1, 2]]
        sigma_x, sigma_y, sigma_yaw = (math.sqrt(max(v, 0.0)) for v in variances)
        half_x = min(max(cfg.window_sigmas * sigma_x, res), cfg.max_window_m) / res
        half_y = min(max(cfg.window_sigmas * sigma_y, res), cfg.max_window_m) / res
        half_yaw = min(cfg.window_sigmas * sigma_yaw, math.radians(cfg.max_window_deg))
        (gy, gx), _ = frame.locate(pose.x, pose.y)
        sigmas = (in_cells(cfg.field_sigma_m, res), in_cells(cfg.coarse_sigma_m, res))
        reach = float(rho.max()) + max(half_x, half_y) + 4.0 * max(sigmas) + 2.0
        top, left = max(0, int(gy - reach)), max(0, int(gx - reach))
        bottom, right = min(frame.shape[0], int(gy + reach) + 2), min(frame.shape[1], int(gx + reach) + 2)
        crop = np.asarray(walls[top:bottom, left:right], bool)
        if int(crop.sum()) < cells_at_least(cfg.min_map_wall_m, res) or min(crop.shape) < 2:
            return ScanMatch(pose, False, nan, nan, "too few walls in the map")
        fine, coarse = likelihood_fields(crop, sigmas)
        origin = (gy - top, gx - left)
        # Offsets are (dy down, dx right, dyaw): the prior reads them in the map frame (y up).
        inv_var = np.array([1.0 / max(sigma_y / res, 1e-9) ** 2, 1.0 / max(sigma_x / res, 1e-9) ** 2,
                            1.0 / max(sigma_yaw, 1e-12) ** 2])

        def objective(field: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            fits = score_poses(field, rho, angles, origin, pose.yaw, offsets)
            return fits - cfg.prior_weight * 0.5 * (offsets ** 2 @ inv_var), fits

        yaw_step = 1.0 / float(rho.max())  # the farthest return moves by about one cell per step
        grids = np.meshgrid(_lattice(half_y, 1.0), _lattice(half_x, 1.0),
                            _lattice(half_yaw, yaw_step) if half_yaw > 0 else np.zeros(1), indexing="ij")
        candidates = np.stack([g.ravel() for g in grids], axis=1)
        # Coarse: the lattice on the wide field (wide basins: the right pose need not lie on the lattice);
        # fine: hill-climbing from the best few on the narrow field, halving the steps at each level.
        coarse_values, _ = objective(coarse, candidates)
        starts = candidates[np.argsort(-coarse_values, kind="stable")[:cfg.starts]]
        around = np.stack([g.ravel() for g in np.meshgrid(*([np.array([-1.0, 0.0, 1.0])] * 3), indexing="ij")],
                          axis=1)
        limits = np.array([half_y, half_x, half_yaw])
        best_value, best_offset, best_fit = -np.inf, np.zeros(3), 0.0
        for start in starts:
            offset = start
            value, fit = (v[0] for v in objective(fine, offset[None, :]))
            steps = np.array([1.0, 1.0, yaw_step])
            for _ in range(cfg.refine_levels + 1):
                for _ in range(_CLIMB_MOVES):
                    local = np.clip(offset + around * steps, -limits, limits)
                    local_values, local_fits = objective(fine, local)
                    k = int(np.argmax(local_values))
                    if not local_values[k] > value:
                        break
                    offset, value, fit = local[k], local_values[k], local_fits[k]
                steps = steps / 2.0
            if value > best_value:
                best_value, best_offset, best_fit = value, offset, fit
        believed_fit = float(score_poses(fine, rho, angles, origin, pose.yaw, np.zeros((1, 3)))[0])
        best_fit = float(best_fit)
        corrected = Pose2D(pose.x + best_offset[1] * res, pose.y - best_offset[0] * res,
                           math.remainder(pose.yaw + best_offset[2], 2.0 * math.pi))
        if best_fit < cfg.min_fit:
            return ScanMatch(pose, False, best_fit, believed_fit, "fit below min_fit")
        if best_fit - believed_fit < cfg.min_gain:
            return ScanMatch(pose, False, best_fit, believed_fit, "gain below min_gain")
        cell = frame.cell_of(corrected.x, corrected.y)
        if not frame.contains(cell) or walls[cell]:
            return ScanMatch(pose, False, best_fit, believed_fit, "corrected pose in a wall or off the map")
        return ScanMatch(corrected, True, best_fit, believed_fit, "")
