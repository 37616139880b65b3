"""Benchmark the SPAD simulator and the NLOS processing on the eval maps.

Part 1 (all 40 eval scenarios, default configuration): median wall time of a plain 2500-ray line-of-sight scan
(``geometry.cast_rays``), of ``simulate_scan`` and of ``process_scan``, timed in the same run.

Part 2 (one start pose per eval map): run time against error as one parameter at a time moves away from the
default. Errors are measured against a dense reference sensor (more rays, a finer fan, finer bins):

* ``hist_l1``: L1 distance between the scan's late (three-bounce) photon distribution over round-trip path
  (summed over rays, rebinned to 0.2 m, normalised to unit sum: eq. (2) counts photons per secondary ray, so
  the totals scale with ``n_secondary`` and only the shape is comparable) and the reference's; in [0, 2].
* ``carved``: carved cells per scan (all sound; more is better) and ``beyond_los``: those out of sight.
* ``bp_iou``: wall IoU of the Laplacian-filtered back-projection thresholded at 0.3 against the NLOS ground
  truth (h2 cells) of the reference scan, both restricted to cells out of sight within 8 m of the robot.

Prints a table and writes JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np

from superex_deploy.geometry import cast_rays, cell_centre, mark_rays, ray_angles
from superex_deploy.maps import list_maps, load_map, start_poses
from superex_deploy.nlos import NlosConfig, nlos_ground_truth, process_scan, wall_iou
from superex_deploy.spad import SPEED_OF_LIGHT, SpadConfig, prepare_scene, simulate_scan

REBIN_M = 0.2
DEFAULT = SpadConfig()
REFERENCE = SpadConfig(n_rays=5000, n_secondary=512, bin_width_s=0.05 / SPEED_OF_LIGHT)


def _timed(function, *args, repeats=3, **kwargs):
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        result = function(*args, **kwargs)
        best = min(best, time.perf_counter() - start)
    return result, best


def _late_distribution(scan) -> np.ndarray:
    """Late photons per ray over round-trip path, rebinned to REBIN_M (direct bins removed)."""
    h = scan.histograms.astype(np.float64)
    first = np.argmax(h > 0, axis=1)
    h[np.arange(h.shape[0]), first] = 0.0
    total = h.sum(axis=0)
    edges = (np.arange(len(total)) * scan.bin_path_m / REBIN_M).astype(int)
    rebinned = np.bincount(edges, weights=total, minlength=int(4 * DEFAULT.range_m / REBIN_M) + 2)
    return rebinned / max(rebinned.sum(), 1e-300)


def _hidden_mask(grid, pose, window_m=8.0):
    seen_free = np.zeros(grid.shape, bool)
    seen_wall = np.zeros(grid.shape, bool)
    mark_rays(grid.occupied, cell_centre(pose), ray_angles(2500), 200.0, seen_free, seen_wall)
    rows, cols = np.ogrid[:grid.shape[0], :grid.shape[1]]
    half = window_m / grid.resolution_m
    near = (np.abs(rows - pose[0]) <= half) & (np.abs(cols - pose[1]) <= half)
    return seen_free | seen_wall, near & ~(seen_free | seen_wall)


def part_timing(scenarios):
    rows = []
    for grid, pose in scenarios:
        _, t_los = _timed(cast_rays, grid.occupied, cell_centre(pose), ray_angles(DEFAULT.n_rays),
                          DEFAULT.range_m / grid.resolution_m)
        scan, t_sim = _timed(simulate_scan, grid, pose, DEFAULT)
        known, _ = _hidden_mask(grid, pose)
        _, t_proc = _timed(process_scan, scan, NlosConfig(), known)
        _, t_serial = _timed(process_scan, scan, NlosConfig(bp_threads=1), known)
        rows.append({"map": grid.name, "pose": list(pose), "los_ms": t_los * 1e3, "spad_ms": t_sim * 1e3,
                     "nlos_ms": t_proc * 1e3, "nlos_one_thread_ms": t_serial * 1e3})
    return rows


def _variants():
    yield "default", DEFAULT, NlosConfig()
    for n_rays in (1000, 5000):
        yield f"n_rays={n_rays}", replace(DEFAULT, n_rays=n_rays), NlosConfig()
    for k in (16, 32, 128, 256):
        yield f"n_secondary={k}", replace(DEFAULT, n_secondary=k), NlosConfig()
    for path in (0.05, 0.2):
        yield f"bin_path={path}m", replace(DEFAULT, bin_width_s=path / SPEED_OF_LIGHT), NlosConfig()
    for window in (4.0, 12.0):
        yield f"bp_window={window:g}m", DEFAULT, NlosConfig(window_m=window)


def part_tradeoff(scenarios):
    references = {}
    for grid, pose in scenarios:
        scan = simulate_scan(grid, pose, REFERENCE)
        known, hidden = _hidden_mask(grid, pose)
        references[(grid.name, pose)] = (_late_distribution(scan), nlos_ground_truth(scan) & hidden, known, hidden)
    rows = []
    for name, spad_cfg, nlos_cfg in _variants():
        sim_ms, proc_ms, l1, carved, beyond, iou = [], [], [], [], [], []
        for grid, pose in scenarios:
            ref_dist, ref_truth, known, hidden = references[(grid.name, pose)]
            scan, t_sim = _timed(simulate_scan, grid, pose, spad_cfg, repeats=1)
            result, t_proc = _timed(process_scan, scan, nlos_cfg, known, repeats=1)
            dist = _late_distribution(scan)
            size = max(len(dist), len(ref_dist))
            dist, ref = np.pad(dist, (0, size - len(dist))), np.pad(ref_dist, (0, size - len(ref_dist)))
            sim_ms.append(t_sim * 1e3)
            proc_ms.append(t_proc * 1e3)
            l1.append(np.abs(dist - ref).sum())
            carved.append(int(result.carved.sum()))
            beyond.append(int((result.carved & hidden).sum()))
            iou.append(wall_iou((result.bp_filtered > 0.3) & hidden, ref_truth))
        rows.append({"variant": name, "spad_ms": float(np.median(sim_ms)), "nlos_ms": float(np.median(proc_ms)),
                     "hist_l1": float(np.median(l1)), "carved": float(np.median(carved)),
                     "beyond_los": float(np.median(beyond)), "bp_iou": float(np.median(iou))})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench_spad.json"))
    parser.add_argument("--maps", type=int, default=10, help="number of eval maps (<= 10)")
    parser.add_argument("--timing-only", action="store_true", help="run part 1 only")
    args = parser.parse_args()
    names = list_maps("eval")[: args.maps]
    grids = {name: load_map(name) for name in names}
    warm = grids[names[0]]
    start = time.perf_counter()
    prepare_scene(warm)
    simulate_scan(warm, start_poses(warm.name)[0], SpadConfig(n_rays=16, n_secondary=4))
    process_scan(simulate_scan(warm, start_poses(warm.name)[0]))
    warmup_s = time.perf_counter() - start
    scene_ms = []
    for grid in grids.values():
        fresh = load_map(grid.name)
        _, t = _timed(prepare_scene, fresh, repeats=1)
        scene_ms.append(t * 1e3)

    timing = part_timing([(grids[n], p) for n in names for p in start_poses(n)])
    los = np.median([r["los_ms"] for r in timing])
    spad = np.median([r["spad_ms"] for r in timing])
    nlos = np.median([r["nlos_ms"] for r in timing])
    nlos_serial = np.median([r["nlos_one_thread_ms"] for r in timing])
    threading_gain = np.median([r["nlos_one_thread_ms"] / r["nlos_ms"] for r in timing])
    print(f"\nPart 1: default configuration, {len(timing)} eval scenarios (median ms; NLOS on "
          f"{numba.get_num_threads()} numba threads, and on one)")
    print("| LOS scan (2500 rays) | SPAD scan | NLOS processing | NLOS, 1 thread | SPAD / LOS | NLOS / SPAD "
          "| 1 thread / threaded |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    print(f"| {los:.2f} | {spad:.2f} | {nlos:.2f} | {nlos_serial:.2f} | {spad / los:.1f}x | {nlos / spad:.2f}x "
          f"| {threading_gain:.2f}x |")
    print(f"one-off per map: normals {np.median(scene_ms):.1f} ms (median); first-call compile {warmup_s:.1f} s")

    tradeoff = [] if args.timing_only else part_tradeoff([(grids[n], start_poses(n)[0]) for n in names])
    if tradeoff:
        print(f"\nPart 2: run time vs error, one start pose on each of {len(names)} eval maps (medians)")
        print("| variant | SPAD ms | NLOS ms | hist L1 vs dense | carved cells | carved out of sight | BP wall IoU |")
        print("|---|---:|---:|---:|---:|---:|---:|")
    for r in tradeoff:
        print(f"| {r['variant']} | {r['spad_ms']:.1f} | {r['nlos_ms']:.1f} | {r['hist_l1']:.3f} | {r['carved']:.0f} | "
              f"{r['beyond_los']:.0f} | {r['bp_iou']:.3f} |")
    args.out.write_text(json.dumps({
        "reference": {"n_rays": REFERENCE.n_rays, "n_secondary": REFERENCE.n_secondary,
                      "bin_path_m": REFERENCE.bin_path_m},
        "timing": {"median_los_ms": los, "median_spad_ms": spad, "median_nlos_ms": nlos,
                   "median_nlos_one_thread_ms": nlos_serial, "median_threading_gain": threading_gain,
                   "numba_threads": numba.get_num_threads(),
                   "median_scene_prepare_ms": float(np.median(scene_ms)), "first_call_s": warmup_s,
                   "per_scenario": timing},
        "tradeoff": tradeoff}, indent=2))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
