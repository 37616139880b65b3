import numpy as np
import pytest

from superex_deploy.geometry import (group_by_cell, cast_rays, cell_centre, line_of_sight, mark_rays, minor_axis_2x2,
                                     ray_angles)
from tests.naive import naive_first_hit, naive_group_by_cell, naive_mark_rays


def _random_grid(rng, shape, density):
    grid = rng.random(shape) < density
    return grid


@pytest.mark.parametrize("dtype", [np.int32, np.int64])  # the simulator's hit cells, the processing's wall cells
@pytest.mark.parametrize("seed", range(3))
def test_group_by_cell_matches_naive(seed, dtype):
    rng = np.random.default_rng(seed)
    n_rays, n_cols = 300, 17
    # Runs of repeated cells, cells that come back after other cells, and misses.
    cells = rng.integers(0, 6, size=(n_rays // 5, 2)).repeat(5, axis=0)
    cells[rng.random(n_rays) < 0.2] = -1
    ray_group, group_cells, first_ray = group_by_cell(cells.astype(dtype), n_cols)
    expected = naive_group_by_cell(cells, n_cols)
    np.testing.assert_array_equal(ray_group, expected[0])
    np.testing.assert_array_equal(group_cells, expected[1])
    np.testing.assert_array_equal(first_ray, expected[2])
    none = group_by_cell(np.full((4, 2), -1, dtype), n_cols)
    assert (none[0] == -1).all() and none[1].shape == (0, 2) and none[2].shape == (0,)


def test_axis_aligned_hits_have_exact_distances():
    occupied = np.zeros((21, 21), bool)
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    hits = cast_rays(occupied, cell_centre((10, 10)), [0.0, np.pi / 2, np.pi, 1.5 * np.pi], 100.0)
    np.testing.assert_array_equal(hits.hit_rc, [[10, 20], [20, 10], [10, 0], [0, 10]])
    np.testing.assert_allclose(hits.distance_cells, [9.5, 9.5, 9.5, 9.5], atol=1e-12)
    np.testing.assert_array_equal(hits.entry_axis, [1, 0, 1, 0])


def test_diagonal_ray_through_wall_corner_gap_is_blocked():
    # Two walls touching only at a corner: the exact-diagonal ray must not slip through.
    occupied = np.zeros((4, 4), bool)
    occupied[1, 2] = occupied[2, 1] = True
    hits = cast_rays(occupied, (1.5, 1.5), [np.pi / 4], 10.0)
    assert tuple(hits.hit_rc[0]) in {(1, 2), (2, 1)}


def test_range_limit_and_leaving_the_grid():
    occupied = np.zeros((5, 50), bool)
    occupied[2, 40] = True
    hits = cast_rays(occupied, cell_centre((2, 2)), [0.0, np.pi], 10.0)
    assert not hits.hit_mask.any()
    assert hits.distance_cells[0] == 10.0
    assert hits.distance_cells[1] == pytest.approx(2.5)


def test_cast_rays_matches_naive_on_random_grids():
    rng = np.random.default_rng(0)
    for _ in range(40):
        shape = tuple(rng.integers(3, 25, size=2))
        occupied = _random_grid(rng, shape, rng.uniform(0.02, 0.3))
        origin = (rng.uniform(0, shape[0]), rng.uniform(0, shape[1]))
        angles = rng.uniform(0, 2 * np.pi, size=25)
        max_t = rng.uniform(1, 30)
        hits = cast_rays(occupied, origin, angles, max_t)
        for i, angle in enumerate(angles):
            r, c, t, axis = naive_first_hit(occupied, origin[0], origin[1], angle, max_t)
            assert (hits.hit_rc[i, 0], hits.hit_rc[i, 1]) == (r, c)
            assert hits.distance_cells[i] == pytest.approx(t, abs=1e-9)
            assert hits.entry_axis[i] == axis


@pytest.mark.slow
def test_mark_rays_matches_naive_on_random_grids():
    rng = np.random.default_rng(1)
    for _ in range(8):
        shape = tuple(rng.integers(4, 16, size=2))
        occupied = _random_grid(rng, shape, 0.15)
        free_cells = np.argwhere(~occupied)
        start = free_cells[rng.integers(len(free_cells))]
        origin = cell_centre(start)
        angles = ray_angles(64, offset_rad=rng.uniform(0, 0.1))
        free = np.zeros(shape, bool)
        hit = np.zeros(shape, bool)
        mark_rays(occupied, origin, angles, 12.0, free, hit)
        ref_free, ref_hit = naive_mark_rays(occupied, origin[0], origin[1], angles, 12.0)
        np.testing.assert_array_equal(hit, ref_hit)
        # Dense sampling can miss a cell the ray only clips within 1e-3 cells; DDA sees every crossed cell.
        assert np.all(free[ref_free])
        assert (free & ~ref_free).sum() <= 2
        assert not np.any(free & occupied) and np.all(occupied[hit])


def test_bad_inputs_raise_clear_errors():
    occupied = np.zeros((5, 5), bool)
    with pytest.raises(ValueError, match="bool"):
        cast_rays(occupied.astype(np.uint8), (1.5, 1.5), [0.0], 3.0)
    with pytest.raises(ValueError, match="outside the grid"):
        cast_rays(occupied, (5.5, 1.5), [0.0], 3.0)
    with pytest.raises(ValueError, match="2-D"):
        cast_rays(np.zeros(5, bool), (0.5, 0.5), [0.0], 3.0)
    with pytest.raises(ValueError, match="max_range_cells"):
        cast_rays(occupied, (1.5, 1.5), [0.0], 0.0)
    with pytest.raises(ValueError, match="finite"):
        cast_rays(occupied, (1.5, 1.5), [np.nan], 3.0)
    with pytest.raises(ValueError, match="n_rays"):
        ray_angles(0)
    with pytest.raises(ValueError, match="free_out"):
        mark_rays(occupied, (1.5, 1.5), [0.0], 3.0, np.zeros((4, 4), bool), np.zeros((5, 5), bool))


def test_line_of_sight_on_a_hand_built_grid():
    blocked = np.zeros((9, 9), bool)
    blocked[4, 2:7] = True  # a wall across the middle, open at both ends
    assert line_of_sight(blocked, (1, 4), (1, 8))  # along a free row
    assert not line_of_sight(blocked, (1, 4), (7, 4))  # straight through the wall
    assert line_of_sight(blocked, (1, 0), (7, 0))  # around its end
    assert not line_of_sight(blocked, (4, 3), (4, 3))  # a blocked cell does not see itself
    assert line_of_sight(blocked, (0, 0), (0, 0))
    assert not line_of_sight(blocked, (1, 4), (4, 4))  # the far end itself is blocked
    # Two blocked cells touching at a corner stop a diagonal line (columns are stepped first on the tie).
    corner = np.zeros((4, 4), bool)
    corner[1, 2] = corner[2, 1] = True
    assert not line_of_sight(corner, (0, 3), (3, 0))
    # On such a tie the cell beside the column step is entered, the one beside the row step is not.
    side = np.zeros((4, 4), bool)
    side[1, 0] = True
    assert line_of_sight(side, (0, 0), (3, 3))
    side[0, 1] = True
    assert not line_of_sight(side, (0, 0), (3, 3))


def _passes_a_cell_corner(y0, x0, y1, x1):
    """Whether the open segment crosses a row and a column boundary at the same point (where the DDA's
    column-first rule and the naive midpoint rule may pick different cells)."""
    rows = [(k - y0) / (y1 - y0) for k in range(int(min(y0, y1)), int(max(y0, y1)) + 2)] if y1 != y0 else []
    cols = [(k - x0) / (x1 - x0) for k in range(int(min(x0, x1)), int(max(x0, x1)) + 2)] if x1 != x0 else []
    return any(0 < t < 1 and abs(t - u) < 1e-12 for t in rows for u in cols)


def test_line_of_sight_matches_naive_first_hit_on_random_grids():
    rng = np.random.default_rng(7)
    compared = 0
    for _ in range(600):
        blocked = _random_grid(rng, (15, 20), 0.15)
        a = tuple(int(v) for v in rng.integers((0, 0), blocked.shape))
        b = tuple(int(v) for v in rng.integers((0, 0), blocked.shape))
        y0, x0 = cell_centre(a)
        y1, x1 = cell_centre(b)
        length = np.hypot(y1 - y0, x1 - x0)
        if _passes_a_cell_corner(y0, x0, y1, x1):
            continue
        compared += 1
        if length == 0:
            expected = not blocked[a]
        else:
            row, _, _, _ = naive_first_hit(blocked, y0, x0, np.arctan2(y1 - y0, x1 - x0), length)
            expected = row < 0
        assert line_of_sight(blocked, a, b) == expected
    assert compared > 300


def test_line_of_sight_rejects_bad_input():
    with pytest.raises(ValueError, match="bool array"):
        line_of_sight(np.zeros((3, 3), np.int8), (0, 0), (1, 1))
    with pytest.raises(ValueError, match="outside the grid"):
        line_of_sight(np.zeros((3, 3), bool), (0, 0), (3, 1))
    with pytest.raises(ValueError, match="outside the grid"):
        line_of_sight(np.zeros((3, 3), bool), (-1, 0), (1, 1))


def test_minor_axis_2x2_matches_numpy_eigh():
    """The shared 2x2 eigen-decomposition (wall normals in the SPAD simulator and the NLOS processing) against
    numpy's symmetric eigensolver, on random covariances including nearly isotropic and axis-aligned ones."""
    rng = np.random.default_rng(3)
    matrices = [rng.normal(size=(2, 2)) for _ in range(300)]
    covariances = [m @ m.T for m in matrices] + [np.diag([2.0, 1.0]), np.diag([1.0, 2.0]),
                                                   np.array([[1.0, 1e-7], [1e-7, 1.0 + 1e-6]])]
    for cov in covariances:
        cyy, cxy, cxx = cov[0, 0], cov[0, 1], cov[1, 1]
        half_trace, spread, vy, vx, norm = minor_axis_2x2(cyy, cxx, cxy)
        values, vectors = np.linalg.eigh(cov)
        np.testing.assert_allclose([half_trace - spread, half_trace + spread], values, rtol=1e-9, atol=1e-12)
        assert norm > 0.0
        unit = np.array([vy, vx]) / norm
        assert abs(abs(unit @ vectors[:, 0]) - 1.0) < 1e-6  # the minor eigenvector, up to sign


def test_minor_axis_2x2_isotropic_has_no_axis():
    assert minor_axis_2x2(1.0, 1.0, 0.0)[4] == 0.0
    assert minor_axis_2x2(0.0, 0.0, 0.0)[4] == 0.0
