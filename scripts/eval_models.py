"""Accuracy of the exported models on the held-out KTH ``train`` buildings (never seen in training).

Part 1, the back-projection filter: Pix2Pix samples are generated exactly as for training
(:func:`superex_train.generate.generate_pix2pix`, exploration episodes, raw back-projection window around the
robot) but on the held-out buildings' maps only; the first ``--filter-samples`` are scored. Wall IoU against the
hidden-wall ground truth (``h2`` cells still unknown), pooled over samples (sum of intersections / sum of
unions), inside the loss mask (unknown cells of the map). Methods: Pix2Pix (threshold 0.5), the Laplacian-
filtered back-projection (the classic baseline, at 0.5 and at its best threshold on these very samples, an
upper bound for it), and the raw back-projection (best threshold).

Part 2, the map predictors: one SuperEx-sensing episode per held-out map (SPAD scan, carving and Pix2Pix
evidence every step; planner cycled over nearest / hector / mapex with the observed map as predictor, so the
trajectory does not depend on the models scored). The first time the line-of-sight coverage enters each
coverage bin (0-10, 10-20, 20-30 %), both ensembles predict the whole map: LAMA_BP from the observation with
carving plus evidence, LAMA_LOS from the line-of-sight observation, and the observed map itself (unknown =
free) as the floor. Scores: wall IoU over the evaluation area (``superex_deploy.evaluation.metrics.map_iou``,
threshold 0.5) and wall IoU on the cells unknown at that step (what prediction adds). A calibration table
pools all predictions: IoU on unknown cells at thresholds 0.1-0.9, the share of unknown cells predicted as walls
at 0.5 and the mean wall probability there, against the true share of walls.

Part 2 also scores each ensemble by distance from known space
(:mod:`superex_deploy.evaluation.known_distance`): the cells of the evaluation area unknown in the pipeline's map
(line of sight and carving: the same cells for both ensembles, as in the calibration table) fall in the bins 0-2,
2-5, 5-10 and >10 m from its nearest known cell, and their counts are pooled cell by cell over all predictions (wall IoU, true wall share, mean wall probability, share called walls at 0.5, expected
calibration error over 10 probability bins, negative log-likelihood, Brier score). It measures the lattice the
LaMa members draw far from known space (:func:`~superex_deploy.evaluation.known_distance.lattice_strength`,
period the ensemble's ``size_multiple``) on the unknown cells more than :data:`LATTICE_DISTANCE_M` away, for
each ensemble's mean and its strongest member. The ensembles are scored with their members' raw outputs (the
lattice filter off); ``--lattice-filter`` scores each a second time with the filter on, as the pipeline runs them
since 0.3 (``lama_bp_filtered``, ``lama_los_filtered``).

``--models DIR`` scores another model folder (a ``manifest.json`` and its files, e.g. ``runs/training/candidate``);
``--maps N`` keeps the first N held-out maps (name order) for both parts, ``--filter-samples N`` the first N
filter windows: ``--maps 3 --filter-samples 64 --jobs 1`` is a quick check. Prints markdown tables and writes
JSON (``--out``, default ``benchmarks/eval_models/eval_models.json``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import markdown_table, run_benchmark_episode, write_json
from superex_deploy.evaluation.known_distance import (DISTANCE_BINS_M, CalibrationCounts, counts_by_distance,
                                                      distance_bin_label, distance_to_known, lattice_strength,
                                                      LATTICE_MIN_CELLS, pool_counts)
from superex_deploy.evaluation.episodes import EpisodeState
from superex_deploy.evaluation.metrics import evaluation_area, map_iou
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN
from superex_deploy.onboard.prediction.inference import (DEFAULT_MODEL_DIR, LamaEnsemble, ModelKind, Pix2PixFilter,
                                      SessionConfig)
from superex_deploy.maps import list_maps, load_map, map_building
from superex_deploy.onboard.nlos import laplacian_filter
from superex_deploy.parallel import process_pool
from superex_deploy.pipeline import PROFILES
from superex_train.datasets import ShardDataset
from superex_train.generate import GenerationConfig, generate_pix2pix, heldout_buildings, random_start

ROOT = Path(__file__).resolve().parent.parent

COVERAGE_BINS = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.3))
SWEEP_THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Thresholds of part 2's calibration table (0.8 is MapEx's visibility threshold)."""
PLANNERS = ("nearest", "hector", "mapex")
LATTICE_DISTANCE_M = 5.0
"""The lattice is measured on unknown cells farther than this from known space (metres): beyond the 0-2 and 2-5 m
bins, where what is known shapes the prediction."""


