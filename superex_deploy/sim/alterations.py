"""Altered floors: obstructions that damage or renovation would leave and a floor-plan prior would not predict.

:func:`alter_floor` closes passages of a floor (a door shut, debris across a corridor, a partition wall across a
room) so that a corridor or a room becomes a **dead end hidden behind a turn**: a robot that sees only in line of
sight learns that the branch leads nowhere only once it has driven into it, while non-line-of-sight sensing (or a
map that knows) can tell earlier. The rules, all drawn from the floor's geometry, the start cell and the seed, never
from where a planner drives:

1. **Robot cells.** The robot's centre may occupy the free cells farther than ``robot_radius_m`` from every wall
   (the planner's traversability, :mod:`superex_deploy.onboard.planning.motion`), 8-connected to the start
   (:func:`superex_deploy.sim.dead_ends.robot_cells`), inside the valid area or not: the eval floors' valid areas
   leave the doorways out, and the robot drives through them.
2. **Passages.** Candidate cuts sit on the medial axis of the free space, read from the nearest-wall feature
   transform (``scipy.ndimage.distance_transform_edt``): two 8-neighbouring robot cells whose nearest wall cells
   ``a`` and ``b`` face each other across the cell (``|a - b| >= facing_ratio * clearance``) mark a passage, and
   the segment from ``a`` to ``b`` crosses it at its narrowest. Half the passage's width (``clearance``) sets the
   kind: a *door* up to ``door_max_half_width_m`` (closed: a thin wall), a *corridor* up to
   ``corridor_max_half_width_m`` (debris: a thick wall and a pile at the centre), a *room* up to
   ``room_max_half_width_m`` (split: a partition wall). A segment that crosses another wall is skipped.
3. **Order.** The seed's generator shuffles the candidates; those within ``prefer_within_m`` of the start
   (geodesic, at the segment's middle) are tried first, then those up to ``max_start_distance_m``, farther ones
   never; one at most is tried in every disc of ``candidate_spacing_m``; no cut cell may lie within
   ``protect_radius_m`` of the start (straight line).
4. **Acceptance.** A cut is kept when all of these hold on the floor altered so far plus the cut:

   * it seals the passage locally: the free cells on its two faces fall into different 4-connected pieces within
     ``seal_window_m`` of it, so that neither the robot nor a ray passes;
   * the start still reaches ``min_kept_fraction`` of the robot cells of the unaltered floor;
   * one of its faces opens a dead end (:mod:`superex_deploy.sim.dead_ends`): a pocket of robot cells, without the
     start, at most ``max_pocket_fraction`` of the robot cells, whose only way out is one mouth at most
     ``2 * corridor_max_half_width_m`` wide (a door's or a corridor's cross-section), ``min_dead_end_m`` to
     ``max_dead_end_m`` long from the obstruction to the mouth;
   * the branch led on before the cut: without it, the cells the mouth closes off held the start or
     ``min_continuation_m2`` of robot cells beyond the pocket (a corridor that now leads nowhere, not a room made
     smaller);
   * the obstruction is **hidden behind a turn**: no robot cell of the mouth, or within ``entrance_band_m`` of it,
     sees a free cell touching the obstruction's face in line of sight
     (:func:`superex_deploy.geometry.line_of_sight`), and a robot must drive ``min_hidden_m`` into the pocket
     before any of its cells sees one (rays of ``sight_range_m``);
   * it keeps ``candidate_spacing_m`` clear of the dead ends already made, and every one of them stays reachable.

5. **Valid area.** After ``alterations`` cuts (or the candidates running out) the valid area is recomputed: the
   free cells of the old valid area within ``robot_radius_m`` + one cell of a robot cell (what the robot's body
   covers, and the cell beside it). What a cut shuts off leaves the valid area; its cells stay free (nothing sees
   them).

The same floor, start and seed give the same altered floor; the grid keeps the floor's name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy import ndimage

from superex_deploy.configs import JsonConfig
from superex_deploy.maps import OccupancyGrid
from superex_deploy.onboard.checks import check_int, check_real
from superex_deploy.onboard.planning.motion import dijkstra
from superex_deploy.sim.dead_ends import DeadEnd, face_hidden_from, measure_dead_end, robot_cells

__all__ = ["AlterationConfig", "Alteration", "AlteredFloor", "alter_floor", "alter_floor_with_record"]

@dataclass(frozen=True)
class AlterationConfig(JsonConfig):
    """Parameters of :func:`alter_floor` (see the module docstring for the rules). Lengths in metres, areas in
    square metres. Fixed on the train floors (``scripts/ceiling_altered.py``); never tuned on ``eval/``.

    Attributes:
        alterations: the most obstructions made (fewer where fewer passages qualify).
        robot_radius_m: the planner's robot radius (:class:`superex_deploy.onboard.planning.motion.MotionConfig`).
        protect_radius_m: no cut cell this close to the start (straight line).
        door_max_half_width_m, corridor_max_half_width_m, room_max_half_width_m: the passage kinds, by half width.
        facing_ratio: how squarely a passage's two walls must face each other (``|a - b| / clearance``, in (1, 2]).
        wall_thickness_m: thickness of a closed door or partition wall (at least 1.5 cells).
        min_dead_end_m, max_dead_end_m: the dead end's length, obstruction to mouth (geodesic).
        min_hidden_m: how far into the dead end a robot must drive before it can see the obstruction.
        entrance_band_m: the cells this close to the mouth must not see the obstruction either.
        min_kept_fraction: the share of the unaltered floor's robot cells the start must still reach.
        max_pocket_fraction: the largest dead end, as a share of the robot cells the start reaches.
        min_continuation_m2: the robot cells the branch led to beyond the dead end before the cut (when not back
            to the start).
        prefer_within_m: candidates this close to the start (geodesic) are tried first, so that the robot meets the
            dead ends early in an episode.
        max_start_distance_m: candidates farther than this from the start (geodesic) are not tried.
        candidate_spacing_m: one candidate at most per disc of this radius; the distance kept from earlier dead ends.
        seal_window_m: the margin around a cut within which it must seal the passage.
        level_step_m: the spacing of the dead end's levels (see :func:`superex_deploy.sim.dead_ends.measure_dead_end`).
        sight_range_m: how far the robot sees (the LiDAR's range, :class:`superex_deploy.sim.world.LidarConfig`).
        max_candidates: the most candidates tried.
    """

    alterations: int = 3
    robot_radius_m: float = 0.15
    protect_radius_m: float = 3.0
    door_max_half_width_m: float = 0.6
    corridor_max_half_width_m: float = 1.5
    room_max_half_width_m: float = 3.0
    facing_ratio: float = 1.8
    wall_thickness_m: float = 0.2
    min_dead_end_m: float = 5.0
    max_dead_end_m: float = 30.0
    min_hidden_m: float = 2.0
    entrance_band_m: float = 1.0
    min_kept_fraction: float = 0.6
    max_pocket_fraction: float = 0.2
    min_continuation_m2: float = 20.0
    prefer_within_m: float = 20.0
    max_start_distance_m: float = 40.0
    candidate_spacing_m: float = 2.0
    seal_window_m: float = 1.5
    level_step_m: float = 0.5
    sight_range_m: float = 20.0
    max_candidates: int = 150

    def __post_init__(self) -> None:
        # Checked, not converted: the values stay as given (the altered floors' cache records them).
        for name in ("alterations", "max_candidates"):
            check_int(f"AlterationConfig.{name}", getattr(self, name), 0)
        for name, value in self.__dict__.items():
            if name not in ("alterations", "max_candidates"):
                check_real(f"AlterationConfig.{name}", value, 0.0)
        if not 0.0 < self.door_max_half_width_m <= self.corridor_max_half_width_m <= self.room_max_half_width_m:
            raise ValueError("AlterationConfig: need 0 < door_max_half_width_m <= corridor_max_half_width_m <= "
                             f"room_max_half_width_m, got {self.door_max_half_width_m}, "
                             f"{self.corridor_max_half_width_m}, {self.room_max_half_width_m}")
        for name in ("min_kept_fraction", "max_pocket_fraction"):
            check_real(f"AlterationConfig.{name}", getattr(self, name), 0.0, 1.0)
        check_real("AlterationConfig.facing_ratio", self.facing_ratio, 1.0, 2.0, low_open=True)
        for name in ("level_step_m", "sight_range_m", "wall_thickness_m", "max_dead_end_m"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"AlterationConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.min_dead_end_m > self.max_dead_end_m:
            raise ValueError(f"AlterationConfig: min_dead_end_m {self.min_dead_end_m} exceeds max_dead_end_m "
                             f"{self.max_dead_end_m}")


@dataclass(frozen=True, eq=False)
class Alteration:
    """One obstruction and the dead end it makes.

    Attributes:
        kind: ``door``, ``corridor`` or ``room`` (the passage closed, see the module docstring).
        segment_rc: float ``[2, 2]`` the wall cells ``a`` and ``b`` the cut joins (row, col).
        cut: bool ``[H, W]`` the cells made walls.
        dead_end: the dead end in front of the cut.
    """

    kind: str
    segment_rc: np.ndarray
    cut: np.ndarray
    dead_end: DeadEnd


@dataclass(frozen=True, eq=False)
class AlteredFloor:
    """What :func:`alter_floor_with_record` made.

    Attributes:
        grid: the altered floor (walls added, valid area recomputed).
        original: the floor it came from.
        start_rc, seed, cfg: the inputs.
        alterations: the obstructions kept, in the order they were made (may be empty: no passage qualified).
        kept_fraction: robot cells the start reaches on the altered floor over those of the unaltered floor.
        candidates_tried: candidate cuts examined.
    """

    grid: OccupancyGrid
    original: OccupancyGrid
    start_rc: tuple[int, int]
    seed: int
    cfg: AlterationConfig
    alterations: tuple[Alteration, ...] = field(default_factory=tuple)
    kept_fraction: float = 1.0
    candidates_tried: int = 0

    @property
    def dead_ends(self) -> tuple[DeadEnd, ...]:
        """The dead ends of the alterations (for :func:`superex_deploy.sim.dead_ends.dead_end_entries`)."""
        return tuple(alteration.dead_end for alteration in self.alterations)


def _check_inputs(grid, start_rc, seed, cfg) -> tuple[int, int]:
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    if not isinstance(cfg, AlterationConfig):
        raise ValueError(f"cfg must be an AlterationConfig, got {type(cfg).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    start = grid.check_pose(start_rc)
    if not grid.valid[start]:
        raise ValueError(f"start cell {start} lies outside the valid area of map {grid.name!r}")
    return start


def _passages(occupied: np.ndarray, reach: np.ndarray, resolution_m: float, cfg: AlterationConfig) -> np.ndarray:
    """Candidate cuts: float ``[N, 5]`` rows ``(a_row, a_col, b_row, b_col, half_width_cells)`` from the medial
    axis of the free space (rule 2), one per robot cell that qualifies."""
    padded = np.pad(~occupied, 1, constant_values=False)
    clearance, nearest = ndimage.distance_transform_edt(padded, return_indices=True)
    clearance, nearest = clearance[1:-1, 1:-1], nearest[:, 1:-1, 1:-1] - 1
    low, high = 2.0 * cfg.robot_radius_m / resolution_m, cfg.room_max_half_width_m / resolution_m
    rows = []
    n_rows, n_cols = occupied.shape
    rp_all, cp_all = np.nonzero(reach)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        rq, cq = rp_all + dr, cp_all + dc
        inside = (rq < n_rows) & (cq >= 0) & (cq < n_cols)
        rp, cp, rq, cq = rp_all[inside], cp_all[inside], rq[inside], cq[inside]
        keep = reach[rq, cq]
        rp, cp, rq, cq = rp[keep], cp[keep], rq[keep], cq[keep]
        a = nearest[:, rp, cp].T.astype(float)
        b = nearest[:, rq, cq].T.astype(float)
        half = np.maximum(clearance[rp, cp], clearance[rq, cq])
        facing = np.hypot(*(a - b).T) >= cfg.facing_ratio * half
        ok = facing & (half >= low) & (half <= high)
        rows.append(np.column_stack([a[ok], b[ok], half[ok]]))
    return np.concatenate(rows) if rows else np.zeros((0, 5))


def _segment_cells(shape, a, b, half_thickness: float, extend: float = 1.0) -> np.ndarray:
    """bool ``[H, W]`` cells whose centre lies within ``half_thickness`` of the segment ``a``-``b`` (cell
    coordinates of cell centres, row/col) extended by ``extend`` cells at both ends."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    direction = (b - a) / max(np.hypot(*(b - a)), 1e-9)
    a, b = a - extend * direction, b + extend * direction
    reach = half_thickness + 1
    r0, c0 = np.floor(np.minimum(a, b) - reach).astype(int)
    r1, c1 = np.ceil(np.maximum(a, b) + reach).astype(int) + 1
    r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, shape[0]), min(c1, shape[1])
    out = np.zeros(shape, bool)
    if r0 >= r1 or c0 >= c1:
        return out
    rr, cc = np.mgrid[r0:r1, c0:c1]
    points = np.stack([rr, cc], axis=-1).astype(float)
    t = np.clip(((points - a) @ (b - a)) / max(float((b - a) @ (b - a)), 1e-9), 0.0, 1.0)
    distance = np.hypot(*np.moveaxis(points - (a + t[..., None] * (b - a)), -1, 0))
    out[r0:r1, c0:c1] = distance <= half_thickness
    return out


