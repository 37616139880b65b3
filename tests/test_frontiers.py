import numpy as np
import pytest

from superex_deploy.onboard.planning.frontiers import find_frontiers, frontier_cells
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
from tests.naive import naive_frontier_regions


def test_a_corridor_opening_into_the_unknown(observed_from_text):
    observed = observed_from_text([
        "#######",
        "#.....?",
        "#.....?",
        "#.....?",
        "#######",
    ])
    np.testing.assert_array_equal(np.argwhere(frontier_cells(observed)), [[1, 5], [2, 5], [3, 5]])
    (region,) = find_frontiers(observed, min_cells=3)
    assert region.cell_rc == (2, 5) and region.size == 3
    np.testing.assert_array_equal(region.cells, [[1, 5], [2, 5], [3, 5]])
    assert region.cells.dtype == np.int32


def test_diagonal_cells_join_a_region_but_diagonal_unknowns_make_no_frontier(observed_from_text):
    observed = observed_from_text([
        "?.....",
        ".?....",
        "......",
    ])
    # (0,1) and (1,0) touch both unknown cells, (1,2) and (2,1) touch (1,1); (0,2) and (2,0) only touch an
    # unknown cell diagonally.
    expected = {(0, 1), (1, 0), (1, 2), (2, 1)}
    assert set(map(tuple, np.argwhere(frontier_cells(observed)).tolist())) == expected
    (region,) = find_frontiers(observed, min_cells=1)  # all four are 8-connected through diagonals
    assert region.size == 4
    # Centroid (1, 1) is equidistant from all four: the first in row-major order wins.
    assert region.cell_rc == (0, 1)


def test_walls_and_the_grid_border_are_not_unknown(observed_from_text):
    observed = observed_from_text([
        "....",
        ".##.",
        "....",
    ])
    assert not frontier_cells(observed).any() and find_frontiers(observed, min_cells=1) == ()
    assert find_frontiers(np.full((4, 4), UNKNOWN, np.int8), min_cells=1) == ()


def test_regions_match_a_flood_fill_on_random_maps():
    rng = np.random.default_rng(2)
    nonempty = 0
    for trial in range(60):
        shape = (int(rng.integers(1, 20)), int(rng.integers(1, 20)))
        p_unknown = rng.uniform(0.05, 0.6)
        observed = rng.choice(np.array([FREE, UNKNOWN, OCCUPIED], np.int8), size=shape,
                              p=[0.8 - p_unknown, p_unknown, 0.2])
        min_cells = int(rng.integers(1, 6))
        got = find_frontiers(observed, min_cells=min_cells)
        expected = naive_frontier_regions(observed, min_cells)
        assert [f.cell_rc for f in got] == [goal for _, goal in expected]
        for frontier, (cells, _) in zip(got, expected):
            assert [tuple(cell) for cell in frontier.cells.tolist()] == cells
        nonempty += bool(got)
    assert nonempty > 30


def test_bad_inputs_raise_value_error():
    with pytest.raises(ValueError, match="int8"):
        find_frontiers(np.zeros((3, 3), np.int16))
    with pytest.raises(ValueError, match="int8"):
        frontier_cells(np.zeros(3, np.int8))
    with pytest.raises(ValueError, match="min_cells"):
        find_frontiers(np.zeros((3, 3), np.int8), min_cells=0)


def test_frontiers_on_a_hand_built_map(observed_from_text):
    observed = observed_from_text([
        "#############",
        "#.....?????..",
        "#.....?????..",
        "#............",
        "#############",
    ])
    cells = frontier_cells(observed)
    expected = {(1, 5), (2, 5), (3, 6), (3, 7), (3, 8), (3, 9), (3, 10), (1, 11), (2, 11)}
    assert set(map(tuple, np.argwhere(cells).tolist())) == expected
    (region,) = find_frontiers(observed, min_cells=9)
    assert region.size == 9
    assert region.cell_rc == (3, 8)  # nearest to the centroid (2.33, 8.0)
    assert find_frontiers(observed, min_cells=10) == ()


def test_separate_frontier_regions_are_ordered_and_filtered():
    observed = np.full((12, 12), FREE, np.int8)
    observed[0:3, 0:3] = UNKNOWN     # frontier: 3 + 3 cells along two sides (diagonal neighbours do not count)
    observed[8:12, 8:12] = UNKNOWN   # 4 + 4 cells
    regions = find_frontiers(observed, min_cells=1)
    assert [r.size for r in regions] == [6, 8]
    assert [r.size for r in find_frontiers(observed, min_cells=7)] == [8]
