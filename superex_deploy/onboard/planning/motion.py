"""Motion planning on the observed map: inflated walls, a wall-proximity cost, cost-to-go and paths.

Planning map (after MapEx's ``inflate_map`` with ``use_distance_transform_for_planning``):

* A cell is traversable when it is known FREE and farther than the robot radius from every observed wall. FREE
  cells are those the map holds free with confidence (log-odds at or below the free threshold); cells known free
  only by NLOS carving are FREE in the map the explorer plans on only as ``MotionConfig.drive_carved`` allows.
  The default radius, 0.15 m, blocks exactly the cells 8-adjacent to a wall, i.e. MapEx's
  dilation of the walls by a 3 x 3 square (``dilate_diam_for_planning: 3``).
* UNKNOWN cells are never traversable (MapEx's ``unknown_as_occ``), but only observed walls are inflated:
  frontier cells border the unknown by definition and must stay reachable.
* The robot's own cell is always traversable, even when a wall seen later puts it inside the inflation: the
  robot is physically there, and a planner that could not leave it would stall the episode.
* Moving into a cell costs ``1 + w * max(0, 1 - d / range)`` per cell length, with ``d`` the distance to the
  nearest observed wall. With ``w = 10`` and ``range = 1 m`` this is MapEx's ``clip(10 - dt, 1, 10)``
  (``dt`` its distance to the inflated walls in cells): cost 9 on the first traversable cells, 1 from 1 m
  on. MapEx also counts unknown cells as obstacles in that distance; we do not, since the unknown is not a
  collision risk and frontiers (which all border it) would all pay the same penalty.

One Dijkstra pass from the robot (8-connected; a step between cells ``a`` and ``b`` costs
``(cost[a] + cost[b]) / 2`` times its length, 1 or sqrt 2, scikit-image ``MCP_Geometric``'s convention) gives
both the cost-to-go to every cell, which the planners need to rank all frontiers, and the path to the chosen goal
through its predecessor links. A* would only add a second search for a path the Dijkstra tree already holds.
The search runs over the bounding box of the known free cells plus a one-cell margin, which holds every observed
wall (each is hit from a free cell). Two compiled kernels do the work: the distance to the nearest wall, stamped
from each wall over a disc just wider than the cost range and the robot radius (exact there, ``inf`` beyond,
where neither rule depends on it), and an indexed-binary-heap Dijkstra over a grid padded with an impassable
border; together they are several times faster than ``scipy.ndimage.distance_transform_edt`` and
``MCP_Geometric`` (measured in docs/benchmarks/exploration.md); ``skimage.graph.MCP_Geometric`` alone, on the same
costs, gives the same cost-to-go to the bit and measured 3.4x slower than the Dijkstra kernel on the largest eval
floor at 0.05 m (1.7x at 0.1 m; ``benchmarks/skimage``). It runs only when a new goal is chosen or the locked path
is blocked. :func:`path_is_clear` checks the cells within a radius given as the float it is (the robot radius over
the planning cell: 1.4999999999999998 on 0.1 m cells, the 3 x 3 square; 2.9999999999999996 on 0.05 m cells, a disc
that no ``skimage.morphology.disk`` of an integer radius gives; ``benchmarks/skimage``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.checks import cells_within, check_real
from superex_deploy.onboard.types import FREE, OCCUPIED, check_observed

__all__ = ["MAX_WALL_REACH_M", "MAX_WALL_REACH_CELLS", "check_wall_reach", "MotionConfig", "PlanningMap",
           "planning_map", "wall_distance", "dijkstra", "path_is_clear"]

MAX_WALL_REACH_M = 5.0
"""The largest robot radius and wall-cost range (metres). The wall distance is stamped from every wall cell over a
disc that wide, so its work grows with the square of it; MapEx's values are 0.15 m and 1 m."""
MAX_WALL_REACH_CELLS = 1000
"""The largest reach of :func:`wall_distance` (cells): its table of disc offsets holds ``(2 reach + 1)**2`` entries
(24 bytes each), 96 MB at this limit."""