def _cut_of(candidate, occupied, resolution_m, cfg: AlterationConfig) -> Optional[tuple[str, np.ndarray]]:
    """The kind and cells of the cut across one candidate passage (rule 2), or None when its segment crosses a
    wall between its ends."""
    a, b, half = candidate[:2], candidate[2:4], candidate[4]
    length = float(np.hypot(*(b - a)))
    samples = a + np.linspace(0.0, 1.0, max(int(2 * length), 2))[:, None] * (b - a)
    interior = np.minimum(np.hypot(*(samples - a).T), np.hypot(*(samples - b).T)) > 1.5
    cells = np.clip(np.rint(samples[interior]).astype(int), 0, np.array(occupied.shape) - 1)
    if occupied[cells[:, 0], cells[:, 1]].any():
        return None
    half_m = half * resolution_m
    kind = "door" if half_m <= cfg.door_max_half_width_m else (
        "corridor" if half_m <= cfg.corridor_max_half_width_m else "room")
    thickness = max(0.75, 0.5 * cfg.wall_thickness_m / resolution_m)
    cut = _segment_cells(occupied.shape, a, b, thickness)
    if kind == "corridor":  # debris: a pile at the centre of the passage
        cut |= _segment_cells(occupied.shape, (a + b) / 2, (a + b) / 2, 0.35 * length, extend=0.0)
    return kind, cut & ~occupied


