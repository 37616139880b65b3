"""Benchmark the SPAD simulator and the NLOS processing on the eval maps.

Part 1 (all 40 eval scenarios, default configuration, single scans): median wall time of a plain 2500-ray
line-of-sight scan (``geometry.cast_rays``), of ``simulate_scan`` cold (the grid's fan cache emptied first, so
every secondary fan is traced; on numba's threads and on one) and with every fan already cached, and of
``process_scan`` (on numba's threads and on one), timed in the same run; the cells a 2500-ray LOS scan from the
pose sees are the known cells.

Part 2 (one episode per eval map from its first start pose, nearest-frontier planner): the same three stages timed
at every step of an exploration episode, as ``superex explore --spad`` runs them: the fan cache warms as the
robot moves (it starts empty), the known cells are the episode's observed map. Medians over steps, then over maps.

Part 3 (one start pose per eval map): run time against error as one parameter at a time moves away from the
default (cold scans). Errors are measured against a dense reference sensor (more rays, a finer fan, finer bins):

* ``hist_l1``: L1 distance between the scan's late (three-bounce) photon distribution over round-trip path
  (summed over rays, rebinned to 0.2 m, normalised to unit sum: eq. (2) counts photons per secondary ray, so
  the totals scale with ``n_secondary`` and only the shape is comparable) and the reference's; in [0, 2].
* ``carved``: carved cells per scan (all sound; more is better) and ``beyond_los``: those out of sight.
* ``bp_iou``: wall IoU of the Laplacian-filtered back-projection thresholded at 0.3 against the NLOS ground
  truth (h2 cells) of the reference scan, both restricted to cells out of sight within 8 m of the robot.

Prints tables and writes JSON (``--out``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np

from superex_deploy.evaluation import run_benchmark_episode, write_json
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import UNKNOWN
from superex_deploy.geometry import cast_rays, cell_centre, mark_rays, ray_angles
from superex_deploy.maps import list_maps, load_map, start_poses
from superex_deploy.pipeline import PROFILES
from superex_deploy.onboard.nlos import NlosConfig, process_scan
from superex_deploy.evaluation.metrics import wall_iou
from superex_deploy.sim.spad import nlos_ground_truth
from superex_deploy.spad_types import SPEED_OF_LIGHT, SpadConfig
from superex_deploy.sim.spad import prepare_scene, simulate_scan

REBIN_M = 0.2
DEFAULT = SpadConfig()
REFERENCE = SpadConfig(n_rays=5000, n_secondary=512, bin_width_s=0.05 / SPEED_OF_LIGHT)


def _timed(function, *args, repeats=3, before=None, **kwargs):
    """(result, best wall time in seconds) over ``repeats`` calls; ``before()`` runs untimed before each."""
    best = np.inf
    for _ in range(repeats):
        if before is not None:
            before()
        start = time.perf_counter()
        result = function(*args, **kwargs)
        best = min(best, time.perf_counter() - start)
    return result, best


def _one_thread(function):
    """``function`` run with numba on one thread."""
    def call(*args, **kwargs):
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            return function(*args, **kwargs)
        finally:
            numba.set_num_threads(threads)
    return call


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


def part_single_scans(scenarios):
    rows = []
    for grid, pose in scenarios:
        scene = prepare_scene(grid)
        _, t_los = _timed(cast_rays, grid.occupied, cell_centre(pose), ray_angles(DEFAULT.n_rays),
                          DEFAULT.range_m / grid.resolution_m)
        _, t_cold = _timed(simulate_scan, grid, pose, DEFAULT, before=scene.clear_fan_caches)
        _, t_cold_serial = _timed(_one_thread(simulate_scan), grid, pose, DEFAULT, before=scene.clear_fan_caches)
        scan, t_cached = _timed(simulate_scan, grid, pose, DEFAULT)
        known, _ = _hidden_mask(grid, pose)
        _, t_proc = _timed(process_scan, scan, NlosConfig(), known)
        _, t_serial = _timed(_one_thread(process_scan), scan, NlosConfig(), known)
        rows.append({"map": grid.name, "pose": list(pose), "los_ms": t_los * 1e3, "spad_cold_ms": t_cold * 1e3,
                     "spad_cold_one_thread_ms": t_cold_serial * 1e3, "spad_cached_ms": t_cached * 1e3,
                     "nlos_ms": t_proc * 1e3, "nlos_one_thread_ms": t_serial * 1e3,
                     "fans": int(scan.truth.fan_rows.shape[0]), "nonzero_bins": int(scan.sparse.bins.shape[0])})
    return rows


def part_episodes(grids, steps):
    rows = []
    for grid in grids:
        scene = prepare_scene(grid)
        scene.clear_fan_caches()
        per_step = []

        def on_step(state):
            origin = cell_centre(state.pose)
            _, t_los = _timed(cast_rays, grid.occupied, origin, ray_angles(DEFAULT.n_rays),
                              DEFAULT.range_m / grid.resolution_m, repeats=1)
            scan, t_spad = _timed(simulate_scan, grid, state.pose, DEFAULT, repeats=1)
            _, t_proc = _timed(process_scan, scan, NlosConfig(), state.observed != UNKNOWN, repeats=1)
            per_step.append((t_los * 1e3, t_spad * 1e3, t_proc * 1e3))

        run_benchmark_episode(grid, start_poses(grid.name)[0], "nearest", ObservedAsPrediction(), steps=steps,
                              on_step=on_step, profile=PROFILES["full"])
        cache = scene.fan_cache(DEFAULT.n_secondary, DEFAULT.range_m / grid.resolution_m)
        los, spad, proc = np.median(np.array(per_step), axis=0)
        rows.append({"map": grid.name, "steps": len(per_step), "los_ms": los, "spad_ms": spad, "nlos_ms": proc,
                     "first_spad_ms": per_step[0][1], "fans_traced": cache.traced, "fans_reused": cache.reused})
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
            scan, t_sim = _timed(simulate_scan, grid, pose, spad_cfg, repeats=1,
                                 before=prepare_scene(grid).clear_fan_caches)
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
    parser.add_argument("--out", type=Path, default=Path("benchmarks/spad/bench_spad.json"))
    parser.add_argument("--maps", type=int, default=10, help="number of eval maps (<= 10)")
    parser.add_argument("--steps", type=int, default=200, help="steps of each part-2 episode")
    parser.add_argument("--timing-only", action="store_true", help="run parts 1 and 2 only")
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

    single = part_single_scans([(grids[n], p) for n in names for p in start_poses(n)])
    med = {key: float(np.median([r[key] for r in single])) for key in single[0] if key.endswith("_ms")}
    print(f"\nPart 1: single scans, default configuration, {len(single)} eval scenarios (median ms; "
          f"{numba.get_num_threads()} numba threads, and one)")
    print("| LOS scan (2500 rays) | SPAD scan, cold | cold, 1 thread | SPAD scan, fans cached | NLOS processing "
          "| NLOS, 1 thread |")
    print("|---:|---:|---:|---:|---:|---:|")
    print(f"| {med['los_ms']:.2f} | {med['spad_cold_ms']:.2f} | {med['spad_cold_one_thread_ms']:.2f} | "
          f"{med['spad_cached_ms']:.2f} | {med['nlos_ms']:.2f} | {med['nlos_one_thread_ms']:.2f} |")
    ratios = {
        "cold_spad_over_los": float(np.median([r["spad_cold_ms"] / r["los_ms"] for r in single])),
        "cold_one_thread_spad_over_los": float(np.median([r["spad_cold_one_thread_ms"] / r["los_ms"]
                                                          for r in single])),
        "cached_spad_over_los": float(np.median([r["spad_cached_ms"] / r["los_ms"] for r in single])),
        "nlos_over_cold_spad": float(np.median([r["nlos_ms"] / r["spad_cold_ms"] for r in single])),
        "nlos_over_cached_spad": float(np.median([r["nlos_ms"] / r["spad_cached_ms"] for r in single])),
    }
    print("ratios (median over scenarios): " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
    print(f"one-off per map: normals {np.median(scene_ms):.1f} ms (median); first-call compile {warmup_s:.1f} s")

    episodes = part_episodes(list(grids.values()), args.steps)
    ep = {key: float(np.median([r[key] for r in episodes])) for key in ("los_ms", "spad_ms", "nlos_ms")}
    traced = sum(r["fans_traced"] for r in episodes)
    reused = sum(r["fans_reused"] for r in episodes)
    print(f"\nPart 2: every step of a {args.steps}-step episode on each of {len(episodes)} eval maps (median over "
          f"steps, then maps; ms)")
    print("| LOS scan | SPAD scan | NLOS processing | SPAD / LOS | NLOS / SPAD | fans traced / fans used |")
    print("|---:|---:|---:|---:|---:|---:|")
    print(f"| {ep['los_ms']:.2f} | {ep['spad_ms']:.2f} | {ep['nlos_ms']:.2f} | {ep['spad_ms'] / ep['los_ms']:.1f}x | "
          f"{ep['nlos_ms'] / ep['spad_ms']:.2f}x | {traced / max(traced + reused, 1):.1%} |")
    for r in episodes:
        print(f"  {r['map']}: LOS {r['los_ms']:.2f}, SPAD {r['spad_ms']:.2f} (first step {r['first_spad_ms']:.2f}), "
              f"NLOS {r['nlos_ms']:.2f} ms over {r['steps']} steps")

    tradeoff = [] if args.timing_only else part_tradeoff([(grids[n], start_poses(n)[0]) for n in names])
    if tradeoff:
        print(f"\nPart 3: run time (cold scans) vs error, one start pose on each of {len(names)} eval maps (medians)")
        print("| variant | SPAD ms | NLOS ms | hist L1 vs dense | carved cells | carved out of sight | BP wall IoU |")
        print("|---|---:|---:|---:|---:|---:|---:|")
    for r in tradeoff:
        print(f"| {r['variant']} | {r['spad_ms']:.1f} | {r['nlos_ms']:.1f} | {r['hist_l1']:.3f} | {r['carved']:.0f} | "
              f"{r['beyond_los']:.0f} | {r['bp_iou']:.3f} |")
    write_json(args.out, {
        "reference": {"n_rays": REFERENCE.n_rays, "n_secondary": REFERENCE.n_secondary,
                      "bin_path_m": REFERENCE.bin_path_m},
        "single_scans": {**{f"median_{k}": v for k, v in med.items()}, "median_ratios": ratios,
                         "numba_threads": numba.get_num_threads(),
                         "median_scene_prepare_ms": float(np.median(scene_ms)), "first_call_s": warmup_s,
                         "per_scenario": single},
        "episodes": {"steps": args.steps, **{f"median_{k}": v for k, v in ep.items()},
                     "fans_traced": traced, "fans_reused": reused, "per_map": episodes},
        "tradeoff": tradeoff}, indent=2)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
