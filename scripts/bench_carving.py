"""Carving nearer its bound: what each carving option adds to coverage on fixed MapEx
trajectories, and whether it stays sound there.

Each scenario runs MapEx on the observed map (no SPAD: the trajectory does not depend on any variant). At every
step the script simulates a SPAD scan at the robot cell for each secondary-fan density a variant asks for,
carves with each variant's :class:`NlosConfig`, and counts the coverage of the line-of-sight map (the explorer's
own) united with everything that variant carved so far. The first-half AUC is the mean coverage over steps
1..``--steps`` (run ``--steps`` = half the episode length). Besides the variants, ``ideal`` carves, for every
wall cell hit, the half-disc about the simulator's own normal out to the nearest wall its densest fan met (the
bound a continuous noise-free sensor's first late photon gives; not sound, a reference). Per variant: the
paired coverage gain over line of sight, the true wall cells ever carved (soundness on the episodes), and per
fan density the simulator's time per scan and its fan cache's counts.

    PYTHONPATH=$PWD python scripts/bench_carving.py --split train --scenarios 6 --steps 300 \
        --out benchmarks/carving/train.json
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import (bootstrap_interval, coverage_at, coverage_auc, eval_scenarios, markdown_table,
                                       run_benchmark_episode, train_scenarios)
from superex_deploy.evaluation.reports import pyplot, save_figure
from superex_deploy.files import write_atomically
from superex_deploy.maps import list_maps, load_map
from superex_deploy.onboard.nlos import NlosConfig, carve, estimate_los
from superex_deploy.onboard.nlos.carving import carve_sectors
from superex_deploy.parallel import process_pool
from superex_deploy.maps import coverage as coverage_of
from superex_deploy.spad_types import SpadConfig

VARIANTS = {
    "today": (64, {}),
    "fan128": (128, {}),
    "fan256": (256, {}),
    "strip0.5": (64, {"wall_strip_m": 0.05}),
    "sector20": (64, {"sector_margin_deg": 20.0}),
    "sector10": (64, {"sector_margin_deg": 10.0}),
    "fan256_strip0.5": (256, {"wall_strip_m": 0.05}),
    "fan256_sector20": (256, {"sector_margin_deg": 20.0}),
    "fan256_sector10": (256, {"sector_margin_deg": 10.0}),
    "fan256_sector10_strip0.5": (256, {"sector_margin_deg": 10.0, "wall_strip_m": 0.05}),
    "sector15": (64, {"sector_margin_deg": 15.0}),
    "fan256_sector15": (256, {"sector_margin_deg": 15.0}),
    "fan512": (512, {}),
    "fan512_sector20": (512, {"sector_margin_deg": 20.0}),
    "ends45": (64, {"_ends_margin_deg": 45.0}),
    "fan256_sector20_ends45": (256, {"sector_margin_deg": 20.0, "_ends_margin_deg": 45.0}),
    "fan256_sector20_ends30": (256, {"sector_margin_deg": 20.0, "_ends_margin_deg": 30.0}),
    "truth_normals": (64, {"_truth_normals": True}),
    "fan256_sector20_truth_normals": (256, {"sector_margin_deg": 20.0, "_truth_normals": True}),
    "fan256_scan_normals": (256, {"normals_from_map": False}),
    "fan256_map_normals": (256, {"normals_from_map": True}),
}
"""Name -> (SpadConfig.n_secondary, NlosConfig overrides); the carve-radius cap follows the fan density.
``_truth_normals``: every wall cell carves about the simulator's own normal (corners and wall ends included), the
most that carving at corners and wall ends could add with these margins (an upper bound, not a sound rule).
``_ends_margin_deg``: wall ends are carved too: a cell whose hits lie on one straight line (the same residual,
gap and variance tests) but run on to one side only, its sector narrowed by this many degrees more than the
others (a corner's or wall end's own normal may turn by up to 45 degrees, either way, from its face's)."""


def nlos_config(variant: str) -> NlosConfig:
    return NlosConfig(**{k: v for k, v in VARIANTS[variant][1].items() if not k.startswith("_")})


def variant_carving(variant: str, scan, los, cfg: NlosConfig, map_walls=None) -> np.ndarray:
    """bool ``[H, W]`` the variant's carving of one scan (``map_walls``: the explorer's wall cells, which support
    the normals where ``cfg.normals_from_map``)."""
    ends_margin = VARIANTS[variant][1].get("_ends_margin_deg")
    if ends_margin is not None:
        return carve(scan, los, cfg, map_walls=map_walls) | _wall_end_carving(scan, los, cfg, ends_margin)
    if not VARIANTS[variant][1].get("_truth_normals"):
        return carve(scan, los, cfg, map_walls=map_walls)
    truth = scan.truth
    rays = np.flatnonzero((los.ray_wall >= 0) & (truth.ray_fan >= 0))
    cells, first = np.unique(los.ray_wall[rays], return_index=True)
    normals = los.wall_normal.copy()
    reliable = np.zeros(len(los.wall_cells), bool)
    normals[cells] = truth.normal1[rays[first]]
    reliable[cells] = True
    half = 0.5 / np.maximum(np.abs(normals).max(axis=1), 1e-12)
    apex = los.wall_cells + 0.5 + half[:, None] * normals
    return carve(scan, replace(los, wall_normal=normals, normal_reliable=reliable, wall_apex=apex), cfg)


def scenarios(split: str, n: int) -> list[tuple[str, tuple[int, int]]]:
    """Eval: the benchmark's start poses, one per floor first (then the second of each, ...); train: the floors
    of at least 40,000 valid cells, evenly spaced, one start each drawn from a generator seeded with the name."""
    if split == "eval":
        return [(s.map_name, s.start_rc) for s in eval_scenarios("start")][:n]
    return train_scenarios(n, 1, 40000)


def ideal_carving(scan) -> np.ndarray:
    """bool ``[H, W]``: for every fan of the scan the half-disc about the simulator's normal from its origin X1
    out to the nearest secondary hit (the range where none), no margins."""
    truth = scan.truth
    rays = np.flatnonzero(truth.ray_fan >= 0)
    fans, first = np.unique(truth.ray_fan[rays], return_index=True)
    normals = truth.normal1[rays[first]]
    cells = truth.h1_rc[rays[first]].astype(np.float64) + 0.5
    half = 0.5 / np.maximum(np.abs(normals[:, 0]), np.abs(normals[:, 1]))
    apex = cells + half[:, None] * normals
    d2 = truth.fan_d2_m[fans]
    nearest = np.where(np.isnan(d2), scan.config.range_m, d2).min(axis=1) / scan.resolution_m
    out = np.zeros(scan.grid_shape, bool)
    carve_sectors(apex, np.ascontiguousarray(normals), nearest, np.zeros(len(fans)), np.zeros(len(fans)), 0, 0, out, 1)
    return out


def _wall_end_carving(scan, los, cfg: NlosConfig, extra_margin_deg: float) -> np.ndarray:
    """bool ``[H, W]`` carved from the wall-end cells only (see ``_ends_margin_deg`` in :data:`VARIANTS`)."""
    from superex_deploy.onboard.nlos.normals import face_the_robot, hit_normals

    n = len(los.wall_cells)
    if n == 0:
        return np.zeros(scan.grid_shape, bool)
    points = los.wall_cells + 0.5
    normals, straight, apex = np.zeros((n, 2)), np.zeros(n, bool), np.empty((n, 2))
    # Interior 0: every straight, contiguous run of hits, its ends included.
    cells = cfg.in_cells(scan.resolution_m)
    hit_normals(points, cells.normal_radius, cfg.normal_max_minor_ratio, cells.normal_max_residual,
                cells.normal_max_gap, np.zeros(n), normals, straight, 1)
    face_the_robot(points, scan.origin_yx[0], scan.origin_yx[1], normals, straight, apex)
    ends = straight & ~los.normal_reliable
    margin = min(cfg.sector_margin_deg + extra_margin_deg, 89.0)
    return carve(scan, replace(los, wall_normal=normals, normal_reliable=ends, wall_apex=apex),
                 replace(cfg, sector_margin_deg=margin))


def _scenario(task: tuple) -> dict:
    from superex_deploy.sim.exploration import ExplorationConfig
    from superex_deploy.sim.spad import simulate_scan
    from superex_deploy.sim.spad.scene import prepare_scene

    name, start, variants, steps, with_ideal = task
    grid = load_map(name)
    fans = sorted({VARIANTS[v][0] for v in variants} | ({256} if with_ideal else set()))
    configs = {v: nlos_config(v) for v in variants}
    carved = {v: np.zeros(grid.shape, bool) for v in [*variants, *(["ideal"] if with_ideal else [])]}
    coverage = {v: [] for v in ["los", *carved]}
    walls = {v: 0 for v in carved}
    scan_s = {k: [] for k in fans}

    def on_step(state) -> None:
        known = state.mapper.known(include_carved=False)
        map_walls = state.mapper.seen_wall
        coverage["los"].append(coverage_of(known, grid.valid))
        scans = {}
        for k in fans:
            clock = time.perf_counter()
            scans[k] = simulate_scan(grid, state.pose, SpadConfig(n_secondary=k))
            scan_s[k].append(time.perf_counter() - clock)
        estimates = {}
        for v, cfg in configs.items():
            k = VARIANTS[v][0]
            # The estimate depends on the normal fields only; the variants here change the carving's.
            key = (k, replace(cfg, sector_margin_deg=0.0, wall_strip_m=0.0, apex_margin_m=0.0))
            if key not in estimates:
                estimates[key] = estimate_los(scans[k], cfg)
            carved[v] |= variant_carving(v, scans[k], estimates[key], cfg, map_walls)
        if with_ideal:
            carved["ideal"] |= ideal_carving(scans[256])
        for v in carved:
            coverage[v].append(coverage_of(known | carved[v], grid.valid))

    clock = time.perf_counter()
    run_benchmark_episode(grid, start, "mapex", "observed", steps=steps, cfg=ExplorationConfig(iou_every=0),
                          on_step=on_step)
    for v in carved:
        walls[v] = int(np.count_nonzero(carved[v] & grid.occupied))
    caches = prepare_scene(grid).fan_caches
    cache = {k: {"traced": c.traced, "reused": c.reused, "restarts": c.restarts}
             for (k, _), c in caches.items()}
    # A finished episode stops early: its coverage stays where it ended (coverage_at). The run is the first half.
    return {"map": name, "start": list(start), "steps": steps, "seconds": time.perf_counter() - clock,
            "auc_first_half": {v: coverage_auc(c, 1, steps) for v, c in coverage.items()},
            "at_step_50": {v: coverage_at(c, min(50, steps)) for v, c in coverage.items()},
            "true_walls_carved": walls, "scan_ms_median": {k: 1000 * float(np.median(s)) for k, s in scan_s.items()},
            "scan_ms_mean": {k: 1000 * float(np.mean(s)) for k, s in scan_s.items()}, "fan_cache": cache}


def _property_floor(task: tuple) -> dict:
    """The property test's poses on one train floor: per variant the poses that carved a true wall (with up to
    three of the cells), the carved cells and those beyond line of sight; and the angle (degrees) between each
    trusted estimated normal and the simulator's normal of every ray sharing its wall cell."""
    from superex_deploy.geometry import cell_centre, mark_rays, ray_angles
    from superex_deploy.sim.spad import simulate_scan

    name, poses, variants, n_rays = task
    grid = load_map(name)
    fans = sorted({VARIANTS[v][0] for v in variants})
    out = {v: {"violations": [], "carved": 0, "beyond_los": 0} for v in variants}
    errors = []
    for pose in poses:
        seen_free = np.zeros(grid.shape, bool)
        mark_rays(grid.occupied, cell_centre(pose), ray_angles(2500), 200.0, seen_free, np.zeros(grid.shape, bool))
        scans = {k: simulate_scan(grid, pose, SpadConfig(n_rays=n_rays, n_secondary=k)) for k in fans}
        for v in variants:
            cfg = nlos_config(v)
            scan = scans[VARIANTS[v][0]]
            los = estimate_los(scan, cfg)
            carved = variant_carving(v, scan, los, cfg)
            walls = np.argwhere(carved & grid.occupied)
            if len(walls):
                out[v]["violations"].append([list(pose), walls[:3].tolist()])
            out[v]["carved"] += int(carved.sum())
            out[v]["beyond_los"] += int((carved & ~seen_free).sum())
        los = estimate_los(scans[fans[0]])
        truth = scans[fans[0]].truth
        rays = np.flatnonzero((los.ray_wall >= 0) & (truth.ray_fan >= 0))
        rays = rays[los.normal_reliable[los.ray_wall[rays]]]
        cos = np.abs(np.sum(los.wall_normal[los.ray_wall[rays]] * truth.normal1[rays], axis=1))
        errors.append(np.degrees(np.arccos(np.clip(cos, 0.0, 1.0))))
    errors = np.concatenate(errors) if errors else np.zeros(0)
    return {"map": name, "poses": len(poses), "variants": out, "normal_error_deg": errors.tolist()}


def noisy_property(n_poses: int, names: list[str], sigma_xy_m: float = 0.05, sigma_yaw_deg: float = 1.0
                   ) -> tuple[dict, str]:
    """tests/test_noisy_carving.py's property for the variants (360 primaries): scans from the true cell,
    placed by a belief drawn at the declared sigmas and carved with that covariance (generator 24, floor
    ``trial % floors``). Returns the poses carving a true wall and the carved cells per scan."""
    from superex_deploy.messages import MapFrame, Pose2D
    from superex_deploy.onboard.nlos.processing import scan_from_frame
    from superex_deploy.sim.spad import measured_frame, simulate_scan

    sigma_yaw = np.deg2rad(sigma_yaw_deg)
    rng = np.random.default_rng(24)
    floors = list_maps("train")
    out = {v: {"poses_carving_walls": 0, "examples": [], "carved_per_scan": 0.0} for v in names}
    for trial in range(n_poses):
        grid = load_map(floors[trial % len(floors)])
        candidates = np.argwhere(grid.valid & ~grid.occupied)
        pose = tuple(int(v) for v in candidates[rng.integers(len(candidates))])
        frame = MapFrame(grid.shape, grid.resolution_m)
        x, y = frame.centre_xy(pose)
        dx, dy = rng.normal(0.0, sigma_xy_m, 2)
        belief = Pose2D(x + dx, y + dy, rng.normal(0.0, sigma_yaw))
        for k in sorted({VARIANTS[v][0] for v in names}):
            cfg = SpadConfig(n_rays=360, n_secondary=k)
            simulated = simulate_scan(grid, pose, cfg)
            scan = scan_from_frame(measured_frame(simulated), frame, belief, cfg)
            for v in (v for v in names if VARIANTS[v][0] == k):
                nlos_cfg = nlos_config(v)
                carved = carve(scan, estimate_los(scan, nlos_cfg), nlos_cfg, (sigma_xy_m, sigma_yaw))
                out[v]["carved_per_scan"] += int(carved.sum()) / n_poses
                if np.any(carved & grid.occupied):
                    out[v]["poses_carving_walls"] += 1
                    out[v]["examples"].append([grid.name, list(pose)])
    lines = [f"Soundness under pose error: {n_poses} random train poses, belief {100 * sigma_xy_m:.0f} cm / "
             f"{sigma_yaw_deg:g} degree off and carved with that covariance, 360 primary rays", "",
             "| carving | poses carving a true wall | carved cells / scan |", "|---|---:|---:|"]
    lines += [f"| {v} | {o['poses_carving_walls']} | {o['carved_per_scan']:.0f} |" for v, o in out.items()]
    return {"poses": n_poses, "sigma_xy_m": sigma_xy_m, "sigma_yaw_deg": sigma_yaw_deg, "variants": out}, \
        "\n".join(lines)


def _floor_poses(n_poses: int) -> dict[str, list]:
    """floor -> poses: the property test's draws (generator 2026, floor ``trial % floors``), grouped by floor."""
    rng = np.random.default_rng(2026)
    floors = list_maps("train")
    per_floor: dict[str, list] = {}
    for trial in range(n_poses):
        grid = load_map(floors[trial % len(floors)])
        candidates = np.argwhere(grid.valid & ~grid.occupied)
        per_floor.setdefault(grid.name, []).append(tuple(int(v) for v in candidates[rng.integers(len(candidates))]))
    return per_floor


def property_run(n_poses: int, names: list[str], n_rays: int, jobs: int) -> tuple[dict, str]:
    """The soundness property over ``n_poses`` random poses on the train floors (the same draws as
    tests/test_carving_soundness.py: generator 2026, floor ``trial % floors``), every variant."""
    per_floor = _floor_poses(n_poses)
    with process_pool(jobs) as pool:
        results = list(pool.map(_property_floor, [(m, p, names, n_rays) for m, p in per_floor.items()]))
    errors = np.concatenate([np.asarray(r["normal_error_deg"]) for r in results])
    summary = {"poses": n_poses, "n_rays": n_rays, "variants": {}, "normal_error_deg": {
        q: float(np.quantile(errors, f)) for q, f in (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999), ("max", 1.0))}}
    lines = [f"Soundness property: {n_poses} random poses on the train floors, {n_rays} primary rays", "",
             "| carving | poses carving a true wall | carved cells / scan | beyond line of sight / scan |",
             "|---|---:|---:|---:|"]
    for v in names:
        bad = [[r["map"], *x] for r in results for x in r["variants"][v]["violations"]]
        carved = sum(r["variants"][v]["carved"] for r in results) / n_poses
        beyond = sum(r["variants"][v]["beyond_los"] for r in results) / n_poses
        summary["variants"][v] = {"poses_carving_walls": len(bad), "examples": bad[:5], "carved_per_scan": carved,
                                  "beyond_los_per_scan": beyond}
        lines.append(f"| {v} | {len(bad)} | {carved:.0f} | {beyond:.1f} |")
    q = summary["normal_error_deg"]
    lines += ["", f"Angle between a trusted estimated normal and the simulator's normal of each ray sharing its wall "
              f"cell ({len(errors)} rays): median {q['p50']:.1f}, 99th percentile {q['p99']:.1f}, 99.9th "
              f"{q['p99.9']:.1f}, max {q['max']:.1f} degrees"]
    return summary, "\n".join(lines)