def _faces(occupied_after: np.ndarray, cut: np.ndarray, a, b, window_cells: int):
    """For each side of the segment ``a``-``b``: the free cells 4-adjacent to the cut (int ``[F, 2]``) and the
    free cells 4-connected to them within a window of ``window_cells`` around the cut (bool ``[H, W]``); None when
    the cut does not seal the passage within that window (rule 4)."""
    rows, cols = np.nonzero(cut)
    r0, c0 = max(rows.min() - window_cells, 0), max(cols.min() - window_cells, 0)
    r1, c1 = rows.max() + window_cells + 1, cols.max() + window_cells + 1
    free = ~occupied_after[r0:r1, c0:c1]
    touching = ndimage.binary_dilation(cut[r0:r1, c0:c1]) & free
    labels, _ = ndimage.label(free)
    cells = np.argwhere(touching)
    direction = np.asarray(b, float) - np.asarray(a, float)
    relative = cells + (r0, c0) - np.asarray(a, float)
    side = relative[:, 0] * direction[1] - relative[:, 1] * direction[0] > 0
    plus, minus = set(labels[tuple(cells[side].T)]), set(labels[tuple(cells[~side].T)])
    if not plus or not minus or plus & minus:
        return None
    faces = []
    for chosen, pieces in ((side, plus), (~side, minus)):
        around = np.zeros(cut.shape, bool)
        around[r0:r1, c0:c1] = np.isin(labels, list(pieces))
        faces.append((cells[chosen] + (r0, c0), around))
    return faces


