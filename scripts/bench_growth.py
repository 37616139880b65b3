"""What a step costs on a map that grows, against fixed frames of growing size (the robot API's step cost followed
the frame, not the explored area).

One drive per train floor (``nearest`` on the observed map, on the floor's own frame, in the simulator) is recorded;
its observations are then fed open-loop to explorers whose grids differ and nothing else: the floor's own frame, the
floor padded to ``--cells`` cells (the floor in the middle), and a growing map started on a 10 m frame at the start.
Contenders alternate within each round; the table gives the median step time of each, its ratio to the floor's own
frame (paired per step), and the cells each grid ended with. Times are this machine's: read the ratios.

    python scripts/bench_growth.py --floors 3 --steps 150 --rounds 3 --out benchmarks/growth
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from superex_deploy.files import write_atomically
from superex_deploy.maps import list_maps, load_map, random_start
from superex_deploy.messages import MapFrame
from superex_deploy.onboard import Explorer, ExplorerConfig
from superex_deploy.onboard.mapping.growth import MapGrowth
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.exploration import ExplorationConfig


def drive(grid, steps: int, seed: int):
    """One recorded drive: ``nearest`` on the observed map from a seeded start, the floor's own frame and its
    observations."""
    observations = []
    run_episode(grid, random_start(grid, np.random.default_rng(seed), 0.5), make_planner("nearest"),
                ObservedAsPrediction(), steps=steps, cfg=ExplorationConfig(iou_every=0),
                on_observation=lambda observation, command, explorer: observations.append(observation))
    return MapFrame(grid.shape, grid.resolution_m), observations


def padded(frame: MapFrame, cells: int) -> MapFrame:
    side = max(int(np.ceil(np.sqrt(cells))), *frame.shape)
    rows, cols = side, side
    top, left = (rows - frame.shape[0]) // 2, (cols - frame.shape[1]) // 2
    res = frame.resolution_m
    bottom = rows - frame.shape[0] - top
    return MapFrame((rows, cols), res, (frame.origin_xy[0] - left * res, frame.origin_xy[1] - bottom * res))


def step_times(frame: MapFrame, observations, growth=None) -> tuple[list[float], tuple[int, int]]:
    explorer = Explorer(frame, make_planner("nearest"), ObservedAsPrediction(), cfg=ExplorerConfig(growth=growth))
    times = []
    for observation in observations:
        clock = time.perf_counter()
        explorer.step(observation)
        times.append(1e3 * (time.perf_counter() - clock))
    return times, explorer.frame.shape


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--floors", type=int, default=3)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cells", type=int, nargs="+", default=[4_000_000, 25_000_000])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    names = list_maps("train")[:: max(1, len(list_maps("train")) // args.floors)][:args.floors]
    contenders = ["floor"] + [f"padded {cells / 1e6:g} M" for cells in args.cells] + ["growing from 10 m"]
    times = {name: [] for name in contenders}
    shapes = {name: [] for name in contenders}
    for index, name in enumerate(names):
        frame, observations = drive(load_map(name), args.steps, index)
        start = observations[0].pose
        setups = {"floor": (frame, None)}
        setups.update({f"padded {cells / 1e6:g} M": (padded(frame, cells), None) for cells in args.cells})
        setups["growing from 10 m"] = (MapFrame.around(start.x, start.y, frame.resolution_m, 10.0), MapGrowth())
        step_times(frame, observations[:3])  # compile
        per_round = {contender: [] for contender in contenders}
        for round_index in range(args.rounds):
            order = contenders if round_index % 2 == 0 else contenders[::-1]
            for contender in order:
                grid_frame, growth = setups[contender]
                measured, shape = step_times(grid_frame, observations, growth)
                per_round[contender].append(measured)
                if round_index == 0:
                    shapes[contender].append(int(shape[0] * shape[1]))
            print(f"{name}: round {round_index + 1}/{args.rounds}", flush=True)
        for contender in contenders:
            times[contender].append(np.median(np.asarray(per_round[contender]), axis=0))  # per step, over rounds
    floor = np.concatenate(times["floor"])
    rows = []
    for contender in contenders:
        mine = np.concatenate(times[contender])
        ratio = mine / floor
        rows.append({"grid": contender, "median_step_ms": float(np.median(mine)), "p99_step_ms":
                     float(np.percentile(mine, 99)), "median_ratio_to_floor": float(np.median(ratio)),
                     "cells_mean": float(np.mean(shapes[contender]))})
    report = {"floors": names, "steps": [len(t) for t in times["floor"]], "rounds": args.rounds, "rows": rows,
              "machine": "this project's 2-core sandbox (no GPU)"}
    write_atomically(args.out / "growth.json", json.dumps(report, indent=2) + "\n")
    lines = ["| grid | cells (mean over floors) | median step (ms) | p99 step (ms) | median ratio to the floor's frame |",
             "|---|---:|---:|---:|---:|"]
    lines += [f"| {r['grid']} | {r['cells_mean']:,.0f} | {r['median_step_ms']:.2f} | {r['p99_step_ms']:.2f} | "
              f"{r['median_ratio_to_floor']:.2f} |" for r in rows]
    table = "\n".join(lines) + "\n"
    write_atomically(args.out / "growth.md", f"Train floors {', '.join(names)}; {args.rounds} rounds, contenders "
                     f"alternated; nearest planner, observed map; open-loop on one recorded drive per floor.\n\n"
                     + table)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