def back_projection_change(n_poses: int, dense: int = 256) -> tuple[dict, str]:
    """How a ``dense``-ray fan changes what the Pix2Pix filter reads, on the property's first ``n_poses`` poses
    (default scans otherwise): the late photons per scan (ratio to 64 rays), the non-zero late bins, and the
    raw back-projection (normalised to its maximum, as the filter gets it): Pearson correlation with the
    64-ray map and mean absolute difference over the cells either map votes on."""
    from superex_deploy.onboard.prediction.inference.manifest import DEFAULT_MODEL_DIR
    from superex_deploy.onboard.prediction.inference.pix2pix import Pix2PixFilter
    from superex_deploy.onboard.nlos import back_project
    from superex_deploy.sim.spad import simulate_scan

    pix2pix = Pix2PixFilter.from_manifest(DEFAULT_MODEL_DIR)
    rows = []
    for name, poses in _floor_poses(n_poses).items():
        grid = load_map(name)
        for pose in poses:
            maps, late, bins = [], [], []
            for k in (64, dense):
                scan = simulate_scan(grid, pose, SpadConfig(n_secondary=k))
                los = estimate_los(scan)
                maps.append(back_project(scan, los))
                h = scan.stored
                ray = np.repeat(np.arange(h.n_rays), np.diff(h.row_start))
                is_late = (los.los_bin[ray] >= 0) & (h.bins > los.los_bin[ray])
                late.append(float(h.counts[is_late].sum()))
                bins.append(int(is_late.sum()))
            voted = (maps[0] > 0) | (maps[1] > 0)
            if voted.sum() > 2 and late[0] > 0:
                a, b = maps[0][voted], maps[1][voted]
                fa, fb = (pix2pix.filter_map(m, pose) for m in maps)
                window = (fa > 0) | (fb > 0)
                rows.append((late[1] / late[0], bins[1] / max(bins[0], 1), float(np.corrcoef(a, b)[0, 1]),
                             float(np.abs(a - b).mean()), float(np.abs(fa - fb)[window].max()),
                             float(((fa > 0.5) != (fb > 0.5))[window].mean())))
    r = np.array(rows)
    out = {"poses": len(rows), "dense": dense, "late_photons_ratio": float(np.median(r[:, 0])),
           "late_bins_ratio": float(np.median(r[:, 1])), "bp_correlation_median": float(np.median(r[:, 2])),
           "bp_mean_abs_difference_median": float(np.median(r[:, 3])),
           "pix2pix_max_abs_difference_median": float(np.median(r[:, 4])),
           "pix2pix_max_abs_difference_max": float(r[:, 4].max()),
           "pix2pix_cells_flipping_at_0.5_mean": float(r[:, 5].mean())}
    text = (f"Back-projection input, {dense} against 64 secondary rays ({len(rows)} train poses, 2500 primaries, "
            f"medians): late photons x{out['late_photons_ratio']:.2f}, non-zero late bins "
            f"x{out['late_bins_ratio']:.2f}; raw back-projection (normalised) correlation "
            f"{out['bp_correlation_median']:.3f}, mean absolute difference {out['bp_mean_abs_difference_median']:.3f} "
            f"over the cells either votes on; the Pix2Pix filter's output: largest absolute difference per scan "
            f"median {out['pix2pix_max_abs_difference_median']:.3f} (max {out['pix2pix_max_abs_difference_max']:.3f}), "
            f"{out['pix2pix_cells_flipping_at_0.5_mean']:.2%} of its window's cells change side of 0.5")
    return out, text


