"""Normals from the map: is carving still sound when each wall point's normal is fitted to the scan's hits and the
map's wall cells together (``NlosConfig.normals_from_map``), and what does it add per scan?

Scans from random L-corner scenes (:func:`superex_deploy.sim.corner_scenes.l_corner_scene`) and random poses of
the train floors, carved with the map given as:

- ``none``: the scan's hits alone (``normals_from_map=False``, the rule before);
- ``surface``: every true wall cell with a free neighbour (each face of every wall, as if the robot had seen the
  whole floor: the most a map can tell, corners, wall ends and both faces of thin walls included);
- ``surface, pose error``: the scan placed by a belief ``--sigma-xy`` / ``--sigma-yaw`` off and carved with that
  covariance (as tests/test_noisy_carving.py), and the map's walls moved by a second, independent rigid error
  of the same size (a map built from other beliefs); against ``none`` under the same scan error.

Per map: scans carving a true wall cell, the true wall cells carved, cells carved per scan, carve time (median,
the map kinds alternated per scan). The default SPAD sensor (256 secondary rays); 720 primaries.

``--episode-timing STEPS`` instead times what the change adds to a step of the shipped pipeline: the ``superex``
row (LaMa-BP, SPAD, the default profile) explores the largest eval floor (50015847, start 0, as the frame budget's
timing run), and at every step the frame is carved again with the explorer's map walls and without, alternated;
per step the difference and the ratio, and apart the time to read the walls (``Mapper.seen_wall``).

    PYTHONPATH=$PWD python scripts/bench_map_normals.py --scenes 2500 --train-poses 10 \\
        --out benchmarks/carving/map_normals.json
    PYTHONPATH=$PWD python scripts/bench_map_normals.py --episode-timing 500 --out benchmarks/carving/map_normals_timing.json
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import ndimage
from tqdm import tqdm

from superex_deploy.files import write_atomically
from superex_deploy.maps import list_maps, load_map
from superex_deploy.messages import MapFrame, Pose2D
from superex_deploy.onboard.nlos import NlosConfig, carve, estimate_los
from superex_deploy.onboard.nlos.processing import scan_from_frame
from superex_deploy.sim.corner_scenes import l_corner_scene
from superex_deploy.sim.spad import measured_frame, simulate_scan
from superex_deploy.spad_types import SpadConfig

CONFIG = SpadConfig(n_rays=720, n_secondary=256)
KINDS = ("none", "surface", "none, pose error", "surface, pose error")


def surface(grid) -> np.ndarray:
    """bool ``[H, W]``: wall cells with a free valid cell among their 8 neighbours (every face of every wall)."""
    free = grid.valid & ~grid.occupied
    return grid.occupied & ndimage.binary_dilation(free, structure=np.ones((3, 3), bool))


def moved(walls: np.ndarray, centre_yx, dy_cells: float, dx_cells: float, yaw: float) -> np.ndarray:
    """``walls`` (bool ``[H, W]``) turned by ``yaw`` about ``centre_yx`` and shifted by ``(dy, dx)`` cells: each wall
    cell's centre moved, the cell it lands in marked."""
    points = np.argwhere(walls) + 0.5 - np.asarray(centre_yx, float)
    c, s = np.cos(yaw), np.sin(yaw)
    turned = np.column_stack([c * points[:, 0] + s * points[:, 1], -s * points[:, 0] + c * points[:, 1]])
    cells = np.floor(turned + np.asarray(centre_yx, float) + (dy_cells, dx_cells)).astype(np.int64)
    inside = np.all((cells >= 0) & (cells < walls.shape), axis=1)
    out = np.zeros_like(walls)
    out[cells[inside, 0], cells[inside, 1]] = True
    return out


def _noisy_scan(grid, pose, rng, sigma_xy_m: float, sigma_yaw: float):
    """The scan simulated at the true cell, placed by a belief drawn at the sigmas (tests/test_noisy_carving.py)."""
    frame = MapFrame(grid.shape, grid.resolution_m)
    x, y = frame.centre_xy(pose)
    dx, dy = rng.normal(0.0, sigma_xy_m, 2)
    belief = Pose2D(x + dx, y + dy, rng.normal(0.0, sigma_yaw))
    return scan_from_frame(measured_frame(simulate_scan(grid, pose, CONFIG)), frame, belief, CONFIG)