def _dead_end_of_face(face, around, occupied, reach, reach_before, cut, start, resolution_m, cfg) -> Optional[DeadEnd]:
    """The dead end in front of one face of a cut if it qualifies (rule 4), else None. ``around``: the free
    cells on the face's side near the cut."""
    near = np.argwhere(reach & around)
    if len(near):  # robot cells within a step of the robot's radius from the face: in front of it, on its side
        gap = np.min(np.hypot(near[:, None, 0] - face[None, :, 0], near[:, None, 1] - face[None, :, 1]), axis=1)
        near = near[gap <= cfg.robot_radius_m / resolution_m + 2.0]
    if len(near) == 0:  # the robot cannot come near this face
        return None
    front = near[np.argmin(np.hypot(*(near - face.mean(axis=0)).T))]  # where the dead end's h is 0
    dead_end = measure_dead_end(occupied, reach, cut, front, face, start, resolution_m,
                                cfg.min_dead_end_m, cfg.min_hidden_m, cfg.max_dead_end_m, cfg.level_step_m,
                                cfg.sight_range_m, max_pocket_cells=int(cfg.max_pocket_fraction * reach.sum()),
                                max_mouth_width_m=2 * cfg.corridor_max_half_width_m)
    if dead_end is None:
        return None
    mouth = np.zeros(reach.shape, bool)
    mouth[tuple(dead_end.mouth.T)] = True
    labels, _ = ndimage.label(reach_before & ~mouth, structure=np.ones((3, 3), bool))
    beyond = labels == labels[tuple(front)]  # where the branch led before the cut
    if not beyond[start] and (beyond & ~dead_end.pocket).sum() * resolution_m ** 2 < cfg.min_continuation_m2:
        return None
    viewers = np.argwhere(reach & ndimage.binary_dilation(
        mouth, iterations=max(1, int(round(cfg.entrance_band_m / resolution_m)))))
    if not face_hidden_from(occupied, viewers, face):
        return None
    return dead_end