def summarise(results: list[dict], names: list[str]) -> tuple[list[dict], str]:
    los = np.array([r["auc_first_half"]["los"] for r in results])
    los50 = np.array([r["at_step_50"]["los"] for r in results])
    rows, cells = [], [["line of sight", f"{100 * los.mean():.2f}", "-", "-", "-", "-", "-"]]
    for v in names:
        auc = np.array([r["auc_first_half"][v] for r in results])
        at50 = np.array([r["at_step_50"][v] for r in results])
        low, high = bootstrap_interval(auc - los)
        row = {"variant": v, "n_secondary": VARIANTS[v][0] if v in VARIANTS else None,
               "overrides": VARIANTS[v][1] if v in VARIANTS else None, "auc_first_half": float(auc.mean()),
               "ratio_vs_los": float(auc.mean() / los.mean() - 1.0), "paired_points": float(100 * (auc - los).mean()),
               "low": 100 * low, "high": 100 * high, "ratio_at_50": float(at50.mean() / los50.mean() - 1.0),
               "true_walls_carved": int(sum(r["true_walls_carved"][v] for r in results))}
        rows.append(row)
        cells.append([v, f"{100 * row['auc_first_half']:.2f}", f"{row['ratio_vs_los']:+.2%}",
                      f"{row['paired_points']:+.2f} [{row['low']:+.2f}, {row['high']:+.2f}]",
                      f"{row['ratio_at_50']:+.1%}", row["true_walls_carved"], row["n_secondary"] or "-"])
    lines = markdown_table(["carving", "first-half AUC", "vs line of sight", "paired points [95 % interval]",
                            "at step 50 vs LOS", "true walls carved", "fans"], cells, ["-"] + ["---:"] * 6)
    fans = sorted({int(k) for r in results for k in r["scan_ms_median"]})
    fan_cells = []
    for k in fans:
        med = np.median([r["scan_ms_median"][str(k)] if str(k) in r["scan_ms_median"] else r["scan_ms_median"][k]
                         for r in results])
        mean = np.mean([r["scan_ms_mean"].get(str(k), r["scan_ms_mean"].get(k)) for r in results])
        cache = [r["fan_cache"].get(str(k), r["fan_cache"].get(k)) for r in results]
        fan_cells.append([k, f"{med:.1f}", f"{mean:.1f}", sum(c["traced"] for c in cache),
                          sum(c["reused"] for c in cache), sum(c["restarts"] for c in cache)])
    lines += [""] + markdown_table(["secondary rays", "simulator ms / scan (median of scenario medians)", "mean",
                                    "fans traced", "reused", "cache restarts"], fan_cells, ["---:"] * 6)
    return rows, "\n".join(lines)


