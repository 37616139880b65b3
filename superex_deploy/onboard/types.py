"""Types shared by the mapper, the planners and the episode loop.

Observed maps are int8 ``[H, W]`` arrays over the ground-truth grid with the codes :data:`UNKNOWN`,
:data:`FREE` and :data:`OCCUPIED`. Predictions are occupancy probabilities (1 = wall).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, ClassVar, Optional, Protocol

import numpy as np

UNKNOWN = np.int8(-1)
FREE = np.int8(0)
OCCUPIED = np.int8(1)


def check_observed(observed, shape: Optional[tuple[int, int]] = None, codes: bool = False) -> np.ndarray:
    """Validate an observed map and return it as an array: a non-empty int8 ``[H, W]`` (of ``shape`` when
    given); with ``codes``, also holding only :data:`UNKNOWN` (-1), :data:`FREE` (0) and :data:`OCCUPIED` (1)
    (a pass over the whole map: the predictors check it, the per-step map code does not).

    Raises:
        ValueError: another dtype or number of axes, an empty map, another shape, or (with ``codes``) another
            value.
    """
    observed = np.asarray(observed)
    if observed.dtype != np.int8 or observed.ndim != 2 or observed.size == 0:
        raise ValueError(f"observed must be a non-empty int8 [H, W] array, got {observed.dtype} with shape "
                         f"{observed.shape}")
    if shape is not None and observed.shape != tuple(shape):
        raise ValueError(f"observed has shape {observed.shape}, expected {tuple(shape)}")
    if codes and (observed.min() < UNKNOWN or observed.max() > OCCUPIED):
        raise ValueError("observed may hold only -1 (unknown), 0 (free) and 1 (occupied)")
    return observed


@dataclass(frozen=True)
class Frontier:
    """One frontier region: free cells next to unknown ones, 8-connected.

    Attributes:
        cell_rc: (row, col) of the region's cell nearest to its centroid (the region's goal cell).
        cells: int32 ``[n, 2]`` (row, col) of every cell of the region.
        whole_size: None, or the region's size before the exploration bounds cut it
            (:func:`~superex_deploy.onboard.planning.bounds.clip_frontiers`: ``cells`` are those inside).
    """

    cell_rc: tuple[int, int]
    cells: np.ndarray
    whole_size: Optional[int] = None

    @property
    def size(self) -> int:
        """Number of cells in the region."""
        return int(self.cells.shape[0])

    @property
    def clipped(self) -> bool:
        """Whether the exploration bounds cut the region."""
        return self.whole_size is not None

    @property
    def extent(self) -> int:
        """The region's size before the bounds cut it (its size when they did not): what says how much lies
        behind it, since a doorway the bounds' edge crosses leaves a few cells inside whatever the room holds."""
        return self.size if self.whole_size is None else self.whole_size


@dataclass(frozen=True)
class Prediction:
    """A predicted occupancy map.

    Attributes:
        mean: float32 ``[H, W]`` probability that each cell is a wall, in [0, 1].
        variance: float32 ``[H, W]`` variance of that probability across ensemble members (0 for a single
            deterministic predictor).
    """

    mean: np.ndarray
    variance: np.ndarray


class MapPredictor(Protocol):
    """Anything that turns an observed map (plus optional evidence) into a predicted occupancy map."""

    name: str

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        """Args: observed int8 ``[H, W]`` (UNKNOWN/FREE/OCCUPIED); extra float32 ``[H, W]`` evidence in the
        map frame (e.g. filtered back-projection) or None. Returns a :class:`Prediction` of shape ``[H, W]``."""
        ...


@dataclass(frozen=True)
class PlanningContext:
    """Everything a planner may look at when it picks the next goal.

    Attributes:
        observed: int8 ``[H, W]`` observed map.
        pose_rc: robot cell (row, col).
        frontiers: the current frontier regions (may be empty).
        travel_cost: float64 ``[H, W]`` cost-to-go from the robot on the planning map (cells, weighted by the
            wall-proximity cost); ``inf`` where unreachable.
        traversable: bool ``[H, W]`` cells the robot may occupy (known free, walls inflated).
        resolution_m: metres per cell.
        predict: returns the current :class:`Prediction`; computed on first call and cached by the caller, so
            planners that never call it never pay for it.
        rng: the episode's random generator (for sampling planners such as UPEN's RRT).
    """

    observed: np.ndarray
    pose_rc: tuple[int, int]
    frontiers: tuple[Frontier, ...]
    travel_cost: np.ndarray
    traversable: np.ndarray
    resolution_m: float
    predict: Callable[[], Prediction]
    rng: np.random.Generator


class Planner(ABC):
    """Chooses the next exploration goal. One subclass per method; stateless between calls unless documented."""

    name: ClassVar[str]
    reads_variance: ClassVar[bool] = False
    """Whether the planner reads ``Prediction.variance`` (the ensemble's spread): it then needs two members or
    more."""

    @abstractmethod
    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        """Return the goal cell (row, col), reachable per ``ctx.travel_cost``, or None when nothing is left."""

    def reset(self) -> None:
        """Forget what the planner kept from an earlier episode (the episode loop calls it first). The default
        planner keeps nothing."""

    def keep_goal(self, observed: np.ndarray, pose_rc: tuple[int, int], goal_rc: tuple[int, int],
                  steps_since_chosen: int) -> bool:
        """Whether to keep driving to the locked goal at this step (called every step while a goal is locked,
        not reached and its path not blocked). The default keeps it, as MapEx does; a planner that returns
        False is asked for a new goal at once.

        Args:
            observed: int8 ``[H, W]`` observed map after this step's scan.
            pose_rc: robot cell.
            goal_rc: the locked goal cell.
            steps_since_chosen: steps since the goal was chosen (0 on the step that chose it).
        """
        return True

    def goal_scores(self, ctx: PlanningContext, cells_rc) -> Optional[np.ndarray]:
        """float64 ``[N]``: the planner's score of each goal cell of int ``[N, 2]`` ``cells_rc`` on this step's
        context (higher is better, 0 for an unreachable cell), or None when the planner has no scores to compare
        (then a locked goal is never replaced by a better one: see
        :class:`~superex_deploy.onboard.planning.goal_policy.GoalPolicy` ``commit_margin``). The default has none."""
        return None


def frontiers_at(cells_rc) -> tuple[Frontier, ...]:
    """One single-cell :class:`Frontier` per cell of int ``[N, 2]`` ``cells_rc``: goal cells scored as frontiers
    (:meth:`Planner.goal_scores`)."""
    cells = np.asarray(cells_rc, np.int64).reshape(-1, 2)
    return tuple(Frontier(cell_rc=(int(r), int(c)), cells=np.array([[r, c]], np.int32)) for r, c in cells)


def scores_by_cell(frontiers, scores, cells_rc) -> np.ndarray:
    """float64 ``[N]``: the score of each cell of ``cells_rc`` among the scored ``frontiers`` (0 where it is not
    among them: unreachable)."""
    by_cell = {f.cell_rc: float(s) for f, s in zip(frontiers, scores)}
    cells = np.asarray(cells_rc, np.int64).reshape(-1, 2)
    return np.array([by_cell.get((int(r), int(c)), 0.0) for r, c in cells], np.float64)
