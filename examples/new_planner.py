"""A new planner: "largest frontier first", registered beside the shipped ones and run by name.

A planner is a :class:`superex_deploy.onboard.types.Planner` subclass with a ``name`` and a ``choose_goal(ctx)``
that returns the goal cell from the step's :class:`~superex_deploy.onboard.types.PlanningContext` (its frontier
regions, the travel cost from the robot, the map). Registered (``register_planner``), it is built by name wherever
a planner is in this process (``make_planner``, ``build_explorer``, ``superex_deploy.cli.main(["explore",
"--planner", "largest", ...])``), though not in ``superex benchmark``'s worker processes, which import only the
package. Here it explores a bundled KTH floor through the construction path ``superex explore`` takes
(``build_explorer``, then the simulated episode), and its coverage is printed against the nearest frontier's.

    python examples/new_planner.py --steps 200
"""

import argparse

from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.planning.planners import reachable_frontiers, register_planner
from superex_deploy.onboard.types import Planner
from superex_deploy.pipeline import DEFAULT_PROFILE, PROFILES, build_explorer
from superex_deploy.evaluation.episodes import run_episode


@register_planner  # built by name from here on, in this process (a planner with settings: register_planner(cls, cfg))
class LargestFrontier(Planner):
    """The reachable frontier region with the most cells; ties to the nearer one (by travel cost), then the cell."""

    name = "largest"

    def choose_goal(self, ctx):
        frontiers, costs = reachable_frontiers(ctx)  # the regions of finite travel cost, and those costs
        if not frontiers:
            return None  # nothing left: the explorer reports no reachable frontier
        best = min(range(len(frontiers)), key=lambda i: (-frontiers[i].size, costs[i], frontiers[i].cell_rc))
        return frontiers[best].cell_rc



def explore(planner: str, floor: str, start: int, steps: int):
    """One episode as ``superex explore`` runs it (on the benchmarks' simulated clock); returns the result and the
    new goals, each with whether it is the goal cell of one of that step's frontier regions."""
    grid = load_map(floor)
    cfg = PROFILES[DEFAULT_PROFILE].episode_config()  # the default profile, the benchmarks' simulated clock
    explorer = build_explorer(MapFrame(grid.shape, grid.resolution_m), planner, "observed", cfg=cfg.explorer)
    goals = []

    def on_step(state):
        if state.goal is not None and (not goals or goals[-1][0] != state.goal):
            goals.append((state.goal, any(f.cell_rc == state.goal for f in state.frontiers)))

    result = run_episode(grid, start_poses(floor)[start], steps=steps, cfg=cfg, on_step=on_step, explorer=explorer)
    return result, goals


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="50052750", help="a bundled floor (superex_deploy.maps.list_maps)")
    parser.add_argument("--start", type=int, default=0, help="which of the floor's benchmark starts")
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args(argv)
    runs = {name: explore(name, args.map, args.start, args.steps) for name in ("largest", "nearest")}
    for step in sorted({min(s, args.steps) for s in (args.steps // 4, args.steps // 2, args.steps)}):
        line = "  ".join(f"{name} {result.coverage[min(step, result.steps) - 1]:6.1%}"
                         for name, (result, _) in runs.items())
        print(f"step {step:4d}  coverage  {line}")
    result, goals = runs["largest"]
    print(f"largest: {len(goals)} goals, {sum(on for _, on in goals)} of them a frontier region's goal cell")
    return {name: {"coverage": result.coverage, "goals": goals} for name, (result, goals) in runs.items()}


if __name__ == "__main__":
    main()
