"""Dead ends: the part of a floor that an obstruction turns into a cul-de-sac, and how far a robot drives into one.

A *dead end* (:class:`DeadEnd`) is measured from one side of an obstruction (a cut across a passage, see
:mod:`superex_deploy.sim.alterations`) over the robot's reachable cells ``reach`` (8-connected cells the robot's
centre may occupy, see :func:`robot_cells`):

* ``h``: the geodesic distance (metres, 8-connected, :func:`superex_deploy.onboard.planning.motion.dijkstra`) from the
  reachable cell right in front of the obstruction's face (the *front*);
* the level band ``L``: the reachable cells with ``L <= h < L + w`` (``w`` at least 1.5 cells, so that no
  8-connected path skips it). The band has a *mouth* when one 8-connected piece of it, at most
  ``max_mouth_width_m`` across, separates the front from the start on its own (the other pieces lead into side
  rooms that end); the *pocket* is then every reachable cell on the front's side of that piece. A dead end's
  pocket never holds the start.
* ``length_m``: the largest level with a mouth, scanned in ``level_step_m`` steps upwards from the shortest level
  that could qualify until ``patience_m`` of levels in a row have none (a dead end's levels are contiguous in
  practice, from the obstruction to the branch entrance) or the pocket would grow beyond ``max_pocket_cells``; the
  pocket and mouth of that level are the dead end's (the mouth is the *branch entrance*).
* ``hidden_m``: how far into the pocket (metres of ``h``, from the mouth) a robot must drive before the obstruction
  can be in its line of sight: ``length_m`` minus the largest ``h`` of a reachable cell that sees a free cell
  touching the obstruction's face (rays of ``sight_range_m`` cast from those face cells). A face in sight of a
  cell farther than the longest dead end sought leaves no dead end.

:func:`dead_end_entries` reads an episode's poses against the dead ends: an *entry* is a run of consecutive poses
inside a pocket that goes at least ``min_depth_m`` deep (depth = ``length_m - h``, at least 0: 0 at the mouth and in
side rooms that reach back beyond it, the dead end's length at the obstruction).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from scipy import ndimage

from superex_deploy.geometry import cell_centre, line_of_sight, mark_rays, ray_angles
from superex_deploy.onboard.planning.motion import dijkstra

__all__ = ["DeadEnd", "DeadEndEntries", "robot_cells", "measure_dead_end", "face_hidden_from", "dead_end_entries"]

_EIGHT = np.ones((3, 3), bool)


def _check_grids(cells: dict, **grids: np.ndarray) -> None:
    """Raise ValueError unless every grid is a bool 2-D array of the first one's shape and every cell of ``cells``
    (name -> (row, col)) lies inside it."""
    shape = None
    for name, grid in grids.items():
        if not isinstance(grid, np.ndarray) or grid.dtype != np.bool_ or grid.ndim != 2:
            raise ValueError(f"{name} must be a bool [H, W] array, got {getattr(grid, 'dtype', type(grid).__name__)}"
                             f" {getattr(grid, 'shape', '')}")
        if shape is not None and grid.shape != shape:
            raise ValueError(f"{name} has shape {grid.shape}, expected {shape}")
        shape = grid.shape
    for name, (row, col) in cells.items():
        if not (0 <= row < shape[0] and 0 <= col < shape[1]):
            raise ValueError(f"{name} {(row, col)} lies outside the grid of shape {shape}")


def robot_cells(occupied: np.ndarray, start_rc, robot_radius_cells: float) -> np.ndarray:
    """bool ``[H, W]``: the cells the robot's centre can reach from ``start_rc``, 8-connected, each free and farther
    than ``robot_radius_cells`` (centre to centre) from every occupied cell: the planner's traversability
    (:mod:`superex_deploy.onboard.planning.motion`) on the true map. The valid area plays no part: the robot drives through
    every free cell, and the eval floors' valid areas leave the doorways out (on the train floors they hold them). The
    start cell itself always counts, as the planner counts the robot's own cell.

    Raises:
        ValueError: a grid that is not a bool ``[H, W]`` array, a start outside it, a negative radius.
    """
    start_rc = tuple(int(v) for v in start_rc)
    _check_grids({"start_rc": start_rc}, occupied=occupied)
    if not float(robot_radius_cells) >= 0.0:
        raise ValueError(f"robot_radius_cells must be >= 0, got {robot_radius_cells}")
    clearance = ndimage.distance_transform_edt(np.pad(~occupied, 1, constant_values=False))[1:-1, 1:-1]
    traversable = ~occupied & (clearance > robot_radius_cells)
    traversable[start_rc] = True
    labels, _ = ndimage.label(traversable, structure=_EIGHT)
    return labels == labels[start_rc]


@dataclass(frozen=True, eq=False)
class DeadEnd:
    """A cul-de-sac in front of one face of an obstruction (see the module docstring).

    Attributes:
        pocket: bool ``[H, W]`` the reachable cells of the dead end (robot-centre cells).
        depth_m: float32 ``[H, W]`` depth into the pocket in metres (``length_m - h``, at least 0: 0 at the
            mouth, ``length_m`` at the obstruction); NaN outside the pocket.
        mouth: int64 ``[M, 2]`` (row, col) the reachable cells bordering the pocket: the branch entrance.
        face: int64 ``[F, 2]`` (row, col) free cells 4-adjacent to the obstruction on the pocket's side.
        length_m: geodesic length of the dead end (metres).
        hidden_m: how far into the pocket a robot must drive before it can see the obstruction (metres).
        area_m2: the pocket's area (robot-centre cells, square metres).
    """

    pocket: np.ndarray
    depth_m: np.ndarray
    mouth: np.ndarray
    face: np.ndarray
    length_m: float
    hidden_m: float
    area_m2: float


def _window_distance(reach: np.ndarray, cut: np.ndarray, front_rc, radius_cells: float) -> np.ndarray:
    """float64 ``[H, W]`` geodesic distance (cells) from ``front_rc`` over ``reach & ~cut``, exact where below
    ``radius_cells`` (the search stays in the square window of that half-size: a path that leaves it is longer),
    ``inf`` elsewhere."""
    pad = int(np.ceil(radius_cells)) + 1
    r0, c0 = max(front_rc[0] - pad, 0), max(front_rc[1] - pad, 0)
    r1, c1 = front_rc[0] + pad + 1, front_rc[1] + pad + 1
    costs = np.where(reach[r0:r1, c0:c1] & ~cut[r0:r1, c0:c1], 1.0, np.inf)
    distance = np.full(reach.shape, np.inf)
    distance[r0:r1, c0:c1] = dijkstra(costs, (front_rc[0] - r0, front_rc[1] - c0))[0]
    distance[distance >= radius_cells] = np.inf
    return distance


def _neighbour_pairs(labels_a: np.ndarray, labels_b: np.ndarray) -> set:
    """The ``(a, b)`` label pairs (both > 0) of 8-neighbouring (or equal) cells of two label grids of one shape."""
    pairs = set()
    n_rows, n_cols = labels_a.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            a = labels_a[max(dr, 0):n_rows + min(dr, 0), max(dc, 0):n_cols + min(dc, 0)]
            b = labels_b[max(-dr, 0):n_rows + min(-dr, 0), max(-dc, 0):n_cols + min(-dc, 0)]
            both = (a > 0) & (b > 0)
            if both.any():
                pairs.update(zip(a[both].tolist(), b[both].tolist()))
    return pairs


def _separating_piece(reach: np.ndarray, band: np.ndarray, source_rc, outside: np.ndarray, max_width_cells: float
                      ) -> Optional[np.ndarray]:
    """The one 8-connected piece of ``band`` whose removal alone from ``reach`` separates the source from the
    ``outside`` cells (the start and the way out of the window searched), or None when no single piece does (two
    ways out, or none needed) or the one that does spans more than ``max_width_cells`` (the diagonal of its
    bounding box: not a door or a corridor)."""
    rest_labels, _ = ndimage.label(reach & ~band, structure=_EIGHT)
    source = rest_labels[source_rc]
    targets = set(np.unique(rest_labels[outside & (rest_labels > 0)]).tolist())
    if source == 0 or not targets or source in targets:
        return None
    cells = np.argwhere(band)
    (r0, c0), (r1, c1) = np.maximum(cells.min(axis=0) - 1, 0), cells.max(axis=0) + 2
    piece_labels, n_pieces = ndimage.label(band[r0:r1, c0:c1], structure=_EIGHT)
    touches = [set() for _ in range(n_pieces)]
    for piece, rest in _neighbour_pairs(piece_labels, rest_labels[r0:r1, c0:c1]):
        touches[piece - 1].add(rest)
    for k in range(n_pieces):
        linked, frontier = {source}, [source]
        while frontier:  # components joined through the other pieces
            component = frontier.pop()
            for j, touched in enumerate(touches):
                if j != k and component in touched:
                    for other in touched - linked:
                        linked.add(other)
                        frontier.append(other)
        if not linked & targets:
            piece = np.zeros(reach.shape, bool)
            piece[r0:r1, c0:c1] = piece_labels == k + 1
            extent = np.ptp(np.argwhere(piece), axis=0)
            return piece if np.hypot(*extent) <= max_width_cells else None
    return None


def _sight_reach(occupied: np.ndarray, face: np.ndarray, sight_cells: float, max_faces: int = 16) -> np.ndarray:
    """bool ``[H, W]`` cells seen (rays through free cells) from the centres of up to ``max_faces`` face cells."""
    seen, hit = np.zeros(occupied.shape, bool), np.zeros(occupied.shape, bool)
    angles = ray_angles(1440)
    for rc in face[np.linspace(0, len(face) - 1, min(len(face), max_faces)).astype(int)]:
        mark_rays(occupied, cell_centre(rc), angles, sight_cells, seen, hit)
    return seen


def measure_dead_end(occupied: np.ndarray, reach: np.ndarray, cut: np.ndarray, front_rc, face: np.ndarray,
                     start_rc, resolution_m: float, min_length_m: float = 5.0, min_hidden_m: float = 0.0,
                     max_length_m: float = 30.0, level_step_m: float = 0.5, sight_range_m: float = 20.0,
                     patience_m: float = 3.0, max_pocket_cells: Optional[int] = None,
                     max_mouth_width_m: float = 3.0) -> Optional[DeadEnd]:
    """The dead end in front of one face of an obstruction, or None where none is ``min_length_m`` long with its
    obstruction hidden ``min_hidden_m`` deep (see the module docstring).

    The levels are scanned from the shortest that could qualify upwards, until ``patience_m`` of levels in a row
    have no single separating piece (from the first level on: a dead end's levels are contiguous in practice, from
    the obstruction to the branch entrance), until a pocket would hold more than ``max_pocket_cells`` cells (a
    pocket only grows with its level), or up to ``max_length_m``.

    Args:
        occupied: bool ``[H, W]`` the altered floor's walls (the obstruction included).
        reach: bool ``[H, W]`` the robot's reachable cells on the altered floor (:func:`robot_cells`).
        cut: bool ``[H, W]`` the obstruction's cells.
        front_rc: the reachable cell right in front of the face (row, col): where ``h`` is 0.
        face: int ``[F, 2]`` free cells 4-adjacent to the obstruction on this side.
        start_rc: the robot's start cell.
        resolution_m: metres per cell.
        min_length_m, min_hidden_m, max_length_m, level_step_m: the dead ends sought (metres).
        patience_m: see above.
        max_pocket_cells: the largest pocket sought (cells; None: no limit).
        max_mouth_width_m: the widest mouth sought (the diagonal of its bounding box): a door's or a corridor's
            cross-section, not a line across a hall.
        sight_range_m: how far a robot sees (the LiDAR's range).

    Raises:
        ValueError: grids that are not bool ``[H, W]`` arrays of one shape, cells outside them, a front that is not
            a reachable cell, no face cells, a resolution or lengths that are not positive.
    """
    front_rc, start_rc = tuple(int(v) for v in front_rc), tuple(int(v) for v in start_rc)
    face = np.asarray(face, np.int64).reshape(-1, 2)
    _check_grids({"front_rc": front_rc, "start_rc": start_rc}, occupied=occupied, reach=reach, cut=cut)
    if len(face) == 0 or (face < 0).any() or (face >= np.array(reach.shape)).any():
        raise ValueError(f"face must hold cells inside the grid of shape {reach.shape}, got {len(face)} cells")
    if not reach[front_rc]:
        raise ValueError(f"front_rc {front_rc} is not a reachable cell")
    if not (resolution_m > 0 and level_step_m > 0 and max_length_m > 0 and sight_range_m > 0):
        raise ValueError("resolution_m, level_step_m, max_length_m and sight_range_m must be > 0")
    band_cells = max(1.5, level_step_m / resolution_m / 2)  # >= sqrt 2: no 8-connected path skips the band
    h = _window_distance(reach, cut, front_rc, (max_length_m + 2 * level_step_m) / resolution_m + band_cells)
    seen = _sight_reach(occupied, face, sight_range_m / resolution_m) & reach
    if not np.isfinite(h[seen]).all():
        return None  # the obstruction is in sight from beyond the longest dead end sought
    reveal_m = float(h[seen].max()) * resolution_m if seen.any() else 0.0
    first = max(min_length_m, reveal_m + min_hidden_m, level_step_m)
    # The scan runs in the window where h is finite; the start and every reachable cell on a window edge that is not
    # the grid's edge count as outside (a way out of a pocket leaves the window or reaches the start).
    finite = np.argwhere(np.isfinite(h))
    (r0, c0), (r1, c1) = np.maximum(finite.min(axis=0) - 2, 0), finite.max(axis=0) + 3
    window = (slice(r0, r1), slice(c0, c1))
    reach_w, h_w = reach[window], h[window]
    outside = np.zeros(reach_w.shape, bool)
    outside[0, :], outside[-1, :] = r0 > 0, r1 < reach.shape[0]
    outside[:, 0] |= c0 > 0
    outside[:, -1] |= c1 < reach.shape[1]
    if r0 <= start_rc[0] < r1 and c0 <= start_rc[1] < c1:
        outside[start_rc[0] - r0, start_rc[1] - c0] = True
    outside &= reach_w
    source = (front_rc[0] - r0, front_rc[1] - c0)
    length, mouth, pocket, misses = 0.0, None, None, 0
    for level in np.arange(np.ceil(first / level_step_m) * level_step_m, max_length_m + 1e-9, level_step_m):
        if h[start_rc] < level / resolution_m + band_cells:
            break  # the band would reach the start: every pocket from here on holds it
        band = reach_w & (h_w >= level / resolution_m) & (h_w < level / resolution_m + band_cells)
        piece = (_separating_piece(reach_w, band, source, outside, max_mouth_width_m / resolution_m)
                 if band.any() else None)
        if piece is not None:
            cut_off = reach.copy()
            cut_off[window] &= ~piece
            labels, _ = ndimage.label(cut_off, structure=_EIGHT)
            inside = labels == labels[front_rc]
            if inside[start_rc]:
                break
            if max_pocket_cells is not None and inside.sum() > max_pocket_cells:
                break
            length, pocket, misses = float(level), inside, 0
            mouth = np.zeros(reach.shape, bool)
            mouth[window] = piece
        else:
            misses += 1
            if misses * level_step_m >= patience_m:
                break
    if mouth is None:
        return None
    depth = np.where(pocket, np.clip(length - np.nan_to_num(h, posinf=1e9) * resolution_m, 0.0, None), np.nan)
    return DeadEnd(pocket=pocket, depth_m=depth.astype(np.float32), mouth=np.argwhere(mouth),
                   face=face, length_m=length, hidden_m=length - reveal_m,
                   area_m2=float(pocket.sum()) * resolution_m ** 2)


def face_hidden_from(occupied: np.ndarray, viewers: np.ndarray, face: np.ndarray) -> bool:
    """True when no face cell is in line of sight (:func:`superex_deploy.geometry.line_of_sight` through the
    non-occupied cells) of any viewer cell. ``viewers``, ``face``: int ``[N, 2]`` (row, col)."""
    return not any(line_of_sight(occupied, viewer, target) for viewer in viewers for target in face)


@dataclass(frozen=True)
class DeadEndEntries:
    """How an episode met the dead ends of an altered floor.

    Attributes:
        entries: runs of consecutive poses inside a pocket reaching at least the minimum depth.
        metres_inside: metres driven between consecutive poses both inside a pocket, over the whole episode.
        metres_in: metres driven from entering a pocket to the deepest pose of that entry (before turning
            back), summed over the entries.
        deepest_m: the deepest pose in any pocket (metres from its mouth; 0 without entries).
        reached_end: entries that came within ``end_margin_m`` of the obstruction.
    """

    entries: int
    metres_inside: float
    metres_in: float
    deepest_m: float
    reached_end: int

    def to_json(self) -> dict:
        """The fields as a JSON-ready dict."""
        return {"entries": self.entries, "metres_inside": self.metres_inside, "metres_in": self.metres_in,
                "deepest_m": self.deepest_m, "reached_end": self.reached_end}


def dead_end_entries(dead_ends: Sequence[DeadEnd], poses_rc, path_length_m, min_depth_m: float = 1.0,
                     end_margin_m: float = 1.5) -> DeadEndEntries:
    """Entries of an episode into dead ends (see the module docstring).

    Args:
        dead_ends: the altered floor's dead ends.
        poses_rc: int ``[T, 2]`` the robot's cell at each step (``EpisodeResult.poses``).
        path_length_m: float ``[T]`` metres driven before each step (``EpisodeResult.path_length_m``).
        min_depth_m: an entry counts when it goes this deep into the pocket.
        end_margin_m: an entry *reached the end* when it came this close to the obstruction.

    Raises:
        ValueError: poses and path lengths of different lengths, poses outside the grid.
    """
    poses = np.asarray(poses_rc, np.int64).reshape(-1, 2)
    driven = np.asarray(path_length_m, float).reshape(-1)
    if len(poses) != len(driven):
        raise ValueError(f"{len(poses)} poses but {len(driven)} path lengths")
    entries = reached = 0
    inside_m = in_m = deepest = 0.0
    for dead_end in dead_ends:
        shape = dead_end.pocket.shape
        if len(poses) and not ((poses >= 0).all() and (poses < np.array(shape)).all()):
            raise ValueError(f"poses must lie inside the grid of shape {shape}")
        depth = dead_end.depth_m[poses[:, 0], poses[:, 1]] if len(poses) else np.zeros(0)
        inside = np.isfinite(depth)
        both = inside[1:] & inside[:-1]
        inside_m += float(np.diff(driven)[both].sum())
        runs = np.flatnonzero(np.diff(np.r_[0, inside.astype(np.int8), 0]))
        for first, end in zip(runs[::2], runs[1::2]):
            run_depth = depth[first:end]
            if run_depth.max() < min_depth_m:
                continue
            entries += 1
            turn = first + int(np.argmax(run_depth))
            in_m += float(driven[turn] - driven[first])
            deepest = max(deepest, float(run_depth.max()))
            reached += int(run_depth.max() >= dead_end.length_m - end_margin_m)
    return DeadEndEntries(entries=entries, metres_inside=inside_m, metres_in=in_m, deepest_m=deepest,
                          reached_end=reached)
