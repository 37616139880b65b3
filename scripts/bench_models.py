"""Latency of the exported models: ONNX Runtime against torch eager, same inputs, same run.

Table 1, per model: Pix2Pix on one robot-centred back-projection window (160 x 160, from a real SPAD scan at
an eval start pose), each LaMa member on the encoded observed map of every distinct eval-map size (padded as
``LamaEnsemble`` pads it; the observation is a short nearest-frontier episode's). torch runs the training
checkpoint (``exported/checkpoints``) under ``inference_mode`` with 2 threads; ONNX Runtime runs the exported
file through ``superex_deploy.inference.make_session`` with 2 intra-op threads. Median of ``--repeats`` timed
runs after one warm-up; the largest |ORT - torch| difference on those inputs is reported too.

Table 2: a whole 3-member ``LamaEnsemble.predict`` (encoding, padding, members, mean and variance) on the
largest eval map, the cost of one prediction at a frontier choice.

Table 3 (``--fft``, slower): the Fourier unit written with ``torch.fft`` exported by the dynamo exporter (ONNX
``DFT``) against the DFT-matrix-product unit, same weights, on the largest eval map.

Prints markdown tables and writes JSON (``--out``, default ``benchmarks/bench_models.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from superex_deploy.explore.episode import ExplorationConfig, run_episode  # noqa: E402
from superex_deploy.explore.planners import make_planner  # noqa: E402
from superex_deploy.explore.prediction import ObservedAsPrediction  # noqa: E402
from superex_deploy.inference import (DEFAULT_MODEL_DIR, LamaEnsemble, ModelKind, SessionConfig,  # noqa: E402
                                      crop_window, encode_bp_windows, encode_map, make_session, read_manifest)
from superex_deploy.maps import list_maps, load_map, start_poses  # noqa: E402
from superex_deploy.nlos import process_scan  # noqa: E402
from superex_deploy.spad import simulate_scan  # noqa: E402
from superex_train.training import build_generator, load_checkpoint  # noqa: E402

THREADS = 2


def median_ms(function, repeats: int) -> float:
    """Median wall time of ``function()`` over ``repeats`` calls after one warm-up call (milliseconds)."""
    function()
    times = []
    for _ in range(repeats):
        clock = time.perf_counter()
        function()
        times.append(time.perf_counter() - clock)
    return float(np.median(times) * 1e3)


def torch_generator(stem: str, spectral: str = "matmul") -> torch.nn.Module:
    """The checkpoint's generator with a sigmoid on top (what the ONNX file computes), eval mode."""
    checkpoint = load_checkpoint(DEFAULT_MODEL_DIR / "checkpoints" / f"{stem}.pt")
    config = dict(checkpoint["model_config"])
    if checkpoint["kind"] is not ModelKind.PIX2PIX:
        config["spectral"] = spectral
    generator = build_generator(checkpoint["kind"], config)
    generator.load_state_dict(checkpoint["state"]["generator"])
    return torch.nn.Sequential(generator, torch.nn.Sigmoid()).eval()


