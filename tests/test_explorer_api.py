"""The explorer's public API for goals chosen outside it (the Gymnasium environment's agent):
:meth:`Explorer.frontier_candidates` is exactly what the explorer offers its planner, :meth:`Explorer.drop_goal`
makes the next step choose again."""

import numpy as np
import pytest

from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import NO_REACHABLE_FRONTIER, LaserScan, MapFrame, Observation, Pose2D
from superex_deploy.onboard import Explorer
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.planning.planners import NearestFrontier
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import PlanningContext
from superex_deploy.sim.world import World


class _Spy(NearestFrontier):
    """The nearest frontier, recording the regions offered at each call; refuses the first offer of a step when
    told to (the explorer then offers the smaller regions)."""

    def __init__(self) -> None:
        self.offers: list[list[tuple[int, int]]] = []
        self.refuse_first = False

    def choose_goal(self, ctx: PlanningContext):
        self.offers.append([f.cell_rc for f in ctx.frontiers])
        if self.refuse_first and len(self.offers) == 1:
            return None
        return super().choose_goal(ctx)


def test_frontier_candidates_are_what_the_explorer_offers_its_planner():
    grid = load_map("50052750")
    world = World(grid, start_poses("50052750")[1])
    planner = _Spy()
    explorer = Explorer(world.frame, planner, ObservedAsPrediction())
    assert explorer.frontier_candidates(world.pose_rc) == ()  # nothing known yet
    min_cells = explorer.frontier_min_cells
    assert min_cells == 10  # frontier_min_m = 1 m at 0.1 m
    checked_large = checked_small = 0
    for t in range(300):
        planner.offers, planner.refuse_first = [], t % 4 == 3
        if t % 5 == 4:
            explorer.drop_goal()  # more choices, between goals reached
        command = explorer.step(world.observe())
        candidates = explorer.frontier_candidates(world.pose_rc)
        large = [f.cell_rc for f in candidates if len(f.cells) >= min_cells]
        small = [f.cell_rc for f in candidates if len(f.cells) < min_cells]
        offers = planner.offers
        if offers and explorer.frontiers:  # the first tier: the regions of at least min_cells cells
            assert offers[0] == large
            checked_large += 1
            offers = offers[1:]
        if offers and offers[0] == small:  # the second tier: the smaller regions
            checked_small += bool(small)
            offers = offers[1:]
        for last_resort in offers:  # regions that count as reached already: never candidates
            assert not set(last_resort) & {f.cell_rc for f in candidates}
        if command.finished and not planner.refuse_first:
            break
        world.apply(command)
    assert checked_large > 10 and checked_small > 0, (checked_large, checked_small)


def _disc_observation(frame: MapFrame, cell: tuple[int, int], range_m: float, step: int = 0) -> Observation:
    """A scan without returns: the explorer marks free a disc of ``range_m`` around ``cell``."""
    x, y = frame.centre_xy(cell)
    scan = LaserScan(0.0, 2 * np.pi / 720, 0.0, range_m, np.full(720, np.inf, np.float32))
    return Observation(step * 0.1, Pose2D(x, y), scan)


def test_frontier_candidates_drop_regions_reached_already_and_goals_visited_before():
    frame = MapFrame((60, 60), 0.1)
    centre, far = (30, 30), (5, 5)
    explorer = Explorer(frame, NearestFrontier(), ObservedAsPrediction())  # goal_reached_m = 1 m: 10 cells
    explorer.step(_disc_observation(frame, centre, 1.2))
    (ring,) = find_frontiers(explorer.observed, 1)
    assert np.hypot(*np.subtract(ring.cell_rc, centre)) > 10
    assert [f.cell_rc for f in explorer.frontier_candidates(centre)] == [ring.cell_rc]

    explorer = Explorer(frame, NearestFrontier(), ObservedAsPrediction())
    command = explorer.step(_disc_observation(frame, centre, 0.98))
    (ring,) = find_frontiers(explorer.observed, 1)
    assert 9 < np.hypot(*np.subtract(ring.cell_rc, centre)) <= 10  # within the tolerance, in sight: reached
    assert explorer.frontier_candidates(centre) == ()
    assert [f.cell_rc for f in explorer.frontier_candidates(far)] == [ring.cell_rc]
    # The last resort: the explorer drives onto the goal cell; reached there, the region stays (nothing new seen).
    assert command.goal_rc == ring.cell_rc
    command = explorer.step(_disc_observation(frame, ring.cell_rc, 0.02, step=1))
    assert explorer.visited_goals == {ring.cell_rc} and command.goal_rc is None
    assert not command.finished and command.status == NO_REACHABLE_FRONTIER  # until the finish delay, 5 s
    assert [f.cell_rc for f in find_frontiers(explorer.observed, 1)] == [ring.cell_rc]
    assert explorer.frontier_candidates(far) == ()  # a goal visited before is not offered again


def test_drop_goal_makes_the_next_step_choose_again():
    grid = load_map("50052750")
    world = World(grid, start_poses("50052750")[0])
    explorer = Explorer(world.frame, NearestFrontier(), ObservedAsPrediction())
    command = explorer.step(world.observe())
    world.apply(command)
    command = explorer.step(world.observe())
    assert explorer.goal is not None and not command.new_goal  # the goal is locked
    visited = explorer.visited_goals
    explorer.drop_goal()
    assert explorer.goal is None and explorer.path == []
    command = explorer.step(world.observe())
    assert command.new_goal and explorer.goal is not None and explorer.visited_goals == visited


def test_frontier_candidates_refuse_a_cell_off_the_map():
    grid = load_map("50052750")
    explorer = Explorer(World(grid, start_poses("50052750")[0]).frame, NearestFrontier(), ObservedAsPrediction())
    with pytest.raises(ValueError, match="outside the map"):
        explorer.frontier_candidates((-1, 0))
    with pytest.raises(ValueError, match="outside the map"):
        explorer.frontier_candidates(np.array(grid.shape))
