"""The NLOS gain of a viewpoint (onboard.planning.nlos_gain): the carving's geometry on the planning map, against
analytic scenes and the slow twin in tests/naive.py."""

from __future__ import annotations

import numpy as np
import pytest

from tests.naive import naive_nlos_carved
from superex_deploy.onboard.planning.nlos_gain import (NlosGainConfig, _kernel_args, planning_walls,
                                                       union_nlos_gains, viewpoint_carved)
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

RES = 0.1


def _scene(shape, walls_rc):
    """An UNKNOWN map with OCCUPIED cells at ``walls_rc`` (a bool mask); its relay walls; a zero prediction."""
    observed = np.full(shape, UNKNOWN, np.int8)
    observed[walls_rc] = OCCUPIED
    mean = np.zeros(shape, np.float32)
    return observed, mean, planning_walls(observed, mean, 0.5)


def test_carved_cells_lie_in_front_of_a_straight_wall_within_the_cap():
    """One straight wall two cells thick across the map, nothing else: every relay point's fan meets nothing, so
    its radius is the cap; what is carved lies on the viewpoint's side, past the strip, within cap - margin of a
    wall cell the viewpoint sees within the incidence limit, and the cell straight in front is carved."""
    shape = (60, 120)
    wall = np.zeros(shape, bool)
    wall[10:12, :] = True
    observed, mean, walls = _scene(shape, wall)
    cfg = NlosGainConfig(cap_m=2.0, margin_m=0.3, strip_m=0.15, max_incidence_deg=60.0)
    flat, offsets = viewpoint_carved(walls, observed, [(30, 60)], cfg, RES)
    assert offsets.tolist() == [0, len(flat)] and len(flat) == len(set(flat.tolist()))
    rows, cols = np.unravel_index(flat, shape)
    face = 12.0  # the wall's face on the viewpoint's side (row boundary)
    assert rows.min() >= face + 0.15 / RES - 0.5  # cell centres at least the strip in front of the face's cells
    # Within (cap - margin) of the centre of a relay cell in the face row seen within 60 degrees of the normal.
    lateral = np.tan(np.radians(60.0)) * (30.5 - 11.5)
    reach = (2.0 - 0.3) / RES
    assert np.all(rows + 0.5 - 11.5 < reach)
    assert np.all(np.abs(cols + 0.5 - 60.5) < lateral + reach)
    assert (12 + 8) * shape[1] + 60 in set(flat.tolist())  # 0.85 m in front of the wall, straight ahead
    assert not np.any(walls.ravel()[flat])


def test_the_radius_stops_at_the_nearest_surface_in_front():
    """Two parallel walls 12 cells apart: the fans of the lower wall meet the upper one, so nothing at or past the
    upper wall's face is carved, and with the cap far larger the carved band ends short of it."""
    shape = (50, 100)
    wall = np.zeros(shape, bool)
    wall[10:12, :] = True
    wall[24:26, :] = True
    observed, mean, walls = _scene(shape, wall)
    cfg = NlosGainConfig(cap_m=8.0, margin_m=0.3, max_incidence_deg=80.0)
    flat, _ = viewpoint_carved(walls, observed, [(18, 50)], cfg, RES)
    rows, _ = np.unravel_index(flat, shape)
    assert len(flat) > 0 and rows.min() >= 12 and rows.max() <= 23
    # Each relay point's radius is at most its distance to the facing wall's surface (12.5 - 0.75 from the vertex,
    # 12.5 from the centre) less the margin: no cell centre 12.5 - 3 cells or more from its wall's cells.
    assert np.all(np.minimum(rows + 0.5 - 11.5, 24.5 - (rows + 0.5)) < 12.5 - 3 + 1e-9)


def test_wall_ends_corners_and_grazing_relay_points_are_not_carved_from():
    """A wall segment seen end-on carves nothing from its end cell; a wall seen only beyond the incidence limit
    carves nothing; a viewpoint inside a wall carves nothing."""
    shape = (40, 80)
    wall = np.zeros(shape, bool)
    wall[20, 40:80] = True  # a thin wall from column 40 to the border: its end faces the viewpoint at (20, 10)
    observed, mean, walls = _scene(shape, wall)
    cfg = NlosGainConfig(n_rays=720)
    flat, _ = viewpoint_carved(walls, observed, [(20, 10)], cfg, RES)
    # Rays reaching the wall from (20, 10) meet it within a few degrees of grazing or at its end: nothing carved.
    assert len(flat) == 0
    flat, offsets = viewpoint_carved(walls, observed, [(20, 45)], cfg, RES)
    assert len(flat) == 0 and offsets.tolist() == [0, 0]


