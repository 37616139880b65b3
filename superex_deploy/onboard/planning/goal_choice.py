"""Which frontier the explorer offers its planner, and when a goal counts as reached: the rules shared by
:meth:`Explorer.step <superex_deploy.onboard.explorer.Explorer.step>` and
:meth:`Explorer.frontier_candidates <superex_deploy.onboard.explorer.Explorer.frontier_candidates>`."""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from superex_deploy.geometry import line_of_sight
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.types import Frontier

__all__ = ["goal_reached", "near_visited_goal", "unreached", "choose_goal", "near_frontier", "frontier_left"]


def goal_reached(not_free: np.ndarray, pose: tuple[int, int], cell: tuple[int, int], reach_cells: float) -> bool:
    """Whether the robot at ``pose`` has reached the goal ``cell``: within the goal tolerance *and* in line of
    sight on the map (``not_free``: bool ``[H, W]``, every cell not known free).

    Distance alone (MapEx's rule) counts a frontier as reached from behind the corner of the wall that hides it,
    and the robot can then shuttle between two such frontiers without ever seeing either (measured in
    docs/benchmarks/better-map.md, "A defect first"). Seeing the goal cell means the sensor has looked at the
    frontier from that side."""
    if np.hypot(cell[0] - pose[0], cell[1] - pose[1]) > reach_cells:
        return False
    return line_of_sight(not_free, pose, cell)


def near_visited_goal(cell: tuple[int, int], visited: set[tuple[int, int]]) -> bool:
    """Whether ``cell`` is a reached goal or one of its 8 neighbours: a frontier whose goal cell was reached
    and that is still there cannot be resolved from where the robot can stand (unknown cells seen only edge-on,
    the inside of a thick wall), and would be offered again as soon as the robot left."""
    return any((cell[0] + dr, cell[1] + dc) in visited for dr in (-1, 0, 1) for dc in (-1, 0, 1))


def unreached(regions: tuple[Frontier, ...], not_free: np.ndarray, pose: tuple[int, int], reach_cells: float,
              visited: set[tuple[int, int]]) -> tuple[Frontier, ...]:
    """The regions a planner may be offered with the robot at ``pose``: their goal not reached from there
    (:func:`goal_reached`) nor a reached goal or next to one (:func:`near_visited_goal`). Order is kept."""
    return tuple(f for f in regions if not near_visited_goal(f.cell_rc, visited)
                 and not goal_reached(not_free, pose, f.cell_rc, reach_cells))


def choose_goal(offer: Callable[[tuple[Frontier, ...]], Optional[tuple[int, int]]], observed: np.ndarray,
            frontiers: tuple[Frontier, ...], min_cells: int, not_free: np.ndarray, pose: tuple[int, int],
            reach_cells: float, visited: set[tuple[int, int]],
            admit: Optional[Callable[[tuple[Frontier, ...]], tuple[Frontier, ...]]] = None
            ) -> tuple[Optional[tuple[int, int]], float]:
    """Offer the frontiers to the planner in three tiers; returns the goal (or None: nothing is left) and the
    distance within which it counts as reached.

    1. Regions of at least ``min_cells`` cells that do not count as reached already (:func:`goal_reached`: MapEx's
       validity rule, since offering one would lock the robot onto a goal it never leaves) and whose goal cell
       the robot has not reached before (:func:`near_visited_goal`).
    2. The same for smaller regions: a doorway seen edge-on can show fewer frontier cells than the minimum, and
       a robot must not stop in a room with an open door.
    3. Regions that count as reached from where the robot stands but were never visited: their goal cell is in
       sight within the tolerance while the unknown behind them is not (seen through a door at a steep angle).
       The robot then drives onto the goal cell itself (tolerance 0) instead of declaring the map explored.

    ``frontiers`` are the first tier's regions as offered (already cut to the exploration bounds, blacklisted ones
    dropped); ``admit`` applies the same to the smaller regions found here (None: all of them).
    """
    admit = admit or (lambda regions: regions)
    small: Optional[tuple[Frontier, ...]] = None
    if not frontiers:
        small = admit(find_frontiers(observed, 1))
        if not small:
            return None, reach_cells
    unvisited = [f for f in frontiers if not near_visited_goal(f.cell_rc, visited)]
    candidates = tuple(f for f in unvisited if not goal_reached(not_free, pose, f.cell_rc, reach_cells))
    # The planner is asked even when every region was filtered out: UPEN's tree can still find a goal.
    chosen = offer(candidates) if frontiers else None
    if chosen is not None:
        return chosen, reach_cells
    if small is None:
        small = tuple(f for f in admit(find_frontiers(observed, 1)) if len(f.cells) < min_cells) \
            if min_cells > 1 else ()
    small_unvisited = [f for f in small if not near_visited_goal(f.cell_rc, visited)]
    candidates = tuple(f for f in small_unvisited if not goal_reached(not_free, pose, f.cell_rc, reach_cells))
    chosen = offer(candidates) if small else None
    if chosen is not None:
        return chosen, reach_cells
    close = tuple(f for f in unvisited + small_unvisited if goal_reached(not_free, pose, f.cell_rc, reach_cells))
    chosen = offer(close) if close else None
    return chosen, 0.0


def near_frontier(regions: tuple[Frontier, ...], cell: tuple[int, int], radius_cells: float,
                  min_cells: int = 1) -> bool:
    """Whether a frontier cell of one of ``regions`` with at least ``min_cells`` cells lies within ``radius_cells``
    of ``cell`` (a kept goal whose frontier is not gone)."""
    for frontier in regions:
        if frontier.extent < min_cells:
            continue
        d = frontier.cells - np.asarray(cell)
        if np.any(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] <= radius_cells * radius_cells):
            return True
    return False


def frontier_left(regions: tuple[Frontier, ...], min_cells: int, travel_cost: np.ndarray,
                  visited: set[tuple[int, int]]) -> bool:
    """Whether one of ``regions`` (already cut to the bounds, blacklisted ones dropped) keeps an exploration alive:
    at least ``min_cells`` cells (before the bounds cut it: ``Frontier.extent``), its goal cell not a reached goal's (:func:`near_visited_goal`), and of finite cost
    in float ``[H, W]`` ``travel_cost`` (a clipped region: any of its cells,
    :func:`~superex_deploy.onboard.planning.bounds.reachable_goals`)."""
    from superex_deploy.onboard.planning.bounds import reachable_goals

    big = tuple(f for f in regions if f.extent >= min_cells and not near_visited_goal(f.cell_rc, visited))
    return any(np.isfinite(travel_cost[f.cell_rc]) for f in reachable_goals(big, travel_cost))
