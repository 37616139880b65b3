"""Altered floors (superex_deploy.sim.alterations) and their dead ends (superex_deploy.sim.dead_ends): the start stays
connected and its surroundings untouched, the valid area is what the robot reaches, the same seed gives the same
floor, every obstruction makes a dead end whose obstruction the branch entrance cannot see, bad inputs are refused."""

import zlib

import numpy as np
import pytest
from scipy import ndimage

from superex_deploy.geometry import line_of_sight
from superex_deploy.maps import OccupancyGrid, load_map, random_start
from superex_deploy.sim.alterations import AlterationConfig, alter_floor, alter_floor_with_record
from superex_deploy.sim.dead_ends import dead_end_entries, measure_dead_end, robot_cells

RADIUS_CELLS = AlterationConfig().robot_radius_m / 0.1
TRAIN_FLOORS = ("0510040942_A-40", "0510045906_A_40_1_104", "0510032260_A_40_1_102")


def ring_floor() -> OccupancyGrid:
    """A start room (top left, 8 m x 8 m) joined to a far room (bottom right) by two L-shaped corridors 1.5 m wide:
    a ring, where a cut after a corridor's turn leaves a dead end hidden from the corridor's entrance."""
    occupied = np.ones((240, 240), bool)
    occupied[10:90, 10:90] = False
    occupied[150:230, 150:230] = False
    occupied[40:55, 90:190] = False
    occupied[40:150, 175:190] = False
    occupied[90:190, 40:55] = False
    occupied[175:190, 40:150] = False
    return OccupancyGrid(occupied=occupied, valid=~occupied, resolution_m=0.1, name="ring")


RING_START = (50, 50)


def straight_floor() -> OccupancyGrid:
    """A room with one straight corridor: whatever blocks it is in sight from the corridor's entrance."""
    occupied = np.ones((100, 260), bool)
    occupied[10:90, 10:90] = False
    occupied[40:55, 90:250] = False
    return OccupancyGrid(occupied=occupied, valid=~occupied, resolution_m=0.1, name="straight")


def _train_scenario(name: str):
    grid = load_map(name)
    start = random_start(grid, np.random.default_rng(zlib.crc32(name.encode())), 0.5)
    return grid, start


@pytest.fixture(scope="module")
def altered_floors():
    """Altered floors (several seeds on the ring, one on each train floor) with their inputs."""
    out = [alter_floor_with_record(ring_floor(), RING_START, seed) for seed in range(4)]
    for name in TRAIN_FLOORS:
        grid, start = _train_scenario(name)
        out.append(alter_floor_with_record(grid, start, 0))
    return out


def _footprint_naive(reach: np.ndarray, radius_cells: float) -> np.ndarray:
    """Cells within ``radius_cells`` + 1 of a reachable cell, by brute force over the reachable cells."""
    rows, cols = np.mgrid[:reach.shape[0], :reach.shape[1]]
    near = np.zeros(reach.shape, bool)
    for r, c in np.argwhere(reach):
        box = (slice(max(r - 3, 0), r + 4), slice(max(c - 3, 0), c + 4))
        near[box] |= np.hypot(rows[box] - r, cols[box] - c) <= radius_cells + 1.0
    return near


def test_every_floor_gets_a_dead_end(altered_floors):
    assert all(record.alterations for record in altered_floors)
    assert all(record.kept_fraction >= record.cfg.min_kept_fraction for record in altered_floors)


def test_the_start_stays_connected_and_the_valid_area_is_what_the_robot_reaches(altered_floors):
    for record in altered_floors:
        grid, start = record.grid, record.start_rc
        reach = robot_cells(grid.occupied, start, RADIUS_CELLS)
        assert reach[start] and reach.sum() > 100
        assert grid.valid[start] and not grid.occupied[start]
        assert not (grid.valid & grid.occupied).any() and not (grid.valid & ~record.original.valid).any()
        labels, _ = ndimage.label(grid.valid, structure=np.ones((3, 3), bool))
        assert (labels[grid.valid] == labels[start]).all(), "the valid area is one piece holding the start"
        if grid.name == "ring":  # the brute-force footprint on the small grid
            expected = _footprint_naive(reach, RADIUS_CELLS) & record.original.valid & ~grid.occupied
            np.testing.assert_array_equal(grid.valid, expected)
        assert reach.sum() >= record.cfg.min_kept_fraction * robot_cells(record.original.occupied, start, RADIUS_CELLS).sum()