def heldout_maps() -> list[str]:
    """The ``train`` maps of the held-out buildings, in name order."""
    held = set(heldout_buildings())
    return [name for name in list_maps("train") if map_building(name) in held]


def _pooled_iou(pairs) -> float:
    inter = sum(int(np.count_nonzero(p & t)) for p, t in pairs)
    union = sum(int(np.count_nonzero(p | t)) for p, t in pairs)
    return inter / union if union else 1.0


def evaluate_filter(model_dir: Path, n_samples: int, jobs: int, maps: list[str]) -> dict:
    """Part 1 (see the module docstring)."""
    p2p = Pix2PixFilter.from_manifest(model_dir)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = GenerationConfig(maps=tuple(maps), episodes_per_map=2, steps=300, sample_every=16,
                               window_cells=p2p.window_cells, jobs=jobs, seed=12345)
        data = ShardDataset(generate_pix2pix(Path(tmp) / "data", cfg, progress=False).directory)
        count = min(n_samples, len(data))
        windows, truths, masks = [], [], []
        for i in range(count):
            inputs, target, mask = data.arrays(i)
            windows.append((inputs[0] + 1.0) / 2.0)
            truths.append(target & mask)
            masks.append(mask)
    raw = np.clip(np.stack(windows), 0.0, 1.0).astype(np.float32)
    clock = time.perf_counter()
    filtered = np.concatenate([p2p.filter_windows(raw[i:i + 16]) for i in range(0, count, 16)])
    p2p_ms = (time.perf_counter() - clock) / count * 1e3
    laplacian = np.stack([laplacian_filter(w) for w in raw])
    thresholds = np.round(np.arange(0.05, 0.96, 0.05), 2)

    def scores(maps: np.ndarray) -> dict[float, float]:
        return {float(t): _pooled_iou([((m >= t) & k, y) for m, k, y in zip(maps, masks, truths)])
                for t in thresholds}

    lap, rawi, p2pi = scores(laplacian), scores(raw), scores(filtered)
    best = lambda s: max(s.items(), key=lambda kv: kv[1])  # noqa: E731
    return {"samples": count, "maps": len(cfg.maps), "pix2pix_iou@0.5": p2pi[0.5],
            "pix2pix_best": best(p2pi), "laplacian_iou@0.5": lap[0.5], "laplacian_best": best(lap),
            "raw_best": best(rawi), "pix2pix_ms_per_window": p2p_ms,
            "hidden_wall_cells_per_sample": float(np.mean([t.sum() for t in truths]))}


def _score_distance_and_lattice(record: dict, method: str, members: np.ndarray, mean: np.ndarray, grid,
                                unknown: np.ndarray, far: np.ndarray, distance: np.ndarray, period: int) -> None:
    """Add one ensemble's distance-bin counts over the ``unknown`` cells (of the evaluation area) and its lattice
    measures over the ``far`` ones to ``record`` (in place)."""
    counts = counts_by_distance(mean, grid.occupied, unknown, grid.resolution_m, distance=distance)
    record.setdefault("distance_counts", {})[method] = {label: c.to_dict() for label, c in counts.items()}
    if np.count_nonzero(far) < LATTICE_MIN_CELLS:
        for key in ("share", "amplitude", "member_share", "variance"):
            record[f"{method}_lattice_{key}_far"] = None
        return
    of_mean = lattice_strength(mean, far, period)
    record[f"{method}_lattice_share_far"] = of_mean.share
    record[f"{method}_lattice_amplitude_far"] = of_mean.amplitude
    record[f"{method}_lattice_member_share_far"] = max(lattice_strength(m, far, period).share for m in members)
    # The members' disagreement there (what MapEx reads as uncertainty), lattice included.
    record[f"{method}_lattice_variance_far"] = float(members.var(axis=0)[far].mean())