def plot(rows: list[dict], title: str, path: Path) -> None:
    """Bar chart of each variant's paired first-half coverage gain over line of sight (points, 95 % interval)."""
    fig, ax = pyplot().subplots(figsize=(8, 0.35 * len(rows) + 1.2))
    y = np.arange(len(rows))[::-1]
    gain = np.array([r["paired_points"] for r in rows])
    err = np.array([[r["paired_points"] - r["low"], r["high"] - r["paired_points"]] for r in rows]).T
    colours = ["tab:red" if r["true_walls_carved"] else "tab:blue" for r in rows]
    ax.barh(y, gain, xerr=err, color=colours, capsize=2)
    ax.set_yticks(y, [f"{r['variant']} ({r['ratio_vs_los']:+.1%})" for r in rows], fontsize=8)
    ax.set_xlabel("first-half coverage gain over line of sight (points; red: carved a true wall)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("train", "eval"), default="train")
    parser.add_argument("--scenarios", type=int, default=6)
    parser.add_argument("--steps", type=int, default=300, help="steps run: the first half of a 2x longer episode")
    parser.add_argument("--variants", default="all", help=f"comma-separated names of {list(VARIANTS)}, or 'all'")
    parser.add_argument("--no-ideal", action="store_true")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--property", type=int, default=0, metavar="POSES",
                        help="instead: the soundness property over this many random train poses")
    parser.add_argument("--noisy-property", type=int, default=0, metavar="POSES",
                        help="instead: the soundness property under a 5 cm / 1 degree pose error")
    parser.add_argument("--bp-change", type=int, default=0, metavar="POSES",
                        help="instead: how a 256-ray fan changes the back-projection, over this many train poses")
    parser.add_argument("--property-rays", type=int, default=360, help="primary rays of the property's scans")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--plot-from", type=Path, default=None, metavar="JSON",
                        help="instead: plot an episode run's JSON next to it (.png)")
    args = parser.parse_args()
    if args.plot_from is not None:
        run = json.loads(args.plot_from.read_text())
        plot(run["rows"], f"{len(run['scenarios'])} {run['split']} scenarios, {run['steps']} steps, fixed MapEx "
             "trajectories", args.plot_from.with_suffix(".png"))
        return
    names = list(VARIANTS) if args.variants == "all" else [v.strip() for v in args.variants.split(",")]
    if any(v not in VARIANTS for v in names):
        raise SystemExit(f"unknown variant(s); choose from {list(VARIANTS)}")
    if args.noisy_property:
        out, text = noisy_property(args.noisy_property, names)
        print(text)
        _write(args.out, out, text)
        return
    if args.bp_change:
        out, text = back_projection_change(args.bp_change)
        print(text)
        _write(args.out, out, text)
        return
    if args.property:
        summary, table = property_run(args.property, names, args.property_rays, args.jobs)
        print(table)
        _write(args.out, summary, table)
        return
    places = scenarios(args.split, args.scenarios)
    print(f"{len(places)} {args.split} scenarios, {args.steps} steps, variants {names}", flush=True)
    tasks = [(m, s, names, args.steps, not args.no_ideal) for m, s in places]
    shown = names + ([] if args.no_ideal else ["ideal"])
    with process_pool(args.jobs) as pool:
        results = []
        for r in pool.map(_scenario, tasks):
            results.append(r)
            print(f"{r['map']} {r['start']}: {r['seconds']:.0f} s, LOS {100 * r['auc_first_half']['los']:.2f}, "
                  + ", ".join(f"{v} {100 * a:.2f}" for v, a in r["auc_first_half"].items() if v != "los"), flush=True)
            # Rewritten after every scenario: a run cut short still leaves its finished scenarios summarised.
            rows, table = summarise(results, shown)
            _write(args.out, {"split": args.split, "steps": args.steps, "rows": rows, "scenarios": results},
                   f"{len(results)} of {len(places)} {args.split} scenarios, {args.steps} steps (the first half of "
                   f"{2 * args.steps}-step episodes)\n\n{table}")
    print(table)


def _write(out, payload: dict, text: str) -> None:
    """``payload`` as JSON to ``out`` and ``text`` as markdown beside it (``out`` None: nothing written)."""
    if out is None:
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(out, json.dumps(payload, indent=1))
    write_atomically(out.with_suffix(".md"), text + "\n")


if __name__ == "__main__":
    main()
