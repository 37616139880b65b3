"""The exploration region: a polygon in map-frame metres (:class:`ExplorationBounds`) outside which frontiers are
ignored, so that a robot explores one wing of a building and stops when that wing is done.

The polygon is rasterised onto the explorer's grid by the even-odd rule on cell centres (:meth:`ExplorationBounds.
mask`): a cell belongs to the region when its centre lies inside. A map that grows moves to a new grid, and the mask
is computed again for it (the polygon itself never moves: it is in metres). Frontier regions are clipped to the mask
before the planner sees them (:func:`clip_frontiers`): cells whose centre lies outside are dropped, a region with no
cell left is dropped, and a region cut in part gets as goal cell its kept cell nearest to the kept cells' centroid
(the rule of :func:`~superex_deploy.onboard.planning.frontiers.find_frontiers`) and keeps its size before the cut
(``Frontier.whole_size``: the finish rule reads it, a doorway cut to a few cells leads to a whole room). When the
planner is asked, a clipped region whose goal cell no path reaches (a frontier cut to the few cells beside a door
frame, inside the robot's clearance of it) takes its kept cell nearest the centroid that a path reaches
(:func:`reachable_goals`): the cut must not drop the only way into the rest of the region.

A polygon too small to hold the robot (no disc of ``MotionConfig.robot_radius_m`` fits inside) is refused when the
explorer's configuration is built (:meth:`ExplorationBounds.check_holds`): a robot cannot explore a region it does
not fit in, and such a run would end at its first step.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass
from typing import Optional

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.types import Frontier

__all__ = ["ExplorationBounds", "clip_frontiers", "reachable_goals", "parse_bounds"]


def _orientation(a, b, c) -> float:
    """Twice the signed area of triangle ``abc`` (positive: counter-clockwise)."""
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _on_segment(a, b, p) -> bool:
    """Whether ``p``, collinear with ``ab``, lies within the segment's bounding box."""
    return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])


def _segments_meet(a, b, c, d) -> bool:
    """Whether the closed segments ``ab`` and ``cd`` share a point (touching counts)."""
    o1, o2, o3, o4 = _orientation(a, b, c), _orientation(a, b, d), _orientation(c, d, a), _orientation(c, d, b)
    if ((o1 > 0) != (o2 > 0)) and ((o3 > 0) != (o4 > 0)) and 0 not in (o1, o2, o3, o4):
        return True
    return ((o1 == 0 and _on_segment(a, b, c)) or (o2 == 0 and _on_segment(a, b, d))
            or (o3 == 0 and _on_segment(c, d, a)) or (o4 == 0 and _on_segment(c, d, b)))


def _point(index: int, value) -> tuple[float, float]:
    """Point ``index`` as a pair of finite floats (metres), or one ValueError naming it."""
    try:
        x, y = value
    except (TypeError, ValueError):
        raise ValueError(f"bounds point {index} must be a pair (x, y) of finite numbers in metres, got "
                         f"{value!r}") from None
    if any(isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) for v in (x, y)):
        raise ValueError(f"bounds point {index} must be a pair (x, y) of finite numbers in metres, got "
                         f"{value!r}")
    return float(x), float(y)


