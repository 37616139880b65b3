"""Generated office floors (superex_deploy.sim.generated_floors): seeded, of the size asked, one connected free
space, the same building at every resolution, and bad layouts refused."""

import numpy as np
import pytest
from scipy import ndimage

from superex_deploy.sim.generated_floors import FloorLayout, generate_floor


@pytest.mark.parametrize("seed", range(6))
def test_a_floor_is_one_connected_building_of_rooms_and_corridors(seed):
    layout = FloorLayout(width_m=40.0, height_m=30.0, cross_corridors=1 + seed % 2)
    grid = generate_floor(layout, 0.1, seed)
    assert grid.occupied.shape == (300, 400) and grid.valid.all()
    free = ~grid.occupied
    labels, count = ndimage.label(free)  # 4-connected: no room reached only across a corner
    assert count == 1
    assert 0.5 < free.mean() < 0.95  # walls and solid strips, but mostly rooms
    assert grid.occupied[[0, -1], :].all() and grid.occupied[:, [0, -1]].all()  # closed by its outer wall
    rooms = ndimage.label(ndimage.binary_erosion(free, iterations=6))[1]  # doors close: rooms and corridors apart
    assert rooms >= 8


def test_the_seed_draws_the_building_and_every_resolution_draws_the_same_one():
    layout = FloorLayout(width_m=30.0, height_m=20.0)
    assert np.array_equal(generate_floor(layout, 0.1, 3).occupied, generate_floor(layout, 0.1, 3).occupied)
    assert not np.array_equal(generate_floor(layout, 0.1, 3).occupied, generate_floor(layout, 0.1, 4).occupied)
    coarse = ~generate_floor(layout, 0.1, 5).occupied
    for k in (2, 4):
        fine = ~generate_floor(layout, 0.1 / k, 5).occupied
        assert fine.shape == (200 * k, 300 * k)
        pooled = fine.reshape(200, k, 300, k).mean(axis=(1, 3)) >= 0.5
        assert (pooled == coarse).mean() > 0.97  # the cells along the rectangles' edges may fall either way
        assert ndimage.label(fine)[1] == 1


def test_the_default_floor_is_larger_than_90_by_60_metres():
    grid = generate_floor(FloorLayout(), 0.1, 0)
    assert grid.occupied.shape[1] * 0.1 >= 90 and grid.occupied.shape[0] * 0.1 >= 60
    assert ndimage.label(~grid.occupied)[1] == 1


@pytest.mark.parametrize("kwargs, message", [
    ({"width_m": 0.0}, "FloorLayout.width_m"),
    ({"room_width_m": (8.0, 3.0)}, "low end 8.0 exceeds high end 3.0"),
    ({"door_m": 3.5}, "door_m \\(3.5\\) must be narrower"),
    ({"cross_corridors": 0}, "cross_corridors must be an integer >= 1"),
    ({"height_m": 10.0}, "too small for one band"),
])
def test_a_bad_layout_is_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FloorLayout(**kwargs)


def test_a_grid_too_coarse_for_the_walls_is_refused():
    with pytest.raises(ValueError, match="cannot draw 0.2 m walls"):
        generate_floor(FloorLayout(), 0.3, 0)
