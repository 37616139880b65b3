"""Lower precision for the LaMa members: int8 (ONNX Runtime dynamic quantisation of the Conv and MatMul
weights) and fp16 (weights and activations, fp32 inputs and outputs) against the exported fp32 member.

Inputs are real partial maps: 200-step episodes (nearest-frontier planner, observed map) on four held-out train
floors, a 256 x 256 crop around the robot (the size an asynchronous crop prediction typically has) and the whole
map. Per variant: the median time of one member on 2 ORT threads (contenders alternated, 5 rounds), and the error
against fp32 on the unknown cells: mean absolute difference of the wall probability and the share of cells whose
wall / free decision at 0.5 flips.

    NUMBA_NUM_THREADS=1 python scripts/bench_precision.py --out benchmarks/realtime

Writes ``OUT/precision.md`` and ``OUT/precision.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import write_json, write_text

ROOT = Path(__file__).resolve().parents[1]


def _variants(source: Path, folder: Path) -> dict[str, Path]:
    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic
    from onnxruntime.transformers import float16

    int8 = folder / "int8.onnx"
    quantize_dynamic(str(source), str(int8), weight_type=QuantType.QInt8, op_types_to_quantize=["Conv", "MatMul"])
    fp16 = folder / "fp16.onnx"
    onnx.save(float16.convert_float_to_float16(onnx.load(str(source)), keep_io_types=True), str(fp16))
    return {"fp32": source, "int8": int8, "fp16": fp16}


def _inputs() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, observed int8 [H, W], encoded float32 [1, 3, H', W'] padded) of the held-out train floors."""
    from superex_deploy.evaluation import run_benchmark_episode, train_scenarios
    from superex_deploy.onboard.prediction.inference import MODEL_CHANNELS, ModelKind, encode_map
    from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
    from superex_deploy.sim.exploration import ExplorationConfig

    out = []
    for name, start in train_scenarios(4, 1, 40000, heldout=True):
        result = run_benchmark_episode(name, start, "nearest", ObservedAsPrediction(), steps=200,
                                       cfg=ExplorationConfig(iou_every=0)).result
        observed = result.final_observed
        r, c = (int(v) for v in result.poses[-1])
        top, left = max(0, min(r - 128, observed.shape[0] - 256)), max(0, min(c - 128, observed.shape[1] - 256))
        for label, crop in (("crop256", observed[top:top + 256, left:left + 256]), ("whole", observed)):
            crop = np.ascontiguousarray(crop)
            encoded = encode_map(crop, np.zeros(crop.shape, np.float32), ModelKind.LAMA_BP)
            rows, cols = (-(-n // 8) * 8 for n in crop.shape)
            padded = np.zeros((1, 3, rows, cols), np.float32)
            padded[:, MODEL_CHANNELS[ModelKind.LAMA_BP].index("unknown")] = 1.0
            padded[:, :, :crop.shape[0], :crop.shape[1]] = encoded
            out.append((f"{name}/{label}", crop, padded))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "realtime")
    args = parser.parse_args()
    from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR, SessionConfig, make_session
    from superex_deploy.onboard.types import UNKNOWN

    inputs = _inputs()
    with tempfile.TemporaryDirectory() as tmp:
        paths = _variants(Path(DEFAULT_MODEL_DIR) / "lama_bp_0.onnx", Path(tmp))
        sessions = {k: make_session(p, SessionConfig(intra_op_threads=2)) for k, p in paths.items()}
        names = list(sessions)
        times = {(k, label): [] for k in names for label, *_ in inputs}
        outputs = {}
        for round_ in range(args.rounds):
            for key in (names if round_ % 2 == 0 else names[::-1]):
                session = sessions[key]
                feed = session.get_inputs()[0].name
                for label, observed, padded in inputs:
                    clock = time.perf_counter()
                    result = session.run(None, {feed: padded})[0]
                    times[(key, label)].append(time.perf_counter() - clock)
                    outputs[(key, label)] = np.clip(result[0, 0, :observed.shape[0], :observed.shape[1]], 0, 1)
        rows = {}
        for key in names:
            for size in ("crop256", "whole"):
                labels = [label for label, *_ in inputs if label.endswith(size)]
                ms = [1e3 * float(np.median(times[(key, label)])) for label in labels]
                ref_ms = [1e3 * float(np.median(times[("fp32", label)])) for label in labels]
                errors, flips = [], []
                for label, observed, _ in inputs:
                    if label not in labels:
                        continue
                    unknown = observed == UNKNOWN
                    a, b = outputs[("fp32", label)][unknown], outputs[(key, label)][unknown]
                    errors.append(float(np.abs(a - b).mean()))
                    flips.append(float(np.mean((a >= 0.5) != (b >= 0.5))))
                rows[f"{key}/{size}"] = {"median_ms": float(np.median(ms)),
                                         "time_ratio": float(np.median(np.array(ms) / np.array(ref_ms))),
                                         "mean_abs_error": float(np.mean(errors)), "flipped_share": float(np.mean(flips))}
    lines = ["One LaMa-BP member, 2 ORT threads, median over maps of the median of "
             f"{args.rounds} alternated rounds; error on unknown cells against fp32.", "",
             "| precision / input | ms | time / fp32 | mean abs error | wall/free flips |", "|---|---:|---:|---:|---:|"]
    for key, row in rows.items():
        lines.append(f"| {key} | {row['median_ms']:.1f} | {row['time_ratio']:.2f} | {row['mean_abs_error']:.4f} | "
                     f"{100 * row['flipped_share']:.2f} % |")
    text = "\n".join(lines) + "\n"
    write_text(args.out / "precision.md", text)
    write_json(args.out / "precision.json", {"rows": rows, "inputs": [l for l, *_ in inputs]})
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