@dataclass(frozen=True)
class ExplorationBounds(JsonConfig):
    """A simple polygon in map-frame metres: the region to explore.

    Attributes:
        points: the polygon's corners ``((x, y), ...)`` in metres, in either winding order, at least 3, not closed
            (the last corner joins the first by itself). A list of pairs (as a recording's metadata holds it) is
            accepted and stored as a tuple of float pairs.

    Raises:
        ValueError: fewer than 3 points, a point that is not a pair of finite numbers, a polygon that crosses or
            touches itself (two edges that are not neighbours share a point, or a corner repeated), or one of zero
            area.
    """

    points: tuple

    def __post_init__(self) -> None:
        if isinstance(self.points, (str, bytes)) or not hasattr(self.points, "__len__"):
            raise ValueError(f"bounds must be a sequence of (x, y) points in metres, got {self.points!r:.80}")
        if len(self.points) < 3:
            raise ValueError(f"bounds must have at least 3 points (x, y), got {len(self.points)}")
        points = tuple(_point(i, p) for i, p in enumerate(self.points))
        object.__setattr__(self, "points", points)
        n = len(points)
        for i in range(n):
            if points[i] == points[(i + 1) % n]:
                raise ValueError(f"bounds polygon repeats point {i} {points[i]} at point {(i + 1) % n}: it must "
                                 f"not touch itself")
        for i in range(n):
            for j in range(i + 2, n):
                if i == 0 and j == n - 1:
                    continue  # neighbours through the closing edge
                a, b, c, d = points[i], points[(i + 1) % n], points[j], points[(j + 1) % n]
                if _segments_meet(a, b, c, d):
                    raise ValueError(f"bounds polygon crosses itself: edge {i} {a}-{b} meets edge {j} {c}-{d}")
        if self.area_m2 == 0.0:
            raise ValueError("bounds polygon has zero area")

    @property
    def area_m2(self) -> float:
        """The polygon's area (square metres; shoelace formula)."""
        xy = np.asarray(self.points, np.float64)
        x, y = xy[:, 0], xy[:, 1]
        return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)) / 2.0)

    def contains_xy(self, xy) -> np.ndarray:
        """bool ``[N]``: whether each map-frame point of float ``[N, 2]`` ``xy`` (metres) lies inside (even-odd rule;
        a point exactly on an edge may fall on either side)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        px, py = xy[:, 0], xy[:, 1]
        inside = np.zeros(len(xy), bool)
        corners = self.points
        for (x1, y1), (x2, y2) in zip(corners, corners[1:] + corners[:1]):
            if y1 == y2:
                continue  # a horizontal edge never crosses the ray
            crosses = (y1 > py) != (y2 > py)
            x_cross = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
            inside ^= crosses & (px < x_cross)
        return inside

    def mask(self, frame: MapFrame) -> np.ndarray:
        """bool ``[H, W]`` on ``frame``: the cells whose centre lies inside (only the polygon's bounding box is
        tested)."""
        h, w = frame.shape
        mask = np.zeros((h, w), bool)
        xy = np.asarray(self.points, np.float64)
        res, (ox, oy) = frame.resolution_m, frame.origin_xy
        col_lo = max(int(np.floor((xy[:, 0].min() - ox) / res)) - 1, 0)
        col_hi = min(int(np.ceil((xy[:, 0].max() - ox) / res)) + 1, w)
        row_lo = max(h - int(np.ceil((xy[:, 1].max() - oy) / res)) - 1, 0)
        row_hi = min(h - int(np.floor((xy[:, 1].min() - oy) / res)) + 1, h)
        if col_lo >= col_hi or row_lo >= row_hi:
            return mask
        rows, cols = np.mgrid[row_lo:row_hi, col_lo:col_hi]
        cells = np.stack([rows.ravel(), cols.ravel()], axis=1)
        mask[row_lo:row_hi, col_lo:col_hi] = self.contains_xy(frame.centres_xy(cells)).reshape(rows.shape)
        return mask

    @functools.cached_property
    def inradius_m(self) -> float:
        """The radius (metres) of the largest disc inside the polygon, measured on a raster of about a million
        pixels over its bounding box (off by at most a pixel: 3 mm for a 100 m x 0.32 m corridor, 0.3 mm for a
        0.3 m square), from the exact Euclidean distance transform of the even-odd mask (scipy); computed once."""
        from scipy.ndimage import distance_transform_edt

        xy = np.asarray(self.points, np.float64)
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        pixel = max(float(np.sqrt((hi - lo).prod() / 1e6)), 1e-9)
        cols = int(np.ceil((hi[0] - lo[0]) / pixel)) + 2
        rows = int(np.ceil((hi[1] - lo[1]) / pixel)) + 2
        gx = lo[0] + (np.arange(cols) - 0.5) * pixel
        gy = lo[1] + (np.arange(rows) - 0.5) * pixel
        grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
        inside = self.contains_xy(grid).reshape(rows, cols)
        if not inside.any():
            return 0.0
        return float(max(distance_transform_edt(inside).max() - 0.5, 0.0) * pixel)

    def check_holds(self, radius_m: float) -> None:
        """Refuse a polygon that holds no disc of ``radius_m`` metres (the robot's radius): a robot cannot stand
        in it, let alone explore it.

        Raises:
            ValueError: the polygon's largest inscribed disc is not larger than ``radius_m``.
        """
        inradius = self.inradius_m
        if inradius <= radius_m:
            raise ValueError(f"the exploration bounds are smaller than the robot: the largest disc inside the polygon "
                             f"has a radius of {inradius:.3f} m, the robot's is {radius_m:.3f} m "
                             f"(MotionConfig.robot_radius_m); points {list(self.points)}")

    def check_contains(self, x: float, y: float) -> None:
        """Refuse a robot pose (metres) outside the region: exploring from outside it could never be bounded.

        Raises:
            ValueError: the point lies outside the polygon.
        """
        if not self.contains_xy([(x, y)])[0]:
            raise ValueError(f"the exploration bounds must contain the robot's start pose: (x, y) = "
                             f"({x:.3f}, {y:.3f}) m lies outside the polygon {list(self.points)}")


def parse_bounds(text: str) -> ExplorationBounds:
    """The bounds of the command line's ``"x1,y1 x2,y2 x3,y3 ..."`` (metres, map frame).

    Raises:
        ValueError: text that is not space-separated ``x,y`` pairs of numbers, or a polygon
            :class:`ExplorationBounds` refuses.
    """
    points = []
    for i, pair in enumerate(str(text).split()):
        parts = pair.split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            points.append((float(parts[0]), float(parts[1])))
        except ValueError:
            raise ValueError(f"--bounds point {i} must be 'x,y' (two numbers in metres, no space), got "
                             f"{pair!r}") from None
    return ExplorationBounds(tuple(points))


def clip_frontiers(frontiers: tuple[Frontier, ...], inside: Optional[np.ndarray]) -> tuple[Frontier, ...]:
    """The frontier regions cut to the cells where bool ``[H, W]`` ``inside`` holds (see the module docstring;
    ``inside`` None: ``frontiers`` itself). Order is kept."""
    if inside is None:
        return frontiers
    kept = []
    for frontier in frontiers:
        within = inside[frontier.cells[:, 0], frontier.cells[:, 1]]
        if within.all():
            kept.append(frontier)
        elif within.any():
            cells = frontier.cells[within]
            centroid = cells.mean(axis=0)
            nearest = int(np.argmin(((cells - centroid) ** 2).sum(axis=1)))  # first of equals: row-major order
            kept.append(Frontier(cell_rc=(int(cells[nearest, 0]), int(cells[nearest, 1])), cells=cells,
                                 whole_size=frontier.extent))
    return tuple(kept)


def reachable_goals(frontiers, travel_cost: np.ndarray) -> tuple[Frontier, ...]:
    """The frontier regions with each clipped one (:func:`clip_frontiers`) whose goal cell is unreachable (``inf``
    in float ``[H, W]`` ``travel_cost``) given its reachable cell nearest the centroid of its cells as goal cell
    (ties: row-major order); regions not clipped, or with no reachable cell, as they are. Order is kept."""
    out = []
    for frontier in frontiers:
        if frontier.clipped and not np.isfinite(travel_cost[frontier.cell_rc]):
            cells = frontier.cells
            reachable = np.isfinite(travel_cost[cells[:, 0], cells[:, 1]])
            if reachable.any():
                centroid = cells.mean(axis=0)
                options = cells[reachable]
                nearest = int(np.argmin(((options - centroid) ** 2).sum(axis=1)))
                frontier = Frontier(cell_rc=(int(options[nearest, 0]), int(options[nearest, 1])), cells=cells,
                                    whole_size=frontier.whole_size)
        out.append(frontier)
    return tuple(out)
