"""IG-Hector (Shrestha et al., ICRA 2019), as MapEx runs it (``hectoraug``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import check_instance, check_real
from superex_deploy.onboard.types import Planner, PlanningContext, Prediction
from superex_deploy.onboard.planning.viewpoint_gains import visible_gains
from superex_deploy.onboard.planning.visibility import (VisibilityConfig, best_frontier, connected_unknown_gains,
                                               reachable_frontiers)

__all__ = ["HectorConfig", "HectorPlanner"]


@dataclass(frozen=True)
class HectorConfig(JsonConfig):
    """IG-Hector (Shrestha et al., ICRA 2019, as MapEx runs it: ``hectoraug``).

    Attributes:
        visibility: information gain region: the unknown cells predicted visible from the frontier (default),
            or None for MapEx's code path, which skips the raycast and counts the whole predicted-free region
            connected to the frontier (:func:`connected_unknown_gains`).
        info_gain_weight: weight ``w`` of ``floor(w * (sqrt(max IG) - sqrt(IG)))`` against travel cost
            (MapEx: 200; finite, >= 0).
        wall_threshold: binarisation of the prediction for the connected region (MapEx: 0.5; in ``[0, 1]``).

    Raises:
        ValueError: a field of another type or out of its range, named (see
            :mod:`~superex_deploy.onboard.checks`).
    """

    visibility: Optional[VisibilityConfig] = field(default_factory=VisibilityConfig)
    info_gain_weight: float = 200.0
    wall_threshold: float = 0.5

    def __post_init__(self) -> None:
        check_instance("visibility", self.visibility, VisibilityConfig, allow_none=True)
        object.__setattr__(self, "info_gain_weight", check_real("info_gain_weight", self.info_gain_weight, 0.0))
        object.__setattr__(self, "wall_threshold", check_real("wall_threshold", self.wall_threshold, 0.0, 1.0))


class HectorPlanner(Planner):
    """IG-Hector: the exploration transform seeded at the frontiers with an information-gain cost.

    MapEx seeds a BFS over the observed free cells at each frontier centre with ``floor(w * (sqrt(max IG) -
    sqrt(IG)))`` and descends its gradient from the robot. The robot's value in that transform is the least,
    over frontiers, of seed plus travel cost, so we pick that frontier directly and let the engine drive there.
    Differences, and why:

    * IG counts the currently unknown cells predicted *visible* from the frontier (MapEx's ``score_frontiers``
      with ``hectoraug`` casts the rays but then skips them, ``skip_raycast=True``, and counts the whole
      predicted-free region connected to the frontier). That region holds the known free space, so every
      frontier the robot can reach gets the same IG and the IG term vanishes: plain Hector. Visibility keeps the
      method the paper describes; ``HectorConfig(visibility=None)`` gives MapEx's code path.
    * Travel cost is the engine's (1 per cell far from walls, up to about 10 beside them) where MapEx's
      transform adds Hector's danger cost, ``5 (15 - d)`` per cell within 15 cells of a wall; the weight of 200
      therefore counts for more against distance here than in MapEx, most in narrow corridors.
    * MapEx re-plans Hector at every step; the episode loop keeps a goal until it is reached or blocked.
    """

    name = "hector"

    def __init__(self, cfg: HectorConfig = HectorConfig()):
        self.cfg = check_instance("cfg", cfg, HectorConfig)

    def information_gain(self, prediction: Prediction, observed: np.ndarray, cells_rc,
                         resolution_m: float) -> np.ndarray:
        """int64 ``[N]`` IG of each cell (see :class:`HectorConfig`)."""
        if self.cfg.visibility is None:
            return connected_unknown_gains(prediction.mean, observed, cells_rc, self.cfg.wall_threshold)
        counts, _ = visible_gains(prediction, observed, cells_rc, self.cfg.visibility, resolution_m)
        return counts

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        frontiers, costs = reachable_frontiers(ctx)
        if not frontiers:
            return None
        gains = self.information_gain(ctx.predict(), ctx.observed, [f.cell_rc for f in frontiers],
                                      ctx.resolution_m)
        root_gain = np.sqrt(gains.astype(np.float64))
        seeds = np.floor(self.cfg.info_gain_weight * (root_gain.max() - root_gain))
        return best_frontier(costs + seeds, costs, frontiers)
