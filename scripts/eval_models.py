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
free) as the floor. Scores: wall IoU over the evaluation area (``superex_deploy.sim.metrics.map_iou``,
threshold 0.5) and wall IoU on the cells unknown at that step (what prediction adds). A calibration table
pools all predictions: IoU on unknown cells at thresholds 0.1-0.9, the share of unknown cells predicted as walls
at 0.5 and the mean wall probability there, against the true share of walls.

Prints markdown tables and writes JSON (``--out``, default ``benchmarks/eval_models.json``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import run_benchmark_episode, write_json
from superex_deploy.sim.episode import EpisodeState
from superex_deploy.sim.metrics import evaluation_area, map_iou
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.onboard.types import OCCUPIED, UNKNOWN
from superex_deploy.onboard.prediction.inference import (DEFAULT_MODEL_DIR, LamaEnsemble, ModelKind, Pix2PixFilter,
                                      SessionConfig)
from superex_deploy.maps import list_maps, load_map, map_building
from superex_deploy.onboard.nlos import laplacian_filter
from superex_deploy.parallel import process_pool
from superex_train.datasets import ShardDataset
from superex_train.generate import GenerationConfig, generate_pix2pix, heldout_buildings, random_start

ROOT = Path(__file__).resolve().parent.parent

COVERAGE_BINS = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.3))
SWEEP_THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Thresholds of part 2's calibration table (0.8 is MapEx's visibility threshold)."""
PLANNERS = ("nearest", "hector", "mapex")


def heldout_maps() -> list[str]:
    """The ``train`` maps of the held-out buildings."""
    held = set(heldout_buildings())
    return [name for name in list_maps("train") if map_building(name) in held]


def _pooled_iou(pairs) -> float:
    inter = sum(int(np.count_nonzero(p & t)) for p, t in pairs)
    union = sum(int(np.count_nonzero(p | t)) for p, t in pairs)
    return inter / union if union else 1.0


def evaluate_filter(model_dir: Path, n_samples: int, jobs: int) -> dict:
    """Part 1 (see the module docstring)."""
    p2p = Pix2PixFilter.from_manifest(model_dir)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = GenerationConfig(maps=tuple(heldout_maps()), episodes_per_map=2, steps=300, sample_every=16,
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


def _episode(args: tuple[str, int, str]) -> list[dict]:
    """Part 2 for one map: a record per coverage bin reached."""
    name, index, model_dir = args
    session = SessionConfig(intra_op_threads=1)
    p2p = Pix2PixFilter.from_manifest(model_dir, session)
    ensembles = {kind: LamaEnsemble.from_manifest(kind, model_dir, session)
                 for kind in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS)}
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
            unknown = (state.observed == UNKNOWN) & area
            means = {"observed": (state.observed == OCCUPIED).astype(np.float32),
                     "lama_bp": ensembles[ModelKind.LAMA_BP].predict(state.observed, sensing.evidence).mean,
                     "lama_los": ensembles[ModelKind.LAMA_LOS].predict(los, None).mean}
            record = {"map": name, "step": state.step, "coverage": state.coverage, "bin": f"{low:.0%}-{high:.0%}"}
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
                              seed=index, sensing=sensing, on_step=on_step)
    except _Done:
        pass
    return records


def evaluate_predictors(model_dir: Path, jobs: int) -> dict:
    """Part 2 (see the module docstring)."""
    maps = heldout_maps()
    tasks = [(name, i, str(model_dir)) for i, name in enumerate(maps)]
    with process_pool(jobs) as pool:
        records = [r for result in pool.map(_episode, tasks) for r in result]
    table = {}
    for low, high in COVERAGE_BINS:
        label = f"{low:.0%}-{high:.0%}"
        rows = [r for r in records if r["bin"] == label]
        table[label] = {"n": len(rows), **{key: float(np.mean([r[key] for r in rows]))
                                            for key in rows[0] if "iou" in key or "fraction" in key
                                            or "probability" in key}} if rows else {"n": 0}
    return {"maps": len(maps), "bins": table, "records": records}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=DEFAULT_MODEL_DIR)
    parser.add_argument("--filter-samples", type=int, default=400)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--skip-filter", action="store_true")
    parser.add_argument("--skip-predictors", action="store_true")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "eval_models.json")
    args = parser.parse_args(argv)
    result = {"heldout_buildings": list(heldout_buildings()), "heldout_maps": heldout_maps()}
    if not args.skip_filter:
        f = evaluate_filter(args.models, args.filter_samples, args.jobs)
        result["filter"] = f
        print(f"\n## Back-projection filter: {f['samples']} held-out windows ({f['maps']} maps), wall IoU vs hidden "
              f"walls\n")
        print("| method | IoU @ 0.5 | best IoU (threshold) |\n|---|---:|---:|")
        print(f"| Pix2Pix | {f['pix2pix_iou@0.5']:.3f} | {f['pix2pix_best'][1]:.3f} ({f['pix2pix_best'][0]}) |")
        print(f"| Laplacian | {f['laplacian_iou@0.5']:.3f} | {f['laplacian_best'][1]:.3f} ({f['laplacian_best'][0]}) |")
        print(f"| raw back-projection | - | {f['raw_best'][1]:.3f} ({f['raw_best'][0]}) |")
        print(f"\nPix2Pix ORT: {f['pix2pix_ms_per_window']:.1f} ms per window (batches of 16)")
    if not args.skip_predictors:
        p = evaluate_predictors(args.models, args.jobs)
        result["predictors"] = p
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
            for method in ("lama_los", "lama_bp"):
                ious = " | ".join(f"{np.mean([r[f'{method}_unknown_iou@{t}'] for r in rows]):.3f}"
                                  for t in SWEEP_THRESHOLDS)
                walls = np.mean([r[f"{method}_unknown_wall_fraction"] for r in rows])
                mean_p = np.mean([r[f"{method}_unknown_mean_probability"] for r in rows])
                print(f"| {method} | {ious} | {walls:.3f} | {mean_p:.3f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, result)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