def _episode(args: tuple[str, int, str, bool]) -> list[dict]:
    """Part 2 for one map: a record per coverage bin reached."""
    name, index, model_dir, lattice_filter = args
    session = SessionConfig(intra_op_threads=1)
    p2p = Pix2PixFilter.from_manifest(model_dir, session)
    # The members' raw outputs (the shipped ensembles filter the lattice: the *_filtered rows).
    ensembles = {kind.value: LamaEnsemble.from_manifest(kind, model_dir, session, lattice_filter=False)
                 for kind in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS)}
    if lattice_filter:
        ensembles.update({f"{k}_filtered": e.with_lattice_filter(True) for k, e in list(ensembles.items())})
    grid = load_map(name)
    rng = np.random.default_rng([777, index])
    start = random_start(grid, rng, 0.4)
    sensing = SpadSensing(bp_filter=p2p.filter_map)
    area = evaluation_area(grid)
    pending = list(COVERAGE_BINS)
    records: list[dict] = []

    class _Done(Exception):
        """Every bin is behind: stop the episode (nothing more to score)."""

    def on_step(state: EpisodeState) -> None:
        if state.coverage >= COVERAGE_BINS[-1][1]:
            raise _Done
        for low, high in list(pending):
            if not low <= state.coverage < high:
                continue
            pending.remove((low, high))
            los = state.mapper.observed(include_carved=False)
            record = {"map": name, "step": state.step, "coverage": state.coverage, "bin": f"{low:.0%}-{high:.0%}"}
            # One set of cells for both ensembles: unknown in the pipeline's map (line of sight and carving), at
            # their distance from its known cells.
            pipeline_unknown = state.observed == UNKNOWN
            unknown = pipeline_unknown & area
            distance = distance_to_known(pipeline_unknown, grid.resolution_m)
            far = unknown & (distance > LATTICE_DISTANCE_M)
            means = {"observed": (state.observed == OCCUPIED).astype(np.float32)}
            for method, ensemble in ensembles.items():
                # LaMa-LOS sees the line-of-sight map (its own unknown cells: carving is not its input).
                bp = ensemble.kind is ModelKind.LAMA_BP
                observed = state.observed if bp else los
                members = ensemble.predict_members(observed, sensing.evidence if bp else None)
                means[method] = mean = ensemble.combine(members, observed).mean
                _score_distance_and_lattice(record, method, members, mean, grid, unknown, far, distance,
                                            ensemble.size_multiple)
            for method, mean in means.items():
                record[f"{method}_iou"] = map_iou(mean, grid, area=area)
                record[f"{method}_unknown_iou"] = map_iou(mean, grid, area=unknown)
                for t in SWEEP_THRESHOLDS:
                    record[f"{method}_unknown_iou@{t}"] = map_iou(mean, grid, threshold=t, area=unknown)
                record[f"{method}_unknown_wall_fraction"] = float((mean[unknown] >= 0.5).mean()) if unknown.any() else 0.0
                record[f"{method}_unknown_mean_probability"] = float(mean[unknown].mean()) if unknown.any() else 0.0
            record["truth_unknown_wall_fraction"] = float(grid.occupied[unknown].mean()) if unknown.any() else 0.0
            records.append(record)

    try:
        run_benchmark_episode(grid, start, PLANNERS[index % len(PLANNERS)], ObservedAsPrediction(), steps=400,
                              seed=index, sensing=sensing, on_step=on_step, profile=PROFILES["full"])
    except _Done:
        pass
    return records


def _pooled_distance_counts(records: list[dict]) -> dict[str, dict[str, CalibrationCounts]]:
    """``{method: {distance bin: counts}}`` of the records' counts pooled cell by cell."""
    methods = list(records[0].get("distance_counts", {})) if records else []
    return {method: pool_counts([{label: CalibrationCounts.from_dict(c)
                                  for label, c in r["distance_counts"][method].items()} for r in records])
            for method in methods}