@dataclass(frozen=True)
class MotionConfig(JsonConfig):
    """Robot motion and path planning.

    Attributes:
        robot_radius_m: walls are inflated by this (metres); the default reproduces MapEx's 3 x 3 dilation.
        wall_cost_weight: extra cost per cell right at a wall, falling linearly to zero at
            ``wall_cost_range_m`` (0 disables the proximity cost).
        wall_cost_range_m: reach of the wall-proximity cost (metres, > 0).
        step_m: how far the robot is expected to drive per step (metres; MapEx's ``ind_to_move_per_step`` of 3
            cells at 0.1 m): the simulator advances :meth:`cells_per_step` path cells, the same metres on any grid.
        goal_reached_m: a goal counts as reached within this straight-line distance (MapEx: 1 m); frontiers
            this close to the robot are not offered to the planner either.
        drive_carved: whether the explorer plans on cells known free only by NLOS carving. False: never, it plans
            (frontiers, paths, goal checks) on the line-of-sight map, whose free cells the map holds free with
            confidence; carved cells count for coverage and for the prediction only. True: always. None (the
            default): only while the pose is exact, i.e. the observation carries no pose covariance (the
            noise-free protocol, where carving is proven sound; the benchmark rows were made so); with a
            covariance (a robot), never.
        planning_cell_m: the planning (frontiers, Dijkstra, the planners' gains, paths) runs on blocks of the map's
            cells at most this wide (metres; :mod:`~superex_deploy.onboard.planning.coarse`): on a map finer than
            this, blocks of ``k x k`` cells, so a 0.05 m SLAM map is planned as the 0.1 m grid the planners were
            tuned on, at a quarter of the cells. At or below the map's resolution, its own cells.

    Raises:
        ValueError: ``MotionConfig: FIELD must ...``, for a field of another type, not finite or out of its range:
            ``robot_radius_m`` in ``[0, MAX_WALL_REACH_M]``, ``wall_cost_range_m`` in ``(0, MAX_WALL_REACH_M]``
            (:data:`MAX_WALL_REACH_M`), ``wall_cost_weight`` and ``goal_reached_m`` finite and >= 0,
            ``step_m`` and ``planning_cell_m`` positive and finite.
    """

    robot_radius_m: float = 0.15
    wall_cost_weight: float = 10.0
    wall_cost_range_m: float = 1.0
    step_m: float = 0.3
    goal_reached_m: float = 1.0
    drive_carved: Optional[bool] = None
    planning_cell_m: float = 0.1

    def __post_init__(self) -> None:
        if self.drive_carved is not None and not isinstance(self.drive_carved, bool):
            raise ValueError(f"MotionConfig: drive_carved must be True, False or None, got {self.drive_carved!r}")
        try:
            checked = {"robot_radius_m": check_real("robot_radius_m", self.robot_radius_m, 0.0, MAX_WALL_REACH_M),
                       "wall_cost_weight": check_real("wall_cost_weight", self.wall_cost_weight, 0.0),
                       "wall_cost_range_m": check_real("wall_cost_range_m", self.wall_cost_range_m, 0.0,
                                                       MAX_WALL_REACH_M, low_open=True),
                       "step_m": check_real("step_m", self.step_m, 0.0, low_open=True),
                       "goal_reached_m": check_real("goal_reached_m", self.goal_reached_m, 0.0),
                       "planning_cell_m": check_real("planning_cell_m", self.planning_cell_m, 0.0, low_open=True)}
        except ValueError as error:
            raise ValueError(f"MotionConfig: {error}") from None
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    def cells_per_step(self, resolution_m: float) -> int:
        """The path cells one step advances on a grid of ``resolution_m`` metres per cell: the most that fit in
        ``step_m`` (3 at 0.1 m, 6 at 0.05 m, 12 at 0.025 m), at least one.

        Raises:
            ValueError: ``resolution_m`` not positive and finite.
        """
        return max(1, cells_within(self.step_m, check_real("resolution_m", resolution_m, 0.0, low_open=True)))


@numba.njit(cache=True)
def _wall_distance(walls, reach_cells, distance):
    """Euclidean distance (cells, centre to centre) from every cell to the nearest wall cell, where it is at
    most ``reach_cells``; ``distance`` (float64, same shape as ``walls``) must be preset to ``inf`` and keeps it
    elsewhere. Walls whose four neighbours are all walls are skipped: one of those neighbours is always nearer
    to any cell outside the wall."""
    n_rows, n_cols = walls.shape
    reach = int(np.floor(reach_cells))
    n_offsets = 0
    offset_r = np.empty((2 * reach + 1) ** 2, np.int64)
    offset_c = np.empty((2 * reach + 1) ** 2, np.int64)
    offset_d = np.empty((2 * reach + 1) ** 2, np.float64)
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if dr * dr + dc * dc <= reach_cells * reach_cells:
                offset_r[n_offsets] = dr
                offset_c[n_offsets] = dc
                offset_d[n_offsets] = np.sqrt(dr * dr + dc * dc)
                n_offsets += 1
    for r in range(n_rows):
        for c in range(n_cols):
            if not walls[r, c]:
                continue
            if (0 < r < n_rows - 1 and 0 < c < n_cols - 1 and walls[r - 1, c] and walls[r + 1, c]
                    and walls[r, c - 1] and walls[r, c + 1]):
                distance[r, c] = 0.0
                continue
            for k in range(n_offsets):
                rr = r + offset_r[k]
                cc = c + offset_c[k]
                if 0 <= rr < n_rows and 0 <= cc < n_cols and offset_d[k] < distance[rr, cc]:
                    distance[rr, cc] = offset_d[k]


