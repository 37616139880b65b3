"""Space carving at wall corners and steps: a property test over random L-shaped walls (every orientation, turn,
thickness and distance, seen from either side) in a closed room, and the cases it found.

What it found (docs/benchmarks/spad.md, "Corners and steps"): a rasterised oblique wall is a staircase, and
the simulator's fan leaves each wall cell along that cell's own surface normal (Sobel of its 3x3 neighbourhood),
which at a step turns up to 45 degrees off the wall's fitted line. The carved sector, +-(90 - 20) degrees about
the fitted normal, then reached past the fan's edge, where no secondary ray had looked, and carved the far wall's
corner. The sector is now narrowed by the wall's turn at each cell (``carving.sector_cos_limits``)."""

import numpy as np
import pytest

from superex_deploy.onboard.nlos import NlosConfig, carve, estimate_los
from superex_deploy.onboard.nlos import carving
from superex_deploy.spad_types import SpadConfig
from superex_deploy.sim.corner_scenes import l_corner_scene
from superex_deploy.sim.spad import simulate_scan
from tests.naive import sector_without_steps

N_SCENES = 500
CONFIG = SpadConfig(n_rays=720, n_secondary=256)


def _walls_carved(seed, nlos_cfg=NlosConfig()):
    grid, pose = l_corner_scene(seed)
    scan = simulate_scan(grid, pose, CONFIG)
    carved = carve(scan, estimate_los(scan, nlos_cfg), nlos_cfg)
    return int((carved & grid.occupied).sum()), int(carved.sum())


# Scenes where the sector of a stepping wall cell reached a wall its fan never covered (found by the property test
# over seeds 0-2,499: 4 scenes carved true walls with the old sector; these 3 are the step's, the 4th is the limit
# below).
STEP_SCENES = (1590, 1595, 2117)


@pytest.mark.parametrize("seed", STEP_SCENES)
def test_the_sector_narrows_where_the_wall_steps(seed, monkeypatch):
    walls, carved = _walls_carved(seed)
    assert walls == 0 and carved > 10000
    monkeypatch.setattr(carving, "sector_cos_limits", sector_without_steps)
    old_walls, old_carved = _walls_carved(seed)
    assert old_walls > 0  # the scene tells the rules apart
    assert carved < old_carved < carved * 1.05  # and the narrowing costs little there


@pytest.mark.slow
def test_carving_is_sound_at_random_l_corners():
    violations, carved = [], 0
    for seed in range(N_SCENES):
        walls, cells = _walls_carved(seed)
        carved += cells
        if walls:
            violations.append((seed, walls))
    assert not violations, f"{len(violations)} scenes carved true walls, e.g. {violations[:3]}"
    # Usefulness: the test cannot pass by carving nothing (measured: ~34,000 of the room's ~48,000 cells a scene).
    assert carved / N_SCENES > 20000


@pytest.mark.xfail(strict=True, reason="the simulator's cell normal reads the wall's back face (module docstring)")
def test_a_back_face_step_turns_a_fan_no_scan_can_see():
    """Seed 2475: a wall two cells thick whose front row runs straight past the cell while its back row starts one
    cell along; the simulator's Sobel normal at the front cell turns 18 degrees towards the back step, 31 degrees
    from the fitted line, and the sector's edge carves 10 cells of the far wall. Nothing the robot measures shows
    the back face; this test fails (passes) once the simulator's normal is the visible surface's, or a rule covers it."""
    assert _walls_carved(2475)[0] == 0