def test_the_start_surroundings_are_never_touched(altered_floors):
    for record in altered_floors:
        rows, cols = np.mgrid[:record.grid.shape[0], :record.grid.shape[1]]
        near = np.hypot(rows - record.start_rc[0], cols - record.start_rc[1]) * 0.1 <= record.cfg.protect_radius_m
        np.testing.assert_array_equal(record.grid.occupied[near], record.original.occupied[near])
        added = record.grid.occupied & ~record.original.occupied
        assert added.any() and not (added & near).any()
        assert not (record.original.occupied & ~record.grid.occupied).any(), "walls are only added"
        cuts = np.zeros(record.grid.shape, bool)
        for alteration in record.alterations:
            cuts |= alteration.cut
        np.testing.assert_array_equal(cuts, added)


def test_each_obstruction_makes_a_dead_end_hidden_from_its_entrance(altered_floors):
    for record in altered_floors:
        reach = robot_cells(record.grid.occupied, record.start_rc, RADIUS_CELLS)
        for alteration in record.alterations:
            dead_end = alteration.dead_end
            assert dead_end.length_m >= record.cfg.min_dead_end_m
            assert dead_end.hidden_m >= record.cfg.min_hidden_m
            assert not (dead_end.pocket & ~reach).any(), "the dead end is reachable"
            assert not dead_end.pocket[record.start_rc]
            mouth = np.zeros(reach.shape, bool)
            mouth[tuple(dead_end.mouth.T)] = True
            assert not (mouth & dead_end.pocket).any() and (mouth & ~reach).sum() == 0
            labels, _ = ndimage.label(reach & ~mouth, structure=np.ones((3, 3), bool))
            np.testing.assert_array_equal(labels == labels[dead_end.pocket][0], dead_end.pocket)
            assert labels[record.start_rc] != labels[dead_end.pocket][0], \
                "every way from the dead end to the start passes through its entrance"
            # The obstruction's face, on the dead end's side, is in sight of no cell of the entrance.
            assert (ndimage.binary_dilation(alteration.cut)[tuple(dead_end.face.T)]).all()
            for viewer in dead_end.mouth[::3]:
                for target in dead_end.face[::2]:
                    assert not line_of_sight(record.grid.occupied, viewer, target)
            depth = dead_end.depth_m[dead_end.pocket]
            assert np.isfinite(depth).all() and depth.min() >= 0 and depth.max() <= dead_end.length_m
            assert np.isnan(dead_end.depth_m[~dead_end.pocket]).all()


def test_the_dead_ends_are_new_the_unaltered_branch_led_on(altered_floors):
    for record in altered_floors:
        before = robot_cells(record.original.occupied, record.start_rc, RADIUS_CELLS)
        for alteration in record.alterations:
            mouth = np.zeros(before.shape, bool)
            mouth[tuple(alteration.dead_end.mouth.T)] = True
            labels, _ = ndimage.label(before & ~mouth, structure=np.ones((3, 3), bool))
            pocket_labels = set(np.unique(labels[alteration.dead_end.pocket]))
            assert labels[record.start_rc] in pocket_labels, "without the obstruction the branch had another way out"


def test_a_block_in_sight_of_the_entrance_is_never_made():
    record = alter_floor_with_record(straight_floor(), (50, 30), 0)
    assert record.alterations == () and record.candidates_tried > 0
    np.testing.assert_array_equal(record.grid.occupied, straight_floor().occupied)


@pytest.mark.slow
def test_the_same_seed_gives_the_same_floor_and_other_seeds_other_floors():
    for grid, start in (( ring_floor(), RING_START), _train_scenario(TRAIN_FLOORS[0])):
        first, again = alter_floor(grid, start, 3), alter_floor(grid, start, 3)
        np.testing.assert_array_equal(first.occupied, again.occupied)
        np.testing.assert_array_equal(first.valid, again.valid)
        others = [alter_floor(grid, start, seed) for seed in (4, 5, 6)]
        assert any(not np.array_equal(first.occupied, other.occupied) for other in others)
        assert first.name == grid.name and first.resolution_m == grid.resolution_m


def test_the_floor_geometry_and_the_seed_alone_decide():
    grid = ring_floor()
    renamed = OccupancyGrid(occupied=grid.occupied, valid=grid.valid, resolution_m=0.1, name="another name")
    np.testing.assert_array_equal(alter_floor(grid, RING_START, 1).occupied, alter_floor(renamed, RING_START, 1).occupied)


def test_no_alterations_only_recomputes_the_valid_area():
    grid = ring_floor()
    grid = OccupancyGrid(occupied=grid.occupied, valid=np.ones(grid.shape, bool) & ~grid.occupied,
                         resolution_m=0.1, name="ring")
    plain = alter_floor(grid, RING_START, 0, AlterationConfig(alterations=0))
    np.testing.assert_array_equal(plain.occupied, grid.occupied)
    assert plain.valid.sum() == grid.valid.sum(), "every free cell of the ring is within the robot's reach"


@pytest.mark.parametrize("start, message", [((0, 0), "inside a wall"), ((-1, 5), "outside"),
                                            ((500, 5), "outside"), ("a", "pair of integers")])