def evaluate_predictors(model_dir: Path, jobs: int, maps: list[str], lattice_filter: bool = False) -> dict:
    """Part 2 (see the module docstring)."""
    tasks = [(name, i, str(model_dir), lattice_filter) for i, name in enumerate(maps)]
    with process_pool(jobs) as pool:
        records = [r for result in pool.map(_episode, tasks) for r in result]
    table = {}
    for low, high in COVERAGE_BINS:
        label = f"{low:.0%}-{high:.0%}"
        rows = [r for r in records if r["bin"] == label]
        table[label] = {"n": len(rows), **{key: float(np.mean([r[key] for r in rows]))
                                            for key in rows[0] if "iou" in key or "fraction" in key
                                            or "probability" in key}} if rows else {"n": 0}
    # Pooled counts (additive: any later pooling starts from them) and their measures, over all predictions and
    # per coverage bin; the per-prediction counts are not kept (16 numbers a bin, method and prediction).
    pooled = {"all": _pooled_distance_counts(records),
              **{label: _pooled_distance_counts([r for r in records if r["bin"] == label]) for label in table}}
    for record in records:
        record.pop("distance_counts", None)

    def summaries(counts: dict) -> dict:
        return {method: {label: c.summary() for label, c in bins.items()} for method, bins in counts.items()}

    distance = {"bins_m": [[low, None if np.isinf(high) else high] for low, high in DISTANCE_BINS_M],
                "pooled": summaries(pooled["all"]),
                "by_coverage": {label: summaries(pooled[label]) for label in table},
                "counts": {key: {method: {label: c.to_dict() for label, c in bins.items()}
                                 for method, bins in counts.items()} for key, counts in pooled.items()}}
    lattice = {}
    for method in pooled["all"]:
        measured = [r for r in records if r.get(f"{method}_lattice_share_far") is not None]
        lattice[method] = {"n": len(measured), **{
            f"{key}_{stat}": (float(fn([r[f"{method}_lattice_{key}_far"] for r in measured])) if measured else None)
            for key in ("share", "member_share", "amplitude", "variance")
            for stat, fn in (("median", np.median), ("max", np.max))}}
    return {"maps": len(maps), "bins": table, "records": records, "distance": distance,
            "lattice": {"distance_m": LATTICE_DISTANCE_M, "min_cells": LATTICE_MIN_CELLS, "ensembles": lattice}}


def distance_markdown(pooled: dict) -> list[str]:
    """The distance table: one row per (distance bin, ensemble)."""
    def number(value, digits=3):
        return "-" if value is None else f"{value:.{digits}f}"

    rows = []
    for label in [distance_bin_label(low, high) for low, high in DISTANCE_BINS_M]:
        for method, bins in pooled.items():
            row = bins.get(label, {"cells": 0})
            rows.append([label, method, row["cells"], number(row.get("wall_share")), number(row.get("mean_p")),
                         number(row.get("predicted_share"), 4), number(row.get("iou")), number(row.get("ece"), 4),
                         number(row.get("nll"), 4), number(row.get("brier"), 4)])
    return markdown_table(["distance", "ensemble", "cells", "true wall share", "mean p", "walls @ 0.5", "IoU @ 0.5",
                           "ECE", "NLL (nats)", "Brier"], rows, ["-", "-"] + ["---:"] * 8)


