"""``superex scan``: simulate one SPAD scan on a map and draw what the NLOS processing makes of it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from superex_deploy.commands.options import check_output_folder, non_negative_int, positive_int, resolve_start
from superex_deploy.spad_types import SpadConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--map", required=True, help="bundled map name (see list_maps) or an image / ROS YAML path")
    parser.add_argument("--start", type=non_negative_int, default=0,
                        help="index of the eval map's start pose (0-3); a map file or a train map needs --pose")
    parser.add_argument("--pose", type=int, nargs=2, metavar=("ROW", "COL"), help="robot cell instead of --start")
    parser.add_argument("--secondary", type=positive_int, default=SpadConfig.n_secondary,
                        help="secondary rays per wall hit (default: the sensor model's, %(default)s)")
    parser.add_argument("--noise", action="store_true", help="Poisson, ambient, dark counts and timing jitter")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="noise seed")
    parser.add_argument("--out", required=True, type=Path, help="output directory")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from superex_deploy.geometry import cell_centre, mark_rays
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.nlos import NlosConfig, process_scan
    from superex_deploy.evaluation.metrics import wall_iou, wall_iou_tolerant
    from superex_deploy.sim.spad import nlos_ground_truth
    from superex_deploy.render import save_scan_figure
    from superex_deploy.spad_types import SpadNoise
    from superex_deploy.sim.spad import simulate_scan

    check_output_folder(args.out)
    grid = load_map(args.map)
    pose = resolve_start(args.map, grid, args.start, args.pose, require_valid=False, seed=args.seed,
                         command="superex scan")
    cfg = SpadConfig(n_secondary=args.secondary, noise=SpadNoise(enabled=args.noise))
    scan = simulate_scan(grid, pose, cfg, rng=np.random.default_rng(args.seed) if args.noise else None)
    seen_free = np.zeros(grid.shape, bool)
    seen_wall = np.zeros(grid.shape, bool)
    mark_rays(grid.occupied, cell_centre(pose), scan.angles, cfg.range_m / grid.resolution_m, seen_free, seen_wall)
    result = process_scan(scan, NlosConfig(), known=seen_free | seen_wall, map_walls=seen_wall)
    truth = nlos_ground_truth(scan)
    hidden = ~(seen_free | seen_wall)
    args.out.mkdir(parents=True, exist_ok=True)
    figure = save_scan_figure(args.out / "scan.png", grid, pose, seen_free, seen_wall, scan, result, truth)
    summary = {
        "map": grid.name, "pose_rc": list(pose), "n_rays": cfg.n_rays, "n_secondary": cfg.n_secondary,
        "bin_path_m": cfg.bin_path_m, "noise": args.noise,
        "carved_cells": int(result.carved.sum()),
        "carved_beyond_line_of_sight": int((result.carved & ~seen_free).sum()),
        "carved_walls": int((result.carved & grid.occupied).sum()),
        # Scored like scripts/bench_spad.py: cells out of sight, filtered maps thresholded at 0.3.
        "bp_wall_iou_raw": wall_iou((result.bp > 0.3) & hidden, truth & hidden),
        "bp_wall_iou_laplacian": wall_iou((result.bp_filtered > 0.3) & hidden, truth & hidden),
        "bp_wall_iou_laplacian_within_1_cell": wall_iou_tolerant((result.bp_filtered > 0.3) & hidden,
                                                                 truth & hidden, 1),
    }
    (args.out / "scan.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    print(f"wrote {figure} and {args.out / 'scan.json'}")
    return 0