def measure(grid, pose, walls: np.ndarray, totals: dict, name: str, rng, sigma_xy_m: float, sigma_yaw: float
            ) -> None:
    """Every map kind on one pose, into ``totals[kind]``."""
    exact = simulate_scan(grid, pose, CONFIG)
    noisy = _noisy_scan(grid, pose, rng, sigma_xy_m, sigma_yaw)
    e_xy = rng.normal(0.0, sigma_xy_m / grid.resolution_m, 2)
    noisy_walls = moved(walls, np.asarray(pose) + 0.5, e_xy[0], e_xy[1], rng.normal(0.0, sigma_yaw))
    runs = {"none": (exact, None, (0.0, 0.0)), "surface": (exact, walls, (0.0, 0.0)),
            "none, pose error": (noisy, None, (sigma_xy_m, sigma_yaw)),
            "surface, pose error": (noisy, noisy_walls, (sigma_xy_m, sigma_yaw))}
    estimates = {id(exact): estimate_los(exact), id(noisy): estimate_los(noisy)}
    order = KINDS if totals[KINDS[0]]["scans"] % 2 == 0 else KINDS[::-1]
    for kind in order:
        scan, map_walls, sigma = runs[kind]
        cfg = NlosConfig(normals_from_map=map_walls is not None)
        start = time.perf_counter()
        carved = carve(scan, estimates[id(scan)], cfg, sigma, map_walls)
        seconds = time.perf_counter() - start
        hit = int((carved & grid.occupied).sum())
        row = totals[kind]
        row["scans"] += 1
        row["scans carving a wall"] += hit > 0
        row["walls carved"] += hit
        row["cells carved"] += int(carved.sum())
        row["seconds"].append(seconds)
        if hit:
            row["examples"].append([name, list(pose), np.argwhere(carved & grid.occupied)[:3].tolist()])


def run(scenes: int, train_poses: int, sigma_xy_m: float, sigma_yaw: float) -> dict:
    out = {}
    rng = np.random.default_rng(11)
    for part in ("L corners", "train floors"):
        totals = {k: {"scans": 0, "scans carving a wall": 0, "walls carved": 0, "cells carved": 0, "seconds": [],
                      "examples": []} for k in KINDS}
        if part == "L corners":
            for seed in tqdm(range(scenes), desc="L corners"):
                grid, pose = l_corner_scene(seed)
                measure(grid, pose, surface(grid), totals, f"seed {seed}", rng, sigma_xy_m, sigma_yaw)
        else:
            poses = np.random.default_rng(7)
            for name in tqdm(list_maps("train"), desc="train floors"):
                grid = load_map(name)
                walls = surface(grid)
                free = np.argwhere(grid.valid & ~grid.occupied)
                for _ in range(train_poses):
                    pose = tuple(int(v) for v in free[poses.integers(len(free))])
                    measure(grid, pose, walls, totals, name, rng, sigma_xy_m, sigma_yaw)
        for base, kind in (("none", "surface"), ("none, pose error", "surface, pose error")):
            totals[kind]["time ratio vs " + base] = float(np.median(np.array(totals[kind]["seconds"])
                                                                    / np.array(totals[base]["seconds"])))
            totals[kind]["cells ratio vs " + base] = totals[kind]["cells carved"] / max(totals[base]["cells carved"], 1)
        for row in totals.values():
            row["seconds"] = float(np.median(row["seconds"]))
        out[part] = totals
    return out


