"""What the LaMa lattice filter (``LamaEnsemble(lattice_filter=True)``) costs a prediction, against the frame budget.

One LaMa-BP member (the ``realtime`` profile's ``max_members=1`` and its ONNX Runtime session: one intra-op thread,
no spinning) predicts the largest eval floor (50015847, 442 x 1327 cells at 0.1 m, the frame-budget benchmark's
floor; ``--crop`` cells around its start 0 for the crop a reusing prediction asks, 0: the whole floor), its cells
known within ``--known-m`` metres of start 0 (true walls and free cells there, the rest unknown, no evidence), with
the filter off and on, alternated (``--repeats`` pairs after one warm-up pair, the order swapped every pair), and
times the prediction (``LamaEnsemble.predict``: encoding, the member, the filter, cropping) and the filter alone
(:func:`~superex_deploy.onboard.prediction.inference.remove_lattice` on the member's padded output). Prints the
medians and their ratios; writes JSON (``--out``).

    NUMBA_NUM_THREADS=1 python scripts/bench_lattice_cost.py --repeats 15 --out benchmarks/lattice/cost.json

Ratios within one run are what to read (the machine may be loaded); the absolute times are this machine's.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FLOOR, START = "50015847", 0


def observed_map(crop: int, known_m: float):
    """int8 ``[H, W]``: the floor (or ``crop`` x ``crop`` cells around start 0) known within ``known_m`` of the
    start, unknown elsewhere."""
    from superex_deploy.maps import load_map, start_poses
    from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN

    grid = load_map(FLOOR)
    r0, c0 = start_poses(FLOOR)[START]
    rows, cols = np.indices(grid.shape)
    near = np.hypot(rows - r0, cols - c0) * grid.resolution_m <= known_m
    observed = np.full(grid.shape, UNKNOWN, np.int8)
    observed[near & grid.valid & ~grid.occupied] = FREE
    observed[near & grid.occupied] = OCCUPIED
    if crop:
        top, left = max(0, r0 - crop // 2), max(0, c0 - crop // 2)
        observed = observed[top:top + crop, left:left + crop]
    return observed


def measure(crop: int, known_m: float, repeats: int) -> dict:
    from superex_deploy.onboard.prediction.inference import remove_lattice
    from superex_deploy.pipeline import PROFILES, make_predictor

    profile = PROFILES["realtime"]
    plain = make_predictor("lama_bp", profile=profile).with_lattice_filter(False)
    filtered = plain.with_lattice_filter(True)
    observed = observed_map(crop, known_m)
    evidence = np.zeros(observed.shape, np.float32)
    padded = np.random.default_rng(0).random(plain.padded_shape(observed.shape)).astype(np.float32) * 0.2
    times = {"off": [], "on": [], "filter": []}
    for i in range(repeats + 1):
        order = (("off", plain), ("on", filtered)) if i % 2 == 0 else (("on", filtered), ("off", plain))
        for name, ensemble in order:
            clock = time.perf_counter()
            ensemble.predict(observed, evidence)
            if i:  # the first pair warms the sessions up
                times[name].append(time.perf_counter() - clock)
        clock = time.perf_counter()
        remove_lattice(padded, plain.size_multiple)
        if i:
            times["filter"].append(time.perf_counter() - clock)
    median = {name: float(np.median(values)) * 1e3 for name, values in times.items()}
    return {"shape": list(observed.shape), "padded": list(plain.padded_shape(observed.shape)),
            "members": plain.max_members, "repeats": repeats, "median_ms": median,
            "ratio_on_off": median["on"] / median["off"], "filter_share_of_off": median["filter"] / median["off"],
            "samples_ms": {k: [round(v * 1e3, 3) for v in values] for k, values in times.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="alternated on / off pairs after one warm-up pair")
    parser.add_argument("--crops", default="0,256", help="comma-separated crop sides in cells (0: the whole floor)")
    parser.add_argument("--known-m", type=float, default=10.0, help="metres around the start that are known")
    parser.add_argument("--out", type=Path, default=None, help="JSON output (default: print only)")
    args = parser.parse_args()
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    rows = {}
    for crop in (int(c) for c in args.crops.split(",") if c.strip()):
        row = measure(crop, args.known_m, args.repeats)
        rows["whole" if crop == 0 else f"crop_{crop}"] = row
        m = row["median_ms"]
        print(f"{FLOOR} {'whole floor' if crop == 0 else f'crop {crop}'} {row['shape']} (padded {row['padded']}): "
              f"prediction off {m['off']:.1f} ms, on {m['on']:.1f} ms (ratio {row['ratio_on_off']:.3f}); filter "
              f"alone {m['filter']:.1f} ms ({100 * row['filter_share_of_off']:.1f} % of a prediction), medians of "
              f"{row['repeats']}")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"floor": FLOOR, "start": START, "known_m": args.known_m,
                                        "machine": platform.machine(), "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