def test_a_bad_start_is_refused(start, message):
    with pytest.raises(ValueError, match=message):
        alter_floor(ring_floor(), start, 0)


def test_a_start_outside_the_valid_area_is_refused():
    grid = ring_floor()
    valid = grid.valid.copy()
    valid[:100, :100] = False
    with pytest.raises(ValueError, match="outside the valid area"):
        alter_floor(OccupancyGrid(occupied=grid.occupied, valid=valid, resolution_m=0.1, name="x"), RING_START, 0)


@pytest.mark.parametrize("seed", [-1, 1.5, True, "0", None])
def test_a_bad_seed_is_refused(seed):
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        alter_floor(ring_floor(), RING_START, seed)


@pytest.mark.parametrize("options, message", [
    ({"robot_radius_m": -0.1}, "robot_radius_m"), ({"alterations": -1}, "alterations"),
    ({"alterations": 1.5}, "alterations"), ({"min_kept_fraction": 1.5}, "min_kept_fraction"),
    ({"door_max_half_width_m": 2.0}, "door_max_half_width_m"), ({"facing_ratio": 3.0}, "facing_ratio"),
    ({"level_step_m": 0.0}, "level_step_m"), ({"min_dead_end_m": 50.0}, "min_dead_end_m"),
    ({"protect_radius_m": float("nan")}, "protect_radius_m"), ({"min_hidden_m": "2"}, "min_hidden_m")])
def test_a_bad_config_is_refused(options, message):
    with pytest.raises(ValueError, match=message):
        AlterationConfig(**options)


def test_other_arguments_are_refused():
    with pytest.raises(ValueError, match="OccupancyGrid"):
        alter_floor(np.zeros((10, 10), bool), (5, 5), 0)
    with pytest.raises(ValueError, match="AlterationConfig"):
        alter_floor(ring_floor(), RING_START, 0, cfg={"alterations": 1})


def test_dead_end_entries_count_the_drives_into_a_dead_end(altered_floors):
    record = altered_floors[0]
    dead_end = record.alterations[0].dead_end
    cells = np.argwhere(dead_end.pocket)
    deepest = cells[np.nanargmax(dead_end.depth_m[dead_end.pocket])]
    outside = record.start_rc
    poses = np.array([outside, outside, deepest, deepest, outside])
    driven = np.array([0.0, 1.0, 5.0, 6.0, 11.0])
    entries = dead_end_entries(record.dead_ends, poses, driven)
    assert entries.entries == 1 and entries.reached_end == 1
    assert entries.metres_in == pytest.approx(0.0) and entries.metres_inside == pytest.approx(1.0)
    assert entries.deepest_m == pytest.approx(float(np.nanmax(dead_end.depth_m)))
    none = dead_end_entries(record.dead_ends, poses[:2], driven[:2])
    assert none.entries == 0 and none.metres_inside == 0.0 and none.to_json()["entries"] == 0
    with pytest.raises(ValueError, match="poses but"):
        dead_end_entries(record.dead_ends, poses, driven[:3])
    with pytest.raises(ValueError, match="inside the grid"):
        dead_end_entries(record.dead_ends, [[-1, 0]], [0.0])


def test_the_robot_drives_through_a_doorway_outside_the_valid_area():
    """The eval floors' valid areas leave the doorways out; the robot's reach (and so the alterations' robot cells)
    goes through them."""
    occupied = np.zeros((40, 80), bool)
    occupied[[0, -1], :], occupied[:, [0, -1]] = True, True
    occupied[:, 38:42] = True
    occupied[15:25, 38:42] = False  # a doorway 1 m wide through a wall 0.4 m thick
    valid = ~occupied
    valid[:, 38:42] = False  # the doorway is not in the valid area
    reach = robot_cells(occupied, (20, 10), 1.5)
    assert reach[20, 70] and reach[20, 40], "the room beyond the doorway is reached through it"
    assert not reach[occupied].any()


def test_the_dead_end_helpers_refuse_bad_grids():
    grid = ring_floor()
    with pytest.raises(ValueError, match="bool"):
        robot_cells(grid.occupied.astype(np.uint8), RING_START, 1.5)
    with pytest.raises(ValueError, match="bool"):
        robot_cells(grid.occupied[0], RING_START, 1.5)
    with pytest.raises(ValueError, match="outside"):
        robot_cells(grid.occupied, (999, 0), 1.5)
    reach = robot_cells(grid.occupied, RING_START, 1.5)
    cut = np.zeros(grid.shape, bool)
    with pytest.raises(ValueError, match="not a reachable cell"):
        measure_dead_end(grid.occupied, reach, cut, (0, 0), np.array([[50, 50]]), RING_START, 0.1)
    with pytest.raises(ValueError, match="face"):
        measure_dead_end(grid.occupied, reach, cut, RING_START, np.zeros((0, 2)), RING_START, 0.1)