@pytest.mark.parametrize("seed", range(10))
def test_viewpoint_carved_matches_the_slow_twin(seed):
    """Random rooms of rectangles and wall segments, random viewpoints and settings: the kernel's cells are the
    twin's, cell for cell."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(30, 50)), int(rng.integers(30, 50)))
    wall = np.zeros(shape, bool)
    wall[[0, -1], :] = True
    wall[:, [0, -1]] = True
    for _ in range(int(rng.integers(2, 6))):
        r, c = int(rng.integers(2, shape[0] - 2)), int(rng.integers(2, shape[1] - 2))
        if rng.random() < 0.5:
            wall[r:r + int(rng.integers(1, 3)), c:c + int(rng.integers(3, 20))] = True
        else:
            wall[r:r + int(rng.integers(3, 20)), c:c + int(rng.integers(1, 3))] = True
    observed, mean, walls = _scene(shape, wall)
    observed[(rng.random(shape) < 0.3) & ~wall] = FREE
    # Odd ray counts: no ray at a multiple of 45 degrees, the only directions from a cell centre (or from the fans'
    # vertices, 0.75 cells off it) that pass exactly through cell corners, where the DDA and the twin's crossing
    # list may pick either neighbour.
    cfg = NlosGainConfig(n_rays=2 * int(rng.integers(4, 30)) + 1, fan_rays=2 * int(rng.integers(2, 12)) + 1,
                         cap_m=float(rng.uniform(0.5, 3.0)), max_incidence_deg=float(rng.uniform(40, 89)),
                         sector_deg=float(rng.uniform(40, 89)))
    free = np.argwhere(~wall)
    views = free[rng.choice(len(free), 3, replace=False)]
    flat, offsets = viewpoint_carved(walls, observed, views, cfg, RES)
    for v, cell in enumerate(views):
        got = set(flat[offsets[v]:offsets[v + 1]].tolist())
        assert got == naive_nlos_carved(walls, observed, tuple(cell), *_kernel_args(cfg, RES))


def test_union_counts_each_cell_once_per_group():
    """The union of a group's viewpoints counts a cell carved from two of them once; a group of one viewpoint counts
    that viewpoint's cells; groups share viewpoints without changing each other."""
    rng = np.random.default_rng(7)
    shape = (40, 60)
    wall = np.zeros(shape, bool)
    wall[[0, -1], :] = True
    wall[:, [0, -1]] = True
    wall[15:17, 10:50] = True
    observed, mean, walls = _scene(shape, wall)
    cells = np.array([(25, 20), (25, 30), (25, 40), (25, 30)])
    offsets = [0, 1, 3, 4]
    cfg = NlosGainConfig(cap_m=2.0)
    counts = union_nlos_gains(observed, mean, cells, offsets, cfg, RES)
    flat, view_offsets = viewpoint_carved(walls, observed, cells, cfg, RES)
    per_view = [set(flat[a:b].tolist()) for a, b in zip(view_offsets[:-1], view_offsets[1:])]
    assert counts.tolist() == [len(per_view[0]), len(per_view[1] | per_view[2]), len(per_view[3])]
    assert counts[1] > 0 and counts[1] < len(per_view[1]) + len(per_view[2])  # the two overlap
    del rng


def test_predicted_walls_relay_and_known_free_cells_do_not():
    """An unknown cell predicted a wall is a relay wall; a known FREE cell is not, whatever the prediction says."""
    observed = np.full((30, 40), UNKNOWN, np.int8)
    mean = np.zeros((30, 40), np.float32)
    mean[10:12, :] = 0.9
    observed[11, :5] = FREE
    walls = planning_walls(observed, mean, 0.5)
    assert walls[10].all() and walls[11, 5:].all() and not walls[11, :5].any()
    assert union_nlos_gains(observed, mean, [(20, 20)], [0, 1], NlosGainConfig(cap_m=2.0), RES)[0] > 0
    assert union_nlos_gains(observed, np.zeros_like(mean), [(20, 20)], [0, 1], NlosGainConfig(cap_m=2.0), RES)[0] == 0


@pytest.mark.parametrize("call, message", [
    (lambda o, m: planning_walls(o, m.astype(np.float16), 0.5), "mean must be a float32 or float64 (10, 12)"),
    (lambda o, m: planning_walls(o, m[:5], 0.5), "mean must be a float32 or float64 (10, 12)"),
    (lambda o, m: viewpoint_carved(np.zeros((10, 12), np.uint8), o, [(1, 1)], NlosGainConfig(), RES),
     "walls must be a non-empty bool [H, W] array"),
    (lambda o, m: viewpoint_carved(np.zeros((10, 12), bool), o, [(10, 1)], NlosGainConfig(), RES),
     "cell (10, 1) lies outside the map"),
    (lambda o, m: viewpoint_carved(np.zeros((10, 12), bool), o, [(1, 1)], NlosGainConfig(), 0.0),
     "resolution_m"),
    (lambda o, m: union_nlos_gains(o, m, [(1, 1), (2, 2)], [0, 1], NlosGainConfig(), RES),
     "offsets must run non-decreasing from 0 to 2"),
])
def test_bad_inputs_are_refused(call, message):
    observed = np.full((10, 12), UNKNOWN, np.int8)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")
                       .replace("]", r"\]")):
        call(observed, np.zeros((10, 12), np.float32))


@pytest.mark.parametrize("field, value", [("n_rays", 2), ("fan_rays", 1), ("cap_m", 0.0), ("sector_deg", 95.0),
                                          ("max_incidence_deg", 0.0), ("margin_m", -0.1), ("wall_threshold", 0.0)])
def test_config_refuses_out_of_range_fields(field, value):
    with pytest.raises(ValueError, match=field):
        NlosGainConfig(**{field: value})


def test_config_round_trips():
    cfg = NlosGainConfig(n_rays=36, cap_m=4.0, wall_threshold=0.3)
    assert NlosGainConfig.from_json(cfg.to_json()) == cfg