@numba.njit(cache=True)
def _dijkstra(costs, source, width, distance, parent):
    """Single-source Dijkstra on a flattened grid padded with a one-cell border of ``inf`` cost.

    ``costs``: float64 ``[n]`` move cost per cell (``inf``: impassable); ``source``: flat index of the start;
    ``width``: padded row length; ``distance`` (preset to ``inf``) and ``parent`` (preset to -1) are filled in
    place with the cost-to-go and the flat index of each reached cell's predecessor. Indexed binary heap with
    decrease-key: at most one heap entry per cell.
    """
    n = costs.shape[0]
    heap_key = np.empty(n, np.float64)
    heap_cell = np.empty(n, np.int64)
    position = np.full(n, -1, np.int64)  # heap slot; -1 never queued, -2 settled
    diagonal = np.sqrt(2.0)
    offsets = np.array([-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1], np.int64)
    lengths = np.array([diagonal, 1.0, diagonal, 1.0, 1.0, diagonal, 1.0, diagonal])
    distance[source] = 0.0
    heap_key[0] = 0.0
    heap_cell[0] = source
    position[source] = 0
    size = 1
    while size > 0:
        u = heap_cell[0]
        du = heap_key[0]
        position[u] = -2
        size -= 1
        if size > 0:  # sift the last entry down from the root
            moved_cell = heap_cell[size]
            moved_key = heap_key[size]
            i = 0
            while True:
                child = 2 * i + 1
                if child >= size:
                    break
                if child + 1 < size and heap_key[child + 1] < heap_key[child]:
                    child += 1
                if heap_key[child] >= moved_key:
                    break
                heap_key[i] = heap_key[child]
                heap_cell[i] = heap_cell[child]
                position[heap_cell[i]] = i
                i = child
            heap_key[i] = moved_key
            heap_cell[i] = moved_cell
            position[moved_cell] = i
        cu = costs[u]
        for k in range(8):
            v = u + offsets[k]
            cv = costs[v]
            if cv == np.inf or position[v] == -2:
                continue
            candidate = du + 0.5 * (cu + cv) * lengths[k]
            if candidate < distance[v]:
                distance[v] = candidate
                parent[v] = u
                i = position[v]
                if i == -1:
                    i = size
                    size += 1
                while i > 0:  # sift up
                    up = (i - 1) // 2
                    if heap_key[up] <= candidate:
                        break
                    heap_key[i] = heap_key[up]
                    heap_cell[i] = heap_cell[up]
                    position[heap_cell[i]] = i
                    i = up
                heap_key[i] = candidate
                heap_cell[i] = v
                position[v] = i


def wall_distance(walls: np.ndarray, reach_cells: float) -> np.ndarray:
    """Distance from each cell to the nearest wall, up to a reach.

    Args:
        walls: bool ``[H, W]``.
        reach_cells: largest distance computed (cells, in ``[0, MAX_WALL_REACH_CELLS]``).

    Returns:
        float64 ``[H, W]``: Euclidean centre-to-centre distance (cells) to the nearest wall cell where it is
        ``<= reach_cells``, ``inf`` elsewhere (0 on walls).
    """
    walls = np.ascontiguousarray(walls)
    if walls.dtype != np.bool_ or walls.ndim != 2:
        raise ValueError(f"walls must be a bool [H, W] array, got {walls.dtype} {walls.shape}")
    if not (0.0 <= float(reach_cells) <= MAX_WALL_REACH_CELLS):
        raise ValueError(f"reach_cells must lie in [0, {MAX_WALL_REACH_CELLS}] (MAX_WALL_REACH_CELLS), got "
                         f"{reach_cells}")
    distance = np.full(walls.shape, np.inf)
    _wall_distance(walls, float(reach_cells), distance)
    return distance