def observed_map(name: str, steps: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """int8 ``[H, W]`` observation after a short nearest-frontier episode from start pose 0, and a float32
    evidence map (the Laplacian-filtered back-projection of a scan at the last pose)."""
    grid = load_map(name)
    result = run_episode(grid, start_poses(name)[0], make_planner("nearest"), ObservedAsPrediction(), steps=steps,
                         cfg=ExplorationConfig(iou_every=0))
    scan = simulate_scan(grid, tuple(result.poses[-1]))
    return result.final_observed, process_scan(scan).bp_filtered


def padded(array: np.ndarray, multiple: int, minimum: int) -> np.ndarray:
    """``[1, C, H, W]`` padded at the bottom/right to multiples of ``multiple`` (unknown = last channel 1)."""
    rows, cols = (max(-(-n // multiple) * multiple, minimum) for n in array.shape[2:])
    out = np.zeros((1, array.shape[1], rows, cols), np.float32)
    out[:, -1] = 1.0
    out[:, :, :array.shape[2], :array.shape[3]] = array
    return out


def bench_model(path: Path, stem: str, kind: ModelKind, inputs: np.ndarray, repeats: int) -> dict:
    session = make_session(path, SessionConfig(intra_op_threads=THREADS))
    feed = {session.get_inputs()[0].name: inputs}
    model = torch_generator(stem)
    x = torch.from_numpy(inputs)
    with torch.inference_mode():
        expected = model(x).numpy()
        torch_ms = median_ms(lambda: model(x), repeats)
    ort_ms = median_ms(lambda: session.run(None, feed), repeats)
    error = float(np.abs(session.run(None, feed)[0] - expected).max())
    return {"model": stem, "kind": kind.value, "input": list(inputs.shape), "torch_ms": torch_ms, "ort_ms": ort_ms,
            "speed_up": torch_ms / ort_ms, "max_abs_diff": error}


def bench_fft_export(stem: str, inputs: np.ndarray, repeats: int) -> dict:
    """ORT latency of the same LaMa member exported with a torch.fft Fourier unit (dynamo, ONNX DFT)."""
    from superex_train.export import ExportConfig, Exporter, export_generator

    generator = torch_generator(stem, spectral="torch_fft")[0]
    kind = ModelKind(load_checkpoint(DEFAULT_MODEL_DIR / "checkpoints" / f"{stem}.pt")["kind"])
    with tempfile.TemporaryDirectory() as tmp:
        clock = time.perf_counter()
        record = export_generator(generator, kind, Path(tmp) / "fft.onnx",
                                  cfg=ExportConfig(exporter=Exporter.DYNAMO))
        export_s = time.perf_counter() - clock
        session = make_session(record.path, SessionConfig(intra_op_threads=THREADS))
        feed = {session.get_inputs()[0].name: inputs}
        ort_ms = median_ms(lambda: session.run(None, feed), repeats)
        output = session.run(None, feed)[0]
    with torch.inference_mode():
        expected = torch.sigmoid(generator(torch.from_numpy(inputs))).numpy()
        torch_ms = median_ms(lambda: generator(torch.from_numpy(inputs)), repeats)
    return {"model": f"{stem} (torch.fft, dynamo, ONNX DFT)", "input": list(inputs.shape), "torch_ms": torch_ms,
            "ort_ms": ort_ms, "speed_up": torch_ms / ort_ms, "max_abs_diff": float(np.abs(output - expected).max()),
            "export_s": export_s}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--models", nargs="*", default=None, help="model stems (default: all in the manifest)")
    parser.add_argument("--largest-only", action="store_true", help="LaMa on the largest eval map size only")
    parser.add_argument("--fft", action="store_true", help="also compare with a torch.fft / ONNX DFT export")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "bench_models.json")
    args = parser.parse_args(argv)
    torch.set_num_threads(THREADS)

    names = list_maps("eval")
    sizes = {}
    for name in names:  # one map per distinct padded size (what the network sees), largest first
        sizes.setdefault(tuple(-(-n // 8) * 8 for n in load_map(name).shape), name)
    largest = max(sizes, key=lambda s: s[0] * s[1])
    map_names = [sizes[largest]] if args.largest_only else [sizes[s] for s in sorted(sizes, key=lambda s: -s[0] * s[1])]
    observations = {name: observed_map(name) for name in map_names}
    grid = load_map(names[0])
    pose = start_poses(names[0])[0]
    window = crop_window(process_scan(simulate_scan(grid, pose)).bp, pose, 160)

    rows = []
    for entry in read_manifest(DEFAULT_MODEL_DIR):
        stem = entry.path.stem
        if args.models and stem not in args.models:
            continue
        if entry.kind is ModelKind.PIX2PIX:
            rows.append(bench_model(entry.path, stem, entry.kind, encode_bp_windows(window[None]), args.repeats))
            continue
        for name in map_names:
            observed, evidence = observations[name]
            encoded = encode_map(observed, evidence if entry.kind is ModelKind.LAMA_BP else None, entry.kind)
            row = bench_model(entry.path, stem, entry.kind, padded(encoded, 8, 16), args.repeats)
            rows.append({**row, "map": name, "map_shape": list(observed.shape)})
    print("\n## ONNX Runtime vs torch eager (2 threads, median ms)\n")
    print("| model | input | torch ms | ORT ms | torch / ORT | max abs diff |\n|---|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['model']} | {'x'.join(map(str, r['input']))} | {r['torch_ms']:.1f} | {r['ort_ms']:.1f} | "
              f"{r['speed_up']:.2f}x | {r['max_abs_diff']:.1e} |")
    speed_ups = [r["speed_up"] for r in rows]
    print(f"\nmedian speed-up over {len(rows)} (model, size) pairs: {np.median(speed_ups):.2f}x "
          f"(min {min(speed_ups):.2f}x, max {max(speed_ups):.2f}x)")

    ensemble_rows = []
    observed, evidence = observations[sizes[largest]]
    for kind in (ModelKind.LAMA_LOS, ModelKind.LAMA_BP):
        ensemble = LamaEnsemble.from_manifest(kind, session=SessionConfig(intra_op_threads=THREADS))
        ms = median_ms(lambda: ensemble.predict(observed, evidence), args.repeats)
        ensemble_rows.append({"ensemble": kind.value, "members": ensemble.members, "map": sizes[largest],
                              "map_shape": list(observed.shape), "predict_ms": ms})
    print(f"\n## One {ensemble_rows[0]['members']}-member ensemble prediction on the largest eval map "
          f"({sizes[largest]}, {observed.shape[0]} x {observed.shape[1]} cells; median ms)\n")
    print("| ensemble | predict ms |\n|---|---:|")
    for r in ensemble_rows:
        print(f"| {r['ensemble']} | {r['predict_ms']:.0f} |")

    fft_rows = []
    if args.fft:
        stem = "lama_los_0"
        encoded = padded(encode_map(observed, None, ModelKind.LAMA_LOS), 8, 16)
        matmul = next((r for r in rows if r["model"] == stem and r.get("map") == sizes[largest]), None) or \
            bench_model(DEFAULT_MODEL_DIR / f"{stem}.onnx", stem, ModelKind.LAMA_LOS, encoded, args.repeats)
        fft_rows = [{**matmul, "model": f"{stem} (DFT matrices, TorchScript exporter)"},
                    bench_fft_export(stem, encoded, args.repeats)]
        print("\n## Fourier unit: DFT-matrix products vs torch.fft / ONNX DFT (largest eval map, median ms)\n")
        print("| export | torch ms | ORT ms | torch / ORT | max abs diff |\n|---|---:|---:|---:|---:|")
        for r in fft_rows:
            print(f"| {r['model']} | {r['torch_ms']:.0f} | {r['ort_ms']:.0f} | {r['speed_up']:.2f}x | "
                  f"{r['max_abs_diff']:.1e} |")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"threads": THREADS, "repeats": args.repeats, "models": rows,
                                    "ensembles": ensemble_rows, "fourier_unit": fft_rows}, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