def alter_floor_with_record(grid: OccupancyGrid, start_rc, seed: int,
                            cfg: AlterationConfig = AlterationConfig()) -> AlteredFloor:
    """Alter ``grid`` around a start cell (see the module docstring) and say what was done.

    Args:
        grid: the floor.
        start_rc: the robot's start cell (row, col): inside the grid, free, in the valid area.
        seed: seed of the candidates' order (an integer >= 0).
        cfg: the generator's parameters.

    Returns:
        The :class:`AlteredFloor`: the altered grid and the alterations with their dead ends.

    Raises:
        ValueError: not an OccupancyGrid, a start outside the grid, in a wall or outside the valid area, a negative
            or non-integer seed, a cfg that is not an :class:`AlterationConfig`.
    """
    start = _check_inputs(grid, start_rc, seed, cfg)
    resolution = grid.resolution_m
    radius_cells = cfg.robot_radius_m / resolution
    occupied, valid = grid.occupied.copy(), grid.valid
    reach0 = robot_cells(occupied, start, radius_cells)
    reach = reach0
    rng = np.random.default_rng(int(seed))
    candidates = _passages(occupied, reach0, resolution, cfg) if cfg.alterations else np.zeros((0, 5))
    candidates = candidates[rng.permutation(len(candidates))]
    from_start = dijkstra(np.where(reach0, 1.0, np.inf), start)[0] * resolution
    middle = np.clip(np.rint((candidates[:, :2] + candidates[:, 2:4]) / 2).astype(int), 0, np.array(grid.shape) - 1)
    distance = from_start[middle[:, 0], middle[:, 1]]
    near = distance <= cfg.prefer_within_m
    candidates = np.concatenate([candidates[near], candidates[~near & (distance <= cfg.max_start_distance_m)]])
    rr, cc = np.mgrid[:grid.shape[0], :grid.shape[1]]
    protected = np.hypot(rr - start[0], cc - start[1]) * resolution <= cfg.protect_radius_m
    tried = np.zeros(grid.shape, bool)
    spacing = cfg.candidate_spacing_m / resolution
    window = int(np.ceil(cfg.seal_window_m / resolution))
    made: list[Alteration] = []
    n_tried = 0
    for candidate in candidates:
        if len(made) >= cfg.alterations or n_tried >= cfg.max_candidates:
            break
        centre = tuple(np.clip(np.rint((candidate[:2] + candidate[2:4]) / 2).astype(int), 0,
                               np.array(grid.shape) - 1))
        if tried[centre]:
            continue
        n_tried += 1
        tried |= np.hypot(rr - centre[0], cc - centre[1]) <= spacing
        shaped = _cut_of(candidate, occupied, resolution, cfg)
        if shaped is None:
            continue
        kind, cut = shaped
        if not cut.any() or (cut & protected).any() or any(
                (cut & ndimage.binary_dilation(m.dead_end.pocket, iterations=int(spacing))).any() for m in made):
            continue
        after = occupied | cut
        faces = _faces(after, cut, candidate[:2], candidate[2:4], window)
        if faces is None:
            continue
        reach_after = robot_cells(after, start, radius_cells)
        if reach_after.sum() < cfg.min_kept_fraction * reach0.sum() or any(
                not reach_after[m.dead_end.pocket].all() for m in made):
            continue
        for face, around in faces:
            dead_end = _dead_end_of_face(face, around, after, reach_after, reach, cut, start, resolution, cfg)
            if dead_end is not None:
                made.append(Alteration(kind=kind, segment_rc=candidate[:4].reshape(2, 2).copy(), cut=cut,
                                       dead_end=dead_end))
                occupied, reach = after, reach_after
                break
    footprint = ndimage.distance_transform_edt(~reach) <= radius_cells + 1.0
    altered = OccupancyGrid(occupied=occupied, valid=valid & ~occupied & footprint, resolution_m=resolution,
                            name=grid.name)
    return AlteredFloor(grid=altered, original=grid, start_rc=start, seed=int(seed), cfg=cfg,
                        alterations=tuple(made), kept_fraction=float(reach.sum() / reach0.sum()),
                        candidates_tried=n_tried)


def alter_floor(grid: OccupancyGrid, start_rc, seed: int, cfg: AlterationConfig = AlterationConfig()
                ) -> OccupancyGrid:
    """The floor ``grid`` altered around ``start_rc`` with ``seed``: :func:`alter_floor_with_record`'s grid (see
    the module docstring for the rules; the same arguments give the same grid)."""
    return alter_floor_with_record(grid, start_rc, seed, cfg).grid