def _search(costs: np.ndarray, source_rc: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, int]:
    """Run :func:`_dijkstra` on ``costs`` padded with an impassable border. Returns the padded cost-to-go and
    parent grids (flat padded indices) and the padded row length."""
    n_rows, n_cols = costs.shape
    width = n_cols + 2
    padded = np.full((n_rows + 2, width), np.inf)
    padded[1:-1, 1:-1] = costs
    distance = np.full(padded.shape, np.inf)
    parent = np.full(padded.shape, -1, np.int64)
    _dijkstra(padded.reshape(-1), (source_rc[0] + 1) * width + source_rc[1] + 1, width, distance.reshape(-1),
              parent.reshape(-1))
    return distance, parent, width


def dijkstra(costs: np.ndarray, source_rc) -> tuple[np.ndarray, np.ndarray]:
    """Cost-to-go from one cell over an 8-connected grid (``MCP_Geometric``'s edge cost, see the module doc).

    Args:
        costs: float64 ``[H, W]`` move cost per cell, finite and > 0, or ``inf`` for impassable cells.
        source_rc: start cell (row, col); its cost must be finite.

    Returns:
        ``(cost_to_go float64 [H, W], parent int64 [H, W])``: ``inf`` / -1 where unreachable; ``parent`` holds
        the flat index ``row * W + col`` of each cell's predecessor on a least-cost path (-1 at the source).
    """
    costs = np.asarray(costs, dtype=np.float64)
    if costs.ndim != 2 or min(costs.shape) < 1:
        raise ValueError(f"costs must be a non-empty [H, W] array, got shape {costs.shape}")
    if np.any(np.isnan(costs)) or np.any(costs <= 0.0):
        raise ValueError("costs must be > 0 (inf for impassable cells), without NaN")
    r, c = int(source_rc[0]), int(source_rc[1])
    if not (0 <= r < costs.shape[0] and 0 <= c < costs.shape[1]):
        raise ValueError(f"source {(r, c)} lies outside the grid of shape {costs.shape}")
    if not np.isfinite(costs[r, c]):
        raise ValueError(f"source {(r, c)} is impassable (infinite cost)")
    distance, parent, width = _search(costs, (r, c))
    parent = parent[1:-1, 1:-1]
    unpadded = (parent // width - 1) * costs.shape[1] + parent % width - 1
    return distance[1:-1, 1:-1].copy(), np.where(parent >= 0, unpadded, -1)


@dataclass(frozen=True)
class PlanningMap:
    """Cost-to-go from the robot on the planning map.

    Attributes:
        traversable: bool ``[H, W]`` cells the robot may occupy (see the module docstring).
        travel_cost: float64 ``[H, W]`` cost-to-go from the robot's cell (cell lengths weighted by the
            proximity cost; 0 at the robot); ``inf`` where unreachable.
        origin_rc: offset of the search window in the full map (row, col).
    """

    traversable: np.ndarray
    travel_cost: np.ndarray
    origin_rc: tuple[int, int]
    # int64 [h + 2, w + 2]: predecessor links of the search window padded by one cell, as flat padded indices.
    _parent: np.ndarray

    def path_to(self, goal_rc) -> list[tuple[int, int]]:
        """Least-cost 8-connected path from the robot's cell to ``goal_rc``, both included; empty if the goal
        is unreachable or off the map."""
        r, c = int(goal_rc[0]), int(goal_rc[1])
        shape = self.travel_cost.shape
        if not (0 <= r < shape[0] and 0 <= c < shape[1]) or not np.isfinite(self.travel_cost[r, c]):
            return []
        # Padded window index (r - r0 + 1, c - c0 + 1) is full-map cell (r, c): shift by origin - 1.
        r_shift, c_shift = self.origin_rc[0] - 1, self.origin_rc[1] - 1
        width = self._parent.shape[1]
        cell = (r - r_shift) * width + (c - c_shift)
        path = []
        while cell >= 0:
            path.append((int(cell // width + r_shift), int(cell % width + c_shift)))
            cell = int(self._parent.flat[cell])
        return path[::-1]


def _check_observed_and_pose(observed: np.ndarray, pose_rc) -> tuple[np.ndarray, tuple[int, int]]:
    observed = check_observed(observed)
    r, c = int(pose_rc[0]), int(pose_rc[1])
    if not (0 <= r < observed.shape[0] and 0 <= c < observed.shape[1]):
        raise ValueError(f"robot cell {(r, c)} lies outside the map of shape {observed.shape}")
    return observed, (r, c)


def check_wall_reach(cfg: MotionConfig, resolution_m: float) -> float:
    """How far (cells) the wall distances of a planning map are computed at ``resolution_m`` metres per cell:
    exact up to a reach beyond both the robot radius and the wall cost range (farther cells are traversable and
    pay no proximity cost whatever their true distance). An explorer checks it once, at construction, so that a
    grid too fine for its motion settings is refused before the first step.

    Raises:
        ValueError: a reach of more than :data:`MAX_WALL_REACH_CELLS` cells.
    """
    reach_cells = float(np.floor(max(cfg.robot_radius_m, cfg.wall_cost_range_m) / float(resolution_m)) + 1.0)
    if reach_cells > MAX_WALL_REACH_CELLS:
        raise ValueError(f"MotionConfig: robot_radius_m {cfg.robot_radius_m} / wall_cost_range_m "
                         f"{cfg.wall_cost_range_m} reach {reach_cells:.0f} cells at {resolution_m} m per cell, more "
                         f"than MAX_WALL_REACH_CELLS ({MAX_WALL_REACH_CELLS})")
    return reach_cells


def planning_map(observed: np.ndarray, pose_rc, resolution_m: float,
                 cfg: MotionConfig = MotionConfig()) -> PlanningMap:
    """Build the planning map and run Dijkstra from the robot's cell.

    Args:
        observed: int8 ``[H, W]`` observed map (UNKNOWN / FREE / OCCUPIED).
        pose_rc: robot cell (row, col).
        resolution_m: metres per cell.
        cfg: robot radius, proximity cost.

    Returns:
        The :class:`PlanningMap` (full-map arrays; the search itself ran on the known bounding box).

    Raises:
        ValueError: a bad map, pose or resolution; a robot radius or wall cost range wider than
            :data:`MAX_WALL_REACH_CELLS` cells at this resolution.
    """
    observed, (pr, pc) = _check_observed_and_pose(observed, pose_rc)
    if not (float(resolution_m) > 0.0 and np.isfinite(resolution_m)):
        raise ValueError(f"resolution_m must be positive and finite, got {resolution_m}")
    free = observed == FREE
    free[pr, pc] = True
    rows = np.flatnonzero(free.any(axis=1))
    cols = np.flatnonzero(free.any(axis=0))
    r0, r1 = max(int(rows[0]) - 1, 0), min(int(rows[-1]) + 2, observed.shape[0])
    c0, c1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, observed.shape[1])
    local_free = free[r0:r1, c0:c1]
    local_walls = observed[r0:r1, c0:c1] == OCCUPIED
    radius_cells = cfg.robot_radius_m / float(resolution_m)
    range_cells = cfg.wall_cost_range_m / float(resolution_m)
    reach_cells = check_wall_reach(cfg, resolution_m)
    wall_distance_cells = wall_distance(local_walls, reach_cells)
    local_traversable = local_free & (wall_distance_cells > radius_cells)
    local_traversable[pr - r0, pc - c0] = True
    proximity = np.maximum(1.0 - wall_distance_cells / range_cells, 0.0)
    costs = np.where(local_traversable, 1.0 + cfg.wall_cost_weight * proximity, np.inf)
    distance, parent, _ = _search(costs, (pr - r0, pc - c0))
    travel_cost = np.full(observed.shape, np.inf)
    travel_cost[r0:r1, c0:c1] = distance[1:-1, 1:-1]
    traversable = np.zeros(observed.shape, bool)
    traversable[r0:r1, c0:c1] = local_traversable
    return PlanningMap(traversable=traversable, travel_cost=travel_cost, origin_rc=(r0, c0), _parent=parent)


def path_is_clear(observed: np.ndarray, path, radius_cells: float) -> bool:
    """Whether a previously planned path is still safe on the current map, without a new search.

    Args:
        observed: int8 ``[H, W]`` current observed map.
        path: the remaining path cells ``[(row, col), ...]`` (the robot's own cell excluded).
        radius_cells: robot radius in cells.

    Returns:
        True when every path cell is known FREE with no observed wall within ``radius_cells`` (the traversable
        rule of :func:`planning_map`); True for an empty path.
    """
    if len(path) == 0:
        return True
    cells = np.asarray(path, np.int64).reshape(-1, 2)
    if np.any(observed[cells[:, 0], cells[:, 1]] != FREE):
        return False
    reach = int(np.floor(radius_cells))
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if dr * dr + dc * dc > radius_cells * radius_cells:
                continue
            rows = np.clip(cells[:, 0] + dr, 0, observed.shape[0] - 1)
            cols = np.clip(cells[:, 1] + dc, 0, observed.shape[1] - 1)
            if np.any(observed[rows, cols] == OCCUPIED):
                return False
    return True

