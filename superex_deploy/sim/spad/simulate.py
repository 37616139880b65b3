"""One SPAD scan (:func:`simulate_scan`): the primaries, the fans (looked up in the grid's cache or traced), the
histograms, optional noise and the scan's ground truth. The model is described in :mod:`superex_deploy.sim.spad`.
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np

from superex_deploy.parallel import kernel_parts
from superex_deploy.geometry import cell_centre, group_by_cell, ray_angles
from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import SpadFrame
from superex_deploy.sim.spad.fans import fan_cache_rows, trace_fans
from superex_deploy.sim.spad.histograms import fill_sparse
from superex_deploy.sim.spad.noise import add_noise, check_noise_rng
from superex_deploy.sim.spad.scene import prepare_scene
from superex_deploy.sim.spad.tracer import cast_primaries
from superex_deploy.sim.spad.truth import SpadTruth
from superex_deploy.spad_types import SpadConfig, SpadScan, SparseHistograms

__all__ = ["MIN_DISTANCE_CELLS", "simulate_scan"]

MIN_DISTANCE_CELLS = 0.5
"""``d1`` and ``d2`` are floored at this many cells, so eq. (2) stays finite for a robot touching a wall."""
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _origin_in_cell(origin_yx, pose_rc) -> tuple[float, float]:
    origin = (float(origin_yx[0]), float(origin_yx[1]))
    if not all(np.isfinite(origin)) or (int(np.floor(origin[0])), int(np.floor(origin[1]))) != tuple(pose_rc):
        raise ValueError(f"origin_yx {origin} cells lies outside the robot cell {tuple(pose_rc)}")
    return origin


def simulate_scan(grid: OccupancyGrid, pose_rc, cfg: SpadConfig = SpadConfig(),
                  rng: Optional[np.random.Generator] = None,
                  origin_yx: Optional[tuple[float, float]] = None) -> SpadScan:
    """Simulate one SPAD scan from the centre of cell ``pose_rc`` (or from ``origin_yx`` inside it).

    Secondary fans are reused from the grid's :class:`FanCache` where an earlier scan traced them (the result is
    the same either way); new ones are traced on numba's threads.

    Args:
        grid: ground-truth occupancy grid.
        pose_rc: robot cell ``(row, col)``: inside the grid, not a wall.
        cfg: sensor configuration.
        rng: random generator, required when ``cfg.noise.enabled`` (ignored otherwise).
        origin_yx: the sensor's continuous grid position ``(y down, x right)`` in cells, inside ``pose_rc`` (a
            robot off its cell's centre, as the simulator's continuous motion leaves it); None: the cell's centre.

    Returns:
        The :class:`SpadScan`: sparse counts without noise, dense with it; counts are float32 and clamped to
        float32's finite range.

    Raises:
        ValueError: bad grid, pose outside the map or in a wall, noise without a generator, an origin outside
            ``pose_rc``.
    """
    if not isinstance(cfg, SpadConfig):
        raise ValueError(f"cfg must be a SpadConfig, got {type(cfg).__name__}")
    scene = prepare_scene(grid)
    pose_rc = grid.check_pose(pose_rc)
    rng = check_noise_rng(cfg, rng)
    origin = cell_centre(pose_rc) if origin_yx is None else _origin_in_cell(origin_yx, pose_rc)
    resolution = grid.resolution_m
    max_t = cfg.range_m / resolution
    angles = ray_angles(cfg.n_rays)
    hit_rc = np.empty((cfg.n_rays, 2), np.int32)
    distance = np.empty(cfg.n_rays)
    entry_axis = np.empty(cfg.n_rays, np.int8)
    direction = np.empty((cfg.n_rays, 2))
    n_parts = kernel_parts()
    cast_primaries(scene.cell_kind, scene.wall_blocks, origin[0], origin[1], angles, max_t, hit_rc, distance,
                   entry_axis, direction, n_parts)
    hit_fan, fan_cells, first_ray = group_by_cell(hit_rc, grid.shape[1])
    fan_entry_axis = entry_axis[first_ray]  # the lowest-index ray that hit the cell

    n_fans = fan_cells.shape[0]
    cache = scene.fan_cache(cfg.n_secondary, max_t)
    fan_normal = np.empty((n_fans, 2))
    fan_key = np.empty(n_fans, np.int64)
    fan_row = np.empty(n_fans, np.int64)
    n_missing = fan_cache_rows(scene.normals, scene.two_sided, scene.wall_index, cache.row_of_key, fan_cells,
                               fan_entry_axis, origin[0], origin[1], fan_normal, fan_key, fan_row)
    min_distance_m = MIN_DISTANCE_CELLS * resolution
    if n_missing:
        rows, cleared = cache.reserve(n_missing, n_fans)
        if cleared:  # the cache started afresh: every fan of this scan is traced
            fan_row[:] = -1
        todo = np.flatnonzero(fan_row < 0)
        fan_row[todo] = rows
        keyed = fan_key[todo] >= 0
        cache.row_of_key[fan_key[todo][keyed]] = rows[keyed] + 1
        trace_fans(scene.cell_kind, scene.wall_blocks, scene.normals, scene.two_sided, fan_cells, fan_normal,
                   todo, rows, cfg.n_secondary, max_t, resolution, min_distance_m, cache.d2_m, cache.cos2,
                   cache.h2_rc, cache.path_m, cache.gain, cache.n_paths, n_parts)
        cache.traced += len(todo)
    cache.reused += n_fans - n_missing

    d1_m = np.empty(cfg.n_rays)
    cos1 = np.empty(cfg.n_rays)
    normal1 = np.empty((cfg.n_rays, 2))
    three_bounce_scale = cfg.three_bounce_scale(resolution)
    row_start, bins, counts = fill_sparse(direction, hit_fan, distance, fan_normal, fan_row, cache.path_m,
                                          cache.gain, cache.n_paths, resolution, cfg.bin_path_m, cfg.n_bins,
                                          cfg.direct_counts, three_bounce_scale, min_distance_m, d1_m, cos1,
                                          normal1, n_parts)
    stored: Union[SparseHistograms, np.ndarray] = SparseHistograms(row_start, bins, counts, cfg.n_bins)
    if rng is not None:
        noisy = np.minimum(add_noise(stored.to_dense().astype(np.float64), cfg, rng), _FLOAT32_MAX)
        stored = noisy.astype(np.float32)

    truth = SpadTruth(h1_rc=hit_rc, d1_m=d1_m, normal1=normal1, cos1=cos1, ray_fan=hit_fan, fan_rows=fan_row,
                      fan_store=(cache.d2_m, cache.cos2, cache.h2_rc), three_bounce_scale=three_bounce_scale)
    return SpadScan(angles=angles, origin_yx=origin, pose_rc=pose_rc, bin_path_m=cfg.bin_path_m,
                    resolution_m=resolution, grid_shape=grid.shape, config=cfg, truth=truth, stored=stored)


def measured_frame(simulated: SpadScan, yaw: float = 0.0) -> SpadFrame:
    """The :class:`~superex_deploy.messages.SpadFrame` a robot heading ``yaw`` (radians, REP 103: counter-clockwise
    from the map's x axis) receives for the simulated scan ``simulated``: its histograms with the grid's ray angles
    turned back into the sensor's (an exact negation at yaw 0; a turned robot's rays are the same grid directions
    seen from its heading). What the world sends, and what a test places with a belief of its own."""
    sparse = simulated.sparse
    angles = -simulated.angles - yaw if yaw else -simulated.angles
    return SpadFrame(angles=angles, bin_width_s=simulated.config.bin_width_s, n_bins=sparse.n_bins,
                     row_start=sparse.row_start, bins=sparse.bins, counts=sparse.counts)
