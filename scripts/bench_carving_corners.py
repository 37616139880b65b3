"""Carving at wall corners and steps: the sector narrowed where the wall steps (today's rule) against the sector of
0.2 (+-(90 - sector_margin_deg) about every fitted normal), on random L-corner scenes
(:func:`superex_deploy.sim.corner_scenes.l_corner_scene`) and random poses of the train floors.

Per rule: scenes (poses) that carved a true wall cell, the true wall cells carved, the cells carved; the carving
lost to the narrowing; the time of ``carve`` under each rule (alternated per scene, median ratio). Also the angle
between each carving wall cell's fitted normal and the simulator's normal of the rays that hit it (what the sector
margin must cover). The default SPAD sensor: 256 secondary rays; 720 primaries.

    PYTHONPATH=$PWD python scripts/bench_carving_corners.py --scenes 2500 --train-poses 10 \\
        --out benchmarks/carving/corners.json
"""

from __future__ import annotations

import argparse
import json
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from tqdm import tqdm

from superex_deploy.maps import list_maps, load_map
from superex_deploy.onboard.nlos import NlosConfig, carve, carving, estimate_los
from superex_deploy.sim.corner_scenes import l_corner_scene
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.spad_types import SpadConfig

CONFIG = SpadConfig(n_rays=720, n_secondary=256)
RULES = ("steps", "sector 0.2")


@contextmanager
def old_sector():
    """Carve with the sector of 0.2 inside the block (the module's rule swapped, then put back)."""
    rule = carving.sector_cos_limits

    def constant(wall_cells, wall_normal, cfg, yaw_margin_rad=0.0, steps=None):
        return np.full(len(wall_cells), np.cos(np.deg2rad(90.0 - cfg.sector_margin_deg)))

    carving.sector_cos_limits = constant
    try:
        yield
    finally:
        carving.sector_cos_limits = rule


def measure(grid, pose, totals: dict, deviations: list, name: str) -> None:
    """Both rules on one scan, into ``totals[rule]``; the normal deviations of the carving wall cells."""
    scan = simulate_scan(grid, pose, CONFIG)
    los = estimate_los(scan)
    order = RULES if totals[RULES[0]]["scans"] % 2 == 0 else RULES[::-1]  # alternated: neither runs warm always
    for rule in order:
        start = time.perf_counter()
        if rule == "steps":
            carved = carve(scan, los)
        else:
            with old_sector():
                carved = carve(scan, los)
        seconds = time.perf_counter() - start
        walls = int((carved & grid.occupied).sum())
        row = totals[rule]
        row["scans"] += 1
        row["scans carving a wall"] += walls > 0
        row["walls carved"] += walls
        row["cells carved"] += int(carved.sum())
        row["seconds"].append(seconds)
        if walls:
            row["examples"].append([name, list(pose), np.argwhere(carved & grid.occupied)[:3].tolist()])
    truth = scan.truth
    hit = los.ray_wall >= 0
    reliable = hit.copy()
    reliable[hit] = los.normal_reliable[los.ray_wall[hit]]
    reliable &= np.any(truth.normal1 != 0, axis=1)
    fitted = los.wall_normal[los.ray_wall[reliable]]
    cosine = np.abs(np.sum(fitted * truth.normal1[reliable], axis=1))
    deviations.extend(np.degrees(np.arccos(np.clip(cosine, 0.0, 1.0))).tolist())


def run(scenes: int, train_poses: int) -> dict:
    out = {}
    for part in ("L corners", "train floors"):
        totals = {rule: {"scans": 0, "scans carving a wall": 0, "walls carved": 0, "cells carved": 0,
                         "seconds": [], "examples": []} for rule in RULES}
        deviations: list = []
        if part == "L corners":
            for seed in tqdm(range(scenes), desc="L corners"):
                grid, pose = l_corner_scene(seed)
                measure(grid, pose, totals, deviations, f"seed {seed}")
        else:
            rng = np.random.default_rng(7)
            for name in tqdm(list_maps("train"), desc="train floors"):
                grid = load_map(name)
                free = np.argwhere(grid.valid & ~grid.occupied)
                for _ in range(train_poses):
                    pose = tuple(int(v) for v in free[rng.integers(len(free))])
                    measure(grid, pose, totals, deviations, name)
        ratio = np.median(np.array(totals["steps"]["seconds"]) / np.array(totals["sector 0.2"]["seconds"]))
        for row in totals.values():
            row["seconds"] = float(np.median(row["seconds"]))
        deviation = np.array(deviations)
        out[part] = {"rules": totals, "carve time ratio (median)": float(ratio),
                     "carving lost": 1.0 - totals["steps"]["cells carved"] / max(totals["sector 0.2"]["cells carved"], 1),
                     "normal deviation deg": {"rays": len(deviation), "median": float(np.median(deviation)),
                                              "p99": float(np.percentile(deviation, 99)),
                                              "p99.9": float(np.percentile(deviation, 99.9)),
                                              "max": float(deviation.max()),
                                              "over 20": int((deviation > 20).sum())}}
    return out


def table(result: dict, scenes: int, train_poses: int) -> str:
    lines = [f"Carving at corners and steps: {scenes} L-corner scenes (seeds 0-{scenes - 1}), {train_poses} random "
             f"poses on each train floor; 720 primary rays, 256 secondary", "",
             "| scenes | rule | scans carving a true wall | true wall cells carved | cells carved / scan | carve ms (median) |",
             "|---|---|---:|---:|---:|---:|"]
    for part, entry in result.items():
        for rule, row in entry["rules"].items():
            lines.append(f"| {part} | {rule} | {row['scans carving a wall']} of {row['scans']} | {row['walls carved']} | "
                         f"{row['cells carved'] / max(row['scans'], 1):.0f} | {1000 * row['seconds']:.1f} |")
    lines.append("")
    for part, entry in result.items():
        d = entry["normal deviation deg"]
        lines.append(f"- {part}: the step rule carves {100 * entry['carving lost']:.2f} % fewer cells; carve time "
                     f"ratio steps / sector 0.2 {entry['carve time ratio (median)']:.2f} (median over scans); fitted "
                     f"vs simulator's normal of the rays on carving-trusted cells ({d['rays']}): median "
                     f"{d['median']:.1f}, p99 {d['p99']:.1f}, p99.9 {d['p99.9']:.1f}, max {d['max']:.1f} degrees, "
                     f"{d['over 20']} over 20")
    for part, entry in result.items():
        for rule, row in entry["rules"].items():
            for example in row["examples"][:5]:
                lines.append(f"- {part}, {rule}: {example[0]} from {tuple(example[1])} carved true walls at "
                             f"{example[2]}")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=2500)
    parser.add_argument("--train-poses", type=int, default=10, help="random poses per train floor")
    parser.add_argument("--out", type=Path, default=None, help="JSON path (the table beside it as .md)")
    args = parser.parse_args()
    result = run(args.scenes, args.train_poses)
    text = table(result, args.scenes, args.train_poses)
    print(text)
    if args.out is not None:
        args.out.write_text(json.dumps({"scenes": args.scenes, "train_poses": args.train_poses, **result}, indent=1))
        args.out.with_suffix(".md").write_text(text)


if __name__ == "__main__":
    main()
