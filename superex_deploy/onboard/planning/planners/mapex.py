"""MapEx (Ho et al., ICRA 2025; ``visvarprob``): predicted-visible variance per unit of distance."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.planning.expected_visibility import ExpectedVisibility, expected_visible_gains
from superex_deploy.onboard.checks import check_choice, check_instance, check_real, in_cells
from superex_deploy.onboard.types import Frontier, Planner, PlanningContext, Prediction, frontiers_at, scores_by_cell
from superex_deploy.onboard.planning.viewpoint_gains import visible_gains
from superex_deploy.onboard.planning.visibility import VisibilityConfig, best_frontier, reachable_frontiers

__all__ = ["MapexConfig", "MapexPlanner"]


@dataclass(frozen=True)
class MapexConfig(JsonConfig):
    """MapEx (``visvarprob``): predicted-visible variance per unit distance.

    Attributes:
        visibility: the probabilistic raycast (MapEx: 250 rays over 20 m, hit threshold 0.8).
        distance: the divisor: ``"travel"`` (default), the cost-to-go of the planning map (path length weighted
            by the wall-proximity cost), or ``"euclidean"``, the straight-line distance from the robot to the
            frontier cell in cells, as MapEx's code divides (``sim_utils.py``: ``frontier_val / cost_dist``).
        min_distance_m: floor on the divisor (metres, positive, finite; one cell of 0.1 m). Frontiers within the
            goal tolerance (1 m) are never offered, so it only guards against a zero distance.
        gain: ``"visible"`` (MapEx): the cells of the thresholded raycast's filled polygon; ``"expected"``: every
            unknown cell weighted by the probability that a ray reaches it through the predicted walls
            (``1 - max p`` over the cells it crossed:
            :func:`~superex_deploy.onboard.planning.expected_visibility.expected_visible_gains`, with ``visibility``'s
            rays and range; its threshold and ``accumulate`` are then unused): the expected variance, or the
            expected count without variance.

    Raises:
        ValueError: a field of another type or out of its range, named (see
            :mod:`~superex_deploy.onboard.checks`).
    """

    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    distance: str = "travel"
    min_distance_m: float = 0.1
    gain: str = "visible"

    def __post_init__(self) -> None:
        check_instance("visibility", self.visibility, VisibilityConfig)
        check_choice("distance", self.distance, ("travel", "euclidean"))
        check_choice("gain", self.gain, ("visible", "expected"))
        object.__setattr__(self, "min_distance_m",
                           check_real("min_distance_m", self.min_distance_m, 0.0, low_open=True))


class MapexPlanner(Planner):
    """MapEx: each frontier scores the predicted variance summed over the currently unknown cells predicted
    visible from it, divided by its distance; the best score wins.

    As MapEx, visibility comes from the probabilistic raycast on the ensemble mean and the variance from the
    ensemble. Differences: the divisor is the travel cost rather than the straight-line distance (see the
    module docstring; ``MapexConfig(distance="euclidean")`` divides as MapEx's code does); and when the
    prediction carries no variance at all (a deterministic predictor such as
    :class:`~superex_deploy.onboard.prediction.baselines.ObservedAsPrediction` or the oracle), where MapEx would tie every
    frontier at zero and take the first, the visible unknown cells are counted instead (MapEx's ``visunk``).

    Reuse: the predictor and its evidence reach the planner only through ``ctx.predict``, so a SuperEx variant
    is this class run with another predictor; :meth:`information` is the hook for a different information
    measure and :meth:`score` gives every reachable frontier's score.
    """

    name = "mapex"
    reads_variance = True

    def __init__(self, cfg: MapexConfig = MapexConfig()):
        self.cfg = check_instance("cfg", cfg, MapexConfig)

    def information(self, prediction: Prediction, observed: np.ndarray, cells_rc, resolution_m: float
                    ) -> np.ndarray:
        """float64 ``[N]``: visible-unknown variance of each viewpoint, or the visible unknown count when the
        prediction has no variance anywhere (both expected ones with ``cfg.gain="expected"``)."""
        if self.cfg.gain == "expected":
            rays = ExpectedVisibility(n_rays=self.cfg.visibility.n_rays, range_m=self.cfg.visibility.range_m)
            cells = np.asarray(cells_rc, np.int64).reshape(-1, 2)
            counts, var_sums = expected_visible_gains(prediction.mean, observed, [[cell] for cell in cells], rays,
                                                      resolution_m, prediction.variance)
        else:
            counts, var_sums = visible_gains(prediction, observed, cells_rc, self.cfg.visibility, resolution_m)
        if np.any(prediction.variance > 0.0):
            return var_sums
        return counts.astype(np.float64)

    def score(self, ctx: PlanningContext) -> tuple[list[Frontier], np.ndarray, np.ndarray]:
        """The reachable frontiers, their travel costs and their scores (information per unit of
        ``cfg.distance``), float64 ``[N]`` each."""
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return [], costs, np.zeros(0)
        cells = np.array([f.cell_rc for f in frontiers], np.float64)
        prediction = ctx.predict()
        information = self.information(prediction, ctx.observed, cells.astype(np.int64), ctx.resolution_m)
        if self.cfg.distance == "euclidean":
            distance = np.hypot(cells[:, 0] - ctx.pose_rc[0], cells[:, 1] - ctx.pose_rc[1])
        else:
            distance = costs
        return frontiers, costs, information / np.maximum(distance, in_cells(self.cfg.min_distance_m, ctx.resolution_m))

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs, scores = self.score(ctx)
        if not frontiers:
            return None
        return best_frontier(-scores, costs, frontiers)

    def goal_scores(self, ctx: PlanningContext, cells_rc) -> np.ndarray:
        """:meth:`score` of each goal cell taken as a frontier (0 where unreachable)."""
        frontiers, _, scores = self.score(replace(ctx, frontiers=frontiers_at(cells_rc)))
        return scores_by_cell(frontiers, scores, cells_rc)
