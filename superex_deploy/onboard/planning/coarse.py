"""Planning on a coarser grid than the map's: frontiers, goals, paths and the planners' scoring at about
:attr:`~superex_deploy.onboard.planning.motion.MotionConfig.planning_cell_m` per cell, whatever the map's resolution.

A SLAM map at 0.05 m (or 0.025 m) holds 4 (16) times the cells of the same floor at 0.1 m. The map itself is kept
at the robot's resolution (the scans, the carving, the SLAM map and what the explorer reports live there), but
what needs no such detail runs on blocks of ``k x k`` cells (``k`` the largest integer with ``k * resolution <=
planning_cell_m``): the frontier search, Dijkstra from the robot, the planners' gains and the path. Its cost then
follows the floor's area, not its cell count, and the decisions are those taken on a grid of the resolution the
planners and models were tuned at. At ``k = 1`` (a map at 0.1 m or coarser with the default) every function here
gives back what it was given: nothing changes.

The blocks are cut from the map's first row and column (block ``(R, C)`` holds cells ``R k .. R k + k - 1`` by
``C k .. C k + k - 1``; the last row and column of blocks may be cut by the map's edge). A block is a wall where
any of its cells is, else free where any is, unknown where none is known
(:func:`~superex_deploy.onboard.mapping.blocks.coarsen_observed`, which the map keeps up to date:
:meth:`~superex_deploy.onboard.mapping.mapper.Mapper.blocks`): the map a coarser grid would have made of the same
rays. A path of free blocks may cross a cell no ray reached between cells rays crossed (a gap between rays at
range), never a cell the map holds occupied. A block's cell on the map is its centre cell (:meth:`PlanningGrid.centre`); a path of blocks becomes an 8-connected
path of cells that never leaves those blocks (:meth:`PlanningGrid.fine_path`).

:func:`pool_prediction_blocks` is a compiled kernel: ``skimage.measure.block_reduce`` (three block sums, the same
bits) measured 9.0x slower on the largest eval floor at 0.05 m (21x at 0.1 m; ``benchmarks/skimage``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numba
import numpy as np

from superex_deploy.onboard.prediction.scale import pool_mean
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.types import FREE, OCCUPIED, Frontier, Prediction

__all__ = ["planning_factor", "pool_prediction_blocks", "PlanningGrid", "CoarsePrediction"]

_TOLERANCE = 1e-6  # 0.1 / 0.05 is 2 up to rounding (and a float32 0.05 from a message): that block counts


def planning_factor(resolution_m: float, planning_cell_m: float) -> int:
    """``k``: the largest integer with ``k * resolution_m <= planning_cell_m`` (at least 1).

    Raises:
        ValueError: a resolution or cell size that is not a positive, finite number of metres.
    """
    for name, value in (("resolution_m", resolution_m), ("planning_cell_m", planning_cell_m)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive, finite number of metres, got {value!r}")
    return max(int(np.floor(float(planning_cell_m) / float(resolution_m) * (1.0 + _TOLERANCE))), 1)


def pool_prediction_blocks(prediction: Prediction, k: int) -> Prediction:
    """A prediction on blocks of ``k x k`` cells (float32 ``[ceil(H/k), ceil(W/k)]``): each block's mean wall
    probability, and the variance of the block's cells taken as one mixture (mean of the variances plus variance of
    the means); ``prediction`` itself at ``k = 1``. A block cut by the map's edge pools the cells it has."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"the block size must be an integer >= 1, got {k!r}")
    if k == 1:
        return prediction
    shape = (-(-prediction.mean.shape[0] // k), -(-prediction.mean.shape[1] // k))
    mean, variance = np.empty(shape, np.float32), np.empty(shape, np.float32)
    _pool_mixture(np.ascontiguousarray(prediction.mean), np.ascontiguousarray(prediction.variance), int(k), mean,
                  variance)
    return Prediction(mean=mean, variance=variance)


@numba.njit(cache=True)
def _pool_mixture(mean, variance, k, out_mean, out_variance):
    rows, cols = mean.shape
    for r in range(out_mean.shape[0]):
        for c in range(out_mean.shape[1]):
            first, second = 0.0, 0.0
            r1, c1 = min(r * k + k, rows), min(c * k + k, cols)
            for i in range(r * k, r1):
                for j in range(c * k, c1):
                    m = np.float64(mean[i, j])
                    first += m
                    second += np.float64(variance[i, j]) + m * m
            n = (r1 - r * k) * (c1 - c * k)
            average = first / n
            out_mean[r, c] = average
            out_variance[r, c] = max(second / n - average * average, 0.0)


@dataclass(frozen=True)
class PlanningGrid:
    """The blocks the planning runs on, over a map of ``shape`` cells of ``resolution_m`` metres.

    Attributes:
        shape: ``(rows, cols)`` of the map.
        resolution_m: metres per map cell.
        factor: ``k``, map cells per block side (:func:`planning_factor`).
    """

    shape: tuple[int, int]
    resolution_m: float
    factor: int

    @classmethod
    def for_map(cls, shape, resolution_m: float, planning_cell_m: float) -> "PlanningGrid":
        """The planning grid of a map of ``shape`` cells at ``resolution_m`` (see :func:`planning_factor`)."""
        return cls((int(shape[0]), int(shape[1])), float(resolution_m), planning_factor(resolution_m, planning_cell_m))

    @property
    def block_m(self) -> float:
        """Metres per planning cell (``factor * resolution_m``)."""
        return self.factor * self.resolution_m

    @property
    def block_shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the planning grid."""
        k = self.factor
        return -(-self.shape[0] // k), -(-self.shape[1] // k)

    def frame_of(self, frame: MapFrame) -> MapFrame:
        """The blocks of ``frame`` (the map this grid was made for) as a map frame of their own: cell ``(R, C)``
        is block ``(R, C)``, at the same place in metres (the last row of blocks may reach below the map's edge);
        ``frame`` itself at ``k = 1``."""
        if self.factor == 1:
            return frame
        rows, cols = self.block_shape
        top_y = frame.origin_xy[1] + frame.shape[0] * frame.resolution_m
        return MapFrame((rows, cols), self.block_m, (frame.origin_xy[0], top_y - rows * self.block_m))

    def grown(self, regrid) -> tuple["PlanningGrid", Callable[[tuple[int, int]], tuple[int, int]]]:
        """This grid on the grown map of ``regrid`` (a :class:`~superex_deploy.onboard.mapping.growth.Regrid` that
        adds whole blocks above and to the left: ``grown_frame(..., align=factor)``), and the block a block of this
        grid becomes there.

        Raises:
            ValueError: a growth by a part of a block (the blocks would not keep their cells).
        """
        k = self.factor
        if regrid.top % k or regrid.left % k:
            raise ValueError(f"the grid grew by {regrid.top} rows and {regrid.left} columns, not whole blocks of {k}")
        top, left = regrid.top // k, regrid.left // k
        return (PlanningGrid(tuple(regrid.frame.shape), self.resolution_m, k),
                lambda block: (int(block[0]) + top, int(block[1]) + left))

    def block(self, cell_rc) -> tuple[int, int]:
        """The block (planning cell) holding map cell ``cell_rc``."""
        return int(cell_rc[0]) // self.factor, int(cell_rc[1]) // self.factor

    def centre(self, block_rc) -> tuple[int, int]:
        """The map cell at the centre of block ``block_rc`` (cell ``k // 2`` of it along each axis, inside the
        map where the edge cuts the block)."""
        k = self.factor
        if k == 1:
            return int(block_rc[0]), int(block_rc[1])
        return (min(int(block_rc[0]) * k + k // 2, self.shape[0] - 1),
                min(int(block_rc[1]) * k + k // 2, self.shape[1] - 1))

    def on_map(self, start_rc, goal, blocks: Sequence[tuple[int, int]], observed: Optional[np.ndarray] = None
               ) -> tuple[Optional[tuple[int, int]], np.ndarray]:
        """A command's goal cell (:meth:`goal_cell`, or None without a goal block) and int64 ``[N, 2]`` path cells
        (:meth:`fine_path`) for the robot at map cell ``start_rc``, on ``observed`` (int8 ``[H, W]``, the map the
        blocks were made of; None: block centres and straight runs)."""
        goal_rc = None if goal is None else self.goal_cell(goal, observed)
        path = self.fine_path(start_rc, blocks, observed, goal_rc)
        return goal_rc, np.asarray(path, np.int64).reshape(-1, 2)

    def goal_cell(self, block_rc, observed: Optional[np.ndarray] = None) -> tuple[int, int]:
        """The map cell a goal block stands for: of its cells ``observed`` (int8 ``[H, W]``, the map) holds free,
        the one nearest its centre (:meth:`centre` without ``observed``, or where none is: a free block has one)."""
        centre = self.centre(block_rc)
        if self.factor == 1 or observed is None:
            return centre
        k = self.factor
        r0, c0 = int(block_rc[0]) * k, int(block_rc[1]) * k
        rows, cols = np.nonzero(observed[r0:r0 + k, c0:c0 + k] == FREE)
        if rows.size == 0:
            return centre
        best = int(np.argmin((rows + r0 - centre[0]) ** 2 + (cols + c0 - centre[1]) ** 2))
        return int(rows[best]) + r0, int(cols[best]) + c0

    def fine_path(self, start_rc, blocks: Sequence[tuple[int, int]], observed: Optional[np.ndarray] = None,
                  goal_rc=None) -> list[tuple[int, int]]:
        """The 8-connected path of map cells from ``start_rc`` (a cell of ``blocks[0]``) through ``blocks`` (each an
        8-neighbour of the one before) to ``goal_rc`` (a cell of the last block; its centre by default), every cell
        inside one of those blocks: in each block it runs straight or diagonally to the cell nearest the next block,
        then one step into it (across the corner both share, for a diagonal move: never through the two blocks
        beside it, which the planning did not check). The blocks after the first are free, so hold no wall; the
        robot's own block may (the planning lets the robot leave its cell whatever it holds): with ``observed``
        (int8 ``[H, W]``, the map) the path leaves it around its walls where it can.
        ``blocks`` itself at ``k = 1``; ``[]`` for no blocks."""
        if self.factor == 1:
            return [(int(r), int(c)) for r, c in blocks]
        if len(blocks) == 0:
            return []
        goal = self.centre(blocks[-1]) if goal_rc is None else (int(goal_rc[0]), int(goal_rc[1]))
        path = [(int(start_rc[0]), int(start_rc[1]))]
        for index, block in enumerate(blocks[1:]):
            entry = self._nearest_in(block, path[-1])
            if index == 0 and self._around(path, entry, (blocks[0], block), observed):
                continue
            self._walk(path, self._nearest_in(self.block(path[-1]), entry))
            path.append(entry)
        if len(blocks) == 1 and self._around(path, goal, (blocks[0],), observed):
            return path
        self._walk(path, goal)
        return path

    def _around(self, path: list, target: tuple[int, int], blocks, observed: Optional[np.ndarray]) -> bool:
        """Extend ``path`` to ``target`` around a wall the straight run there would cross (:meth:`_route`); False,
        and ``path`` unchanged, where the straight run crosses none (or ``observed`` is None, or no route exists)."""
        if observed is None:
            return False
        straight = [path[-1]]
        self._walk(straight, self._nearest_in(self.block(path[-1]), target))
        if target != straight[-1]:
            straight.append(target)
        if not any(observed[cell] == OCCUPIED for cell in straight):
            return False
        return self._route(path, target, blocks, observed)

    def _route(self, path: list, target: tuple[int, int], blocks, observed: np.ndarray) -> bool:
        """Extend ``path`` to ``target`` by a shortest 8-connected route over the cells of ``blocks`` that
        ``observed`` holds no wall in (a breadth-first search over at most ``2 k^2`` cells); False, and ``path``
        unchanged, where none is."""
        allowed = {cell for block in blocks for cell in self._cells(block) if observed[cell] != OCCUPIED}
        start = path[-1]
        allowed.add(start)
        if target not in allowed:
            return False
        parent, frontier = {start: start}, [start]
        while frontier and target not in parent:
            following = []
            for r, c in frontier:
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        cell = (r + dr, c + dc)
                        if cell in allowed and cell not in parent:
                            parent[cell] = (r, c)
                            following.append(cell)
            frontier = following
        if target not in parent:
            return False
        route, cell = [], target
        while cell != start:
            route.append(cell)
            cell = parent[cell]
        path.extend(reversed(route))
        return True

    def _cells(self, block) -> list[tuple[int, int]]:
        """The map cells of ``block`` (those inside the map)."""
        k = self.factor
        return [(r, c) for r in range(block[0] * k, min(block[0] * k + k, self.shape[0]))
                for c in range(block[1] * k, min(block[1] * k + k, self.shape[1]))]

    def _nearest_in(self, block, cell_rc) -> tuple[int, int]:
        """The cell of ``block`` (inside the map) nearest ``cell_rc``."""
        k = self.factor
        return (min(max(int(cell_rc[0]), block[0] * k), min(block[0] * k + k, self.shape[0]) - 1),
                min(max(int(cell_rc[1]), block[1] * k), min(block[1] * k + k, self.shape[1]) - 1))

    @staticmethod
    def _walk(path: list, target: tuple[int, int]) -> None:
        """Extend ``path`` from its last cell to ``target`` diagonally, then straight (inside the two cells'
        bounding box)."""
        r, c = path[-1]
        while (r, c) != target:
            r += int(np.sign(target[0] - r))
            c += int(np.sign(target[1] - c))
            path.append((r, c))

    def fine_frontier(self, frontier: Frontier) -> Frontier:
        """A frontier of blocks as map cells: its goal block's centre, and every block's centre."""
        if self.factor == 1:
            return frontier
        k = self.factor
        cells = np.asarray(frontier.cells, np.int64).reshape(-1, 2) * k + k // 2
        cells = np.minimum(cells, np.array(self.shape, np.int64) - 1).astype(np.int32)
        return Frontier(self.centre(frontier.cell_rc), cells)


class CoarsePrediction:
    """What the planners read on the planning grid: the step's prediction (a
    :class:`~superex_deploy.onboard.prediction.schedule.LazyPrediction` or ``StalePrediction``, on the map) pooled
    onto blocks (:func:`pool_prediction_blocks`), and its evidence block-averaged; computed once per step."""

    def __init__(self, inner, factor: int):
        self.inner, self.factor = inner, int(factor)
        self._pooled: Optional[tuple] = None
        self._evidence: Optional[tuple] = None
        self._pooling_s = 0.0

    def _pool(self, prediction: Prediction) -> Prediction:
        if self._pooled is None or self._pooled[0] is not prediction:
            clock = time.perf_counter()
            self._pooled = (prediction, pool_prediction_blocks(prediction, self.factor))
            self._pooling_s += time.perf_counter() - clock
        return self._pooled[1]

    def __call__(self) -> Prediction:
        return self._pool(self.inner())

    def look(self) -> Prediction:
        return self._pool(self.inner.look())

    @property
    def evidence(self) -> Optional[np.ndarray]:
        evidence = getattr(self.inner, "evidence", None)
        if evidence is None:
            return None
        if self._evidence is None or self._evidence[0] is not evidence:
            self._evidence = (evidence, pool_mean(np.asarray(evidence, np.float32), self.factor))
        return self._evidence[1]

    @property
    def seconds(self) -> float:
        """The wrapped prediction's seconds plus this pooling's."""
        return self.inner.seconds + self._pooling_s

    @property
    def value(self) -> Optional[Prediction]:
        return self.inner.value