def lattice_markdown(lattice: dict) -> list[str]:
    """The lattice table: one row per ensemble."""
    def pair(row, key, digits):
        if row[f"{key}_median"] is None:
            return "-"
        return f"{row[f'{key}_median']:.{digits}f} / {row[f'{key}_max']:.{digits}f}"

    rows = [[method, row["n"], pair(row, "share", 3), pair(row, "member_share", 3), pair(row, "amplitude", 4),
             pair(row, "variance", 5)] for method, row in lattice["ensembles"].items()]
    return markdown_table(["ensemble", "predictions", "share of the mean (median / max)",
                           "strongest member's share (median / max)", "amplitude of the mean (median / max)",
                           "members' variance (median / max)"], rows, ["-"] + ["---:"] * 5)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=DEFAULT_MODEL_DIR,
                        help="model folder with a manifest.json (default: the committed exported/)")
    parser.add_argument("--maps", type=int, default=None, help="score only the first N held-out maps (both parts)")
    parser.add_argument("--filter-samples", type=int, default=400, help="part 1: filter windows scored")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--skip-filter", action="store_true")
    parser.add_argument("--skip-predictors", action="store_true")
    parser.add_argument("--lattice-filter", action="store_true",
                        help="part 2: also score each ensemble with its lattice filter on")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "eval_models" / "eval_models.json")
    args = parser.parse_args(argv)
    if args.maps is not None and args.maps < 1:
        parser.error(f"--maps must be >= 1, got {args.maps}")
    all_maps = heldout_maps()
    maps = all_maps[:args.maps]
    result = {"heldout_buildings": list(heldout_buildings()), "heldout_maps": all_maps, "maps_scored": maps,
              "models": str(args.models), "seconds": {}}
    if not args.skip_filter:
        clock = time.perf_counter()
        f = evaluate_filter(args.models, args.filter_samples, args.jobs, maps)
        result["filter"] = f
        result["seconds"]["filter"] = time.perf_counter() - clock
        print(f"\n## Back-projection filter: {f['samples']} held-out windows ({f['maps']} maps), wall IoU vs hidden "
              f"walls\n")
        print("| method | IoU @ 0.5 | best IoU (threshold) |\n|---|---:|---:|")
        print(f"| Pix2Pix | {f['pix2pix_iou@0.5']:.3f} | {f['pix2pix_best'][1]:.3f} ({f['pix2pix_best'][0]}) |")
        print(f"| Laplacian | {f['laplacian_iou@0.5']:.3f} | {f['laplacian_best'][1]:.3f} ({f['laplacian_best'][0]}) |")
        print(f"| raw back-projection | - | {f['raw_best'][1]:.3f} ({f['raw_best'][0]}) |")
        print(f"\nPix2Pix ORT: {f['pix2pix_ms_per_window']:.1f} ms per window (batches of 16)")
    if not args.skip_predictors:
        clock = time.perf_counter()
        p = evaluate_predictors(args.models, args.jobs, maps, args.lattice_filter)
        result["predictors"] = p
        result["seconds"]["predictors"] = time.perf_counter() - clock
        print(f"\n## Map prediction on {p['maps']} held-out maps: wall IoU (whole evaluation area / unknown cells)\n")
        print("| coverage | n | observed | LaMa-LOS | LaMa-BP |\n|---|---:|---:|---:|---:|")
        for label, row in p["bins"].items():
            if row["n"] == 0:
                print(f"| {label} | 0 | - | - | - |")
                continue
            cell = lambda m: f"{row[m + '_iou']:.3f} / {row[m + '_unknown_iou']:.3f}"  # noqa: E731
            print(f"| {label} | {row['n']} | {cell('observed')} | {cell('lama_los')} | {cell('lama_bp')} |")
        rows = [r for r in p["records"]]
        if rows:
            print(f"\nCalibration, all {len(rows)} predictions: wall IoU on unknown cells by threshold, the share of "
                  f"unknown cells predicted as walls at 0.5 and their mean wall probability (truth: "
                  f"{np.mean([r['truth_unknown_wall_fraction'] for r in rows]):.3f} of them are walls)\n")
            print("| ensemble | " + " | ".join(f"IoU @ {t}" for t in SWEEP_THRESHOLDS) + " | walls @ 0.5 | mean p |")
            print("|---|" + "---:|" * (len(SWEEP_THRESHOLDS) + 2))
            for method in [m for m in p["distance"]["pooled"] if m.startswith("lama_los")] + [
                    m for m in p["distance"]["pooled"] if m.startswith("lama_bp")]:
                ious = " | ".join(f"{np.mean([r[f'{method}_unknown_iou@{t}'] for r in rows]):.3f}"
                                  for t in SWEEP_THRESHOLDS)
                walls = np.mean([r[f"{method}_unknown_wall_fraction"] for r in rows])
                mean_p = np.mean([r[f"{method}_unknown_mean_probability"] for r in rows])
                print(f"| {method} | {ious} | {walls:.3f} | {mean_p:.3f} |")
            print(f"\n## Accuracy by distance from known space, all {len(rows)} predictions pooled cell by cell\n")
            print("\n".join(distance_markdown(p["distance"]["pooled"])))
            print(f"\n## Lattice far out: unknown cells > {LATTICE_DISTANCE_M:g} m from known space, period "
                  f"size_multiple, over the predictions with at least {LATTICE_MIN_CELLS} such cells\n")
            print("\n".join(lattice_markdown(p["lattice"])))
    write_json(args.out, result)
    print(f"\nwrote {args.out} ({', '.join(f'{k} {v:.0f} s' for k, v in result['seconds'].items())})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