def table(result: dict, scenes: int, train_poses: int, sigma_xy_m: float, sigma_yaw: float) -> str:
    lines = [f"Normals from the map: {scenes} L-corner scenes (seeds 0-{scenes - 1}), {train_poses} random poses on "
             f"each train floor; 720 primary rays, 256 secondary; pose error {100 * sigma_xy_m:g} cm / "
             f"{np.degrees(sigma_yaw):g} degree (scan and map drawn independently)", "",
             "| scenes | map | scans carving a true wall | true wall cells carved | cells carved / scan | vs no map | "
             "carve ms (median) | time ratio vs no map |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for part, totals in result.items():
        for kind, row in totals.items():
            base = "none, pose error" if "pose error" in kind else "none"
            cells = row.get("cells ratio vs " + base)
            ratio = row.get("time ratio vs " + base)
            lines.append(f"| {part} | {kind} | {row['scans carving a wall']} of {row['scans']} | {row['walls carved']} "
                         f"| {row['cells carved'] / max(row['scans'], 1):.0f} | "
                         f"{'-' if cells is None else f'{cells - 1:+.2%}'} | {1000 * row['seconds']:.1f} | "
                         f"{'-' if ratio is None else f'{ratio:.2f}'} |")
    for part, totals in result.items():
        for kind, row in totals.items():
            for example in row["examples"][:5]:
                lines.append(f"- {part}, {kind}: {example[0]} from {tuple(example[1])} carved true walls at "
                             f"{example[2]}")
    return "\n".join(lines) + "\n"


def episode_timing(steps: int) -> tuple[dict, str]:
    """Carve time with and without the map's walls along the shipped ``superex`` row's episode on the largest eval
    floor (see the module docstring)."""
    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import start_poses

    floor = "50015847"
    times = {"map": [], "none": [], "seen_wall": []}
    cells = {"map": 0, "none": 0}

    def on_observation(observation, command, explorer) -> None:
        processing = explorer.spad_processing
        if observation.spad is None:
            return
        scan = scan_from_frame(observation.spad, explorer.frame, observation.pose, processing.sensor)
        los = estimate_los(scan, processing.nlos_cfg)
        start = time.perf_counter()
        walls = explorer.mapper.seen_wall
        times["seen_wall"].append(time.perf_counter() - start)
        order = ("map", "none") if len(times["map"]) % 2 == 0 else ("none", "map")
        for kind in order:
            start = time.perf_counter()
            if kind == "map":
                carved = carve(scan, los, replace(processing.nlos_cfg, normals_from_map=True), map_walls=walls)
            else:
                carved = carve(scan, los, replace(processing.nlos_cfg, normals_from_map=False))
            times[kind].append(time.perf_counter() - start)
            cells[kind] += int(carved.sum())

    run_benchmark_episode(floor, start_poses(floor)[0], "superex", "lama_bp", spad=True, steps=steps,
                          on_observation=on_observation)
    with_map, without = np.array(times["map"]), np.array(times["none"])
    diff = 1000 * (with_map - without)
    out = {"floor": floor, "steps": steps, "frames": len(with_map),
           "ms": {k: {"median": float(1000 * np.median(v)), "mean": float(1000 * np.mean(v)),
                      "p99": float(1000 * np.percentile(v, 99))} for k, v in (("map", with_map), ("none", without))},
           "added_ms": {"median": float(np.median(diff)), "mean": float(diff.mean()),
                        "p99": float(np.percentile(diff, 99))},
           "ratio_median": float(np.median(with_map / without)), "cells": cells,
           "seen_wall_ms": {"median": float(1000 * np.median(times["seen_wall"])),
                            "p99": float(1000 * np.percentile(times["seen_wall"], 99))}}
    m = out["ms"]
    text = (f"Carve time along the shipped superex row's episode on {floor} (start 0, {steps} steps, "
            f"{out['frames']} frames, alternated per frame):\n\n"
            "| carving | median ms | mean ms | p99 ms | cells carved (sum) |\n|---|---:|---:|---:|---:|\n"
            f"| scan's hits alone | {m['none']['median']:.2f} | {m['none']['mean']:.2f} | {m['none']['p99']:.2f} | "
            f"{cells['none']} |\n"
            f"| with the map's walls | {m['map']['median']:.2f} | {m['map']['mean']:.2f} | "
            f"{m['map']['p99']:.2f} | {cells['map']} |\n\n"
            f"Added per frame: median {out['added_ms']['median']:.2f} ms, mean {out['added_ms']['mean']:.2f} ms, "
            f"p99 {out['added_ms']['p99']:.2f} ms; ratio (median over frames) {out['ratio_median']:.2f}; the map's "
            f"walls (Mapper.seen_wall, read after the step) median {out['seen_wall_ms']['median']:.3f} ms, p99 "
            f"{out['seen_wall_ms']['p99']:.3f} ms\n")
    return out, text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=2500)
    parser.add_argument("--train-poses", type=int, default=10, help="random poses per train floor")
    parser.add_argument("--sigma-xy", type=float, default=0.05, help="pose error, metres")
    parser.add_argument("--sigma-yaw", type=float, default=1.0, help="pose error, degrees")
    parser.add_argument("--out", type=Path, default=None, help="JSON path (the table beside it as .md)")
    parser.add_argument("--episode-timing", type=int, default=0, metavar="STEPS",
                        help="instead: the carve time with and without the map along the shipped row's episode")
    args = parser.parse_args()
    if args.episode_timing:
        payload, text = episode_timing(args.episode_timing)
        print(text)
        if args.out is not None:
            write_atomically(args.out, json.dumps(payload, indent=1))
            write_atomically(args.out.with_suffix(".md"), text)
        return
    sigma_yaw = float(np.radians(args.sigma_yaw))
    result = run(args.scenes, args.train_poses, args.sigma_xy, sigma_yaw)
    text = table(result, args.scenes, args.train_poses, args.sigma_xy, sigma_yaw)
    print(text)
    if args.out is not None:
        payload = {"scenes": args.scenes, "train_poses": args.train_poses, "sigma_xy_m": args.sigma_xy,
                   "sigma_yaw_deg": args.sigma_yaw, **result}
        write_atomically(args.out, json.dumps(payload, indent=1))
        write_atomically(args.out.with_suffix(".md"), text)


if __name__ == "__main__":
    main()
