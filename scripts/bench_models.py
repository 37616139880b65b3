"""Latency of the exported models: ONNX Runtime against torch eager, same inputs, same process.

What is measured
----------------
Table 1, one row per (model, input size):

* **Pix2Pix** on one robot-centred back-projection window (``window_cells`` x ``window_cells`` from the model's
  metadata, 160 x 160; batch 1), cut from a real SPAD scan (``simulate_scan`` + ``process_scan``) at the first
  start pose of the first eval map and encoded with ``encode_bp_windows`` in the encoding the model declares.
* **Each LaMa member** (``lama_bp_*``, ``lama_los_*``) on the encoded observed map of every eval-map size,
  padded exactly as :meth:`LamaEnsemble.padded_shape` pads it (bottom/right, to multiples of the model's
  ``size_multiple``, at least ``min_size``; the padding is unknown space) and deduplicated by padded shape. The
  observation is real: a short nearest-frontier episode (``--steps``, observed map taken as the prediction)
  from start pose 0 of one map of that size; the LAMA_BP evidence is the Laplacian-filtered back-projection of a
  SPAD scan at the episode's last pose.

torch runs the training checkpoint (``exported/checkpoints/<stem>.pt``; LaMa rebuilt with the ``matmul``
Fourier unit, as ``superex_train.export.export_checkpoint`` does) wrapped in the export's sigmoid, under
``torch.inference_mode()`` with ``torch.set_num_threads(2)``. ONNX Runtime runs the exported file through
``superex_deploy.onboard.prediction.inference.make_session`` with ``SessionConfig(intra_op_threads=2)``. Both get the same float32
array. After ``--warmup`` untimed calls of each, ``--repeats`` timed rounds run torch and ORT alternately (the
order flips every round, so slow drifts of the machine's load hit both alike); each call is timed on its own
with ``time.perf_counter`` after an untimed ``--settle`` pause (0.1 s): ONNX Runtime's intra-op threads keep
spinning for a while after a run, and a torch call started at once shares the cores with them (measured on
2 cores: torch about 10 % slower without the pause, which would inflate the torch / ORT ratio). Reported: the median of each (milliseconds), their ratio torch / ORT (> 1: ORT is
faster) and the largest |ORT - torch| over the whole output tensor (wall probabilities in [0, 1]).

Table 2: one whole 3-member ``LamaEnsemble.from_manifest(kind).predict(observed, evidence)`` per LaMa kind,
end to end (encoding, padding, every member, mean / variance, ``keep_observed``), on the LARGEST eval map
(median ms over ``--repeats`` after ``--warmup``): the cost of one map prediction at a frontier choice.

Table 3 (``--fft``, slower): the Fourier unit the committed LaMa uses (DFT-matrix products, exported by the
TorchScript exporter) against the same member rebuilt with a ``torch.fft`` Fourier unit and exported by the dynamo
exporter at opset 18 (ONNX ``DFT``), same weights, same padded largest-map input; torch eager and ORT latency of
each, the export time and the largest |ORT - torch| difference. This is the measurement behind the choice of the
matmul unit.

Prints markdown tables and writes JSON (``--out``, default ``benchmarks/model_speed/bench_models.json``). Timings depend on
the machine and its load; nothing here asserts on them.

Usage::

    .venv/bin/python scripts/bench_models.py                      # everything, 10 repeats
    .venv/bin/python scripts/bench_models.py --quick              # smoke test: largest size, 2 repeats
    .venv/bin/python scripts/bench_models.py --models pix2pix lama_bp_0 --sizes largest --repeats 5
    .venv/bin/python scripts/bench_models.py --fft                # also table 3
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

import torch

from superex_deploy.evaluation import run_benchmark_episode, write_json
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.prediction.inference import (MODEL_CHANNELS, BpEncoding, LamaEnsemble, ManifestEntry,
                                      ModelKind, SessionConfig, crop_window, encode_bp_windows, encode_map,
                                      make_session, read_manifest)
from superex_deploy.maps import list_maps, load_map, start_poses
from superex_deploy.onboard.nlos import process_scan
from superex_deploy.sim.spad import simulate_scan
from superex_train.calibration import LogitCalibration
from superex_train.export import ExportConfig, Exporter, WallProbabilityModel, export_generator
from superex_train.training import build_generator, load_checkpoint

ROOT = Path(__file__).resolve().parent.parent

THREADS = 2
"""torch threads and ONNX Runtime intra-op threads."""

MODEL_DIR = ROOT / "exported"
CHECKPOINT_DIR = MODEL_DIR / "checkpoints"
LAMA_KINDS = (ModelKind.LAMA_BP, ModelKind.LAMA_LOS)


@dataclass(frozen=True)
class Observation:
    """A real observation of one eval map.

    Attributes:
        map_name: the bundled map.
        observed: int8 ``[H, W]`` observed map after a short episode (-1 unknown, 0 free, 1 occupied).
        evidence: float32 ``[H, W]`` Laplacian-filtered back-projection in [0, 1] of a scan at the last pose.
        steps: steps the episode ran.
    """

    map_name: str
    observed: np.ndarray
    evidence: np.ndarray
    steps: int

    @property
    def known_fraction(self) -> float:
        """Fraction of the map's cells that are not unknown."""
        return float((self.observed != -1).mean())


# ----------------------------------------------------------------------------------------------- timing


def paired_median_ms(first: Callable[[], object], second: Callable[[], object], repeats: int,
                     warmup: int, settle_s: float = 0.0) -> tuple[float, float]:
    """Median wall time (milliseconds) of ``first()`` and of ``second()``.

    ``warmup`` untimed calls of each, then ``repeats`` rounds that call both, each call timed on its own; the
    order alternates between rounds so that load drifting during the run affects both alike. Before every
    timed call the process sleeps ``settle_s`` seconds (untimed) so that the other runtime's worker threads,
    which keep spinning for a while after a call, have gone idle.
    """
    for _ in range(warmup):
        first()
        second()
    times: tuple[list[float], list[float]] = ([], [])
    for round_ in range(repeats):
        order = ((0, first), (1, second)) if round_ % 2 == 0 else ((1, second), (0, first))
        for index, function in order:
            if settle_s > 0:
                time.sleep(settle_s)
            clock = time.perf_counter()
            function()
            times[index].append(time.perf_counter() - clock)
    return float(np.median(times[0]) * 1e3), float(np.median(times[1]) * 1e3)


def median_ms(function: Callable[[], object], repeats: int, warmup: int, settle_s: float = 0.0) -> float:
    """Median wall time (milliseconds) of ``function()`` over ``repeats`` calls after ``warmup`` untimed ones,
    with an untimed ``settle_s`` second sleep before each timed call."""
    for _ in range(warmup):
        function()
    times = []
    for _ in range(repeats):
        if settle_s > 0:
            time.sleep(settle_s)
        clock = time.perf_counter()
        function()
        times.append(time.perf_counter() - clock)
    return float(np.median(times) * 1e3)


# ----------------------------------------------------------------------------------------------- models


def torch_model(stem: str, spectral: str = "matmul") -> tuple[torch.nn.Module, ModelKind, dict]:
    """The checkpoint ``exported/checkpoints/<stem>.pt`` as the exported graph computes it.

    Args:
        stem: the model's file stem.
        spectral: Fourier unit LaMa is rebuilt with (``"matmul"``: what ``superex export`` writes;
            ``"torch_fft"``: the alternative table 3 measures). Ignored for Pix2Pix.

    Returns:
        ``(model, kind, checkpoint)``: ``model`` maps float32 ``[N, C, H, W]`` to wall probabilities
        ``[N, 1, H, W]`` (sigmoid of the generator's logits under the exported file's calibration), in eval
        mode; LaMa is built with the ``matmul`` Fourier unit, as ``export_checkpoint`` does.
    """
    checkpoint = load_checkpoint(CHECKPOINT_DIR / f"{stem}.pt")
    kind = checkpoint["kind"]
    config = dict(checkpoint["model_config"])
    if kind is not ModelKind.PIX2PIX:
        config["spectral"] = spectral
    generator = build_generator(kind, config)
    generator.load_state_dict(checkpoint["state"]["generator"])
    calibration = None
    path = MODEL_DIR / f"{stem}.onnx"
    if path.is_file():  # the graph's Platt calibration, so that max |ORT - torch| compares the same function
        import onnx

        metadata = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
        calibration = LogitCalibration(float(metadata.get("logit_scale", 1.0)),
                                       float(metadata.get("logit_offset", 0.0)))
    return WallProbabilityModel(generator, calibration).eval(), kind, checkpoint


def model_metadata(session) -> dict:
    """An ONNX Runtime session's ``metadata_props`` (written by ``superex export``)."""
    return dict(session.get_modelmeta().custom_metadata_map)


def lama_padded_shape(metadata: dict, shape: tuple[int, int]) -> tuple[int, int]:
    """``(rows, cols)`` a map of ``shape`` (cells) is padded to for a LaMa model with these metadata; the same
    rule as :meth:`LamaEnsemble.padded_shape` (multiples of ``size_multiple``, at least ``min_size``)."""
    multiple, minimum = int(metadata["size_multiple"]), int(metadata["min_size"])
    return tuple(max(-(-int(n) // multiple) * multiple, minimum) for n in shape)  # type: ignore[return-value]


def pad_encoded(encoded: np.ndarray, kind: ModelKind, padded_shape: tuple[int, int]) -> np.ndarray:
    """float32 ``[1, C, rows, cols]``: ``encoded`` ``[1, C, H, W]`` at the top left, the rest unknown space (as
    ``LamaEnsemble.predict_members`` pads)."""
    rows, cols = padded_shape
    out = np.zeros((1, encoded.shape[1], rows, cols), np.float32)
    out[:, MODEL_CHANNELS[kind].index("unknown")] = 1.0
    out[:, :, :encoded.shape[2], :encoded.shape[3]] = encoded
    return out


def bench_pair(entry: ManifestEntry, session, model: torch.nn.Module, inputs: np.ndarray, repeats: int,
               warmup: int, settle_s: float) -> dict:
    """torch and ORT latency of one model on one input, and the largest output difference.

    Args:
        entry: the model's manifest entry.
        session: its ONNX Runtime session.
        model: the torch module computing the same function (:func:`torch_model`).
        inputs: float32 ``[N, C, H, W]``.
        repeats, warmup, settle_s: see :func:`paired_median_ms`.

    Returns:
        A JSON-able row: ``torch_ms``, ``ort_ms`` (medians, ms), ``torch_over_ort``, ``max_abs_diff``.
    """
    feed = {session.get_inputs()[0].name: inputs}
    output_name = session.get_outputs()[0].name
    x = torch.from_numpy(inputs)

    def run_torch():
        with torch.inference_mode():
            return model(x)

    def run_ort():
        return session.run([output_name], feed)[0]

    expected = run_torch().numpy()
    actual = run_ort()
    torch_ms, ort_ms = paired_median_ms(run_torch, run_ort, repeats, warmup, settle_s)
    return {"model": entry.path.stem, "kind": entry.kind.value, "input": list(inputs.shape),
            "torch_ms": torch_ms, "ort_ms": ort_ms, "torch_over_ort": torch_ms / ort_ms,
            "max_abs_diff": float(np.abs(actual.astype(np.float64) - expected.astype(np.float64)).max())}


def bench_fourier_unit(stem: str, inputs: np.ndarray, repeats: int, warmup: int, settle_s: float) -> dict:
    """torch and ORT latency of LaMa member ``stem`` rebuilt with a ``torch.fft`` Fourier unit and exported by
    the dynamo exporter (ONNX ``DFT``, opset 18) to a temporary file.

    Args:
        stem: a LaMa member's file stem.
        inputs: float32 ``[1, C, rows, cols]``, already padded.
        repeats, warmup, settle_s: see :func:`paired_median_ms`.

    Returns:
        A row like :func:`bench_pair`'s plus ``export_s`` (seconds the export and its check took).
    """
    model, kind, checkpoint = torch_model(stem, spectral="torch_fft")
    with tempfile.TemporaryDirectory() as tmp:
        clock = time.perf_counter()
        calibration = LogitCalibration(model.logit_scale, model.logit_offset)
        record = export_generator(model.generator, kind, Path(tmp) / f"{stem}_fft.onnx",
                                  cfg=ExportConfig(exporter=Exporter.DYNAMO), calibration=calibration)
        export_s = time.perf_counter() - clock
        session = make_session(record.path, SessionConfig(intra_op_threads=THREADS))
        entry = ManifestEntry(path=record.path, kind=kind, member=0, sha256=record.sha256)
        row = bench_pair(entry, session, model, inputs, repeats, warmup, settle_s)
        del session
    return {**row, "model": f"{stem} (torch.fft, dynamo exporter, ONNX DFT)", "export_s": export_s}


# ----------------------------------------------------------------------------------------------- inputs


def observe(map_name: str, steps: int) -> Observation:
    """A real observation of ``map_name`` (see :class:`Observation`): ``steps`` nearest-frontier steps from
    start pose 0 with the observed map as the prediction, then one SPAD scan at the last pose."""
    grid = load_map(map_name)
    result = run_benchmark_episode(grid, start_poses(map_name)[0], "nearest", ObservedAsPrediction(), steps=steps,
                                   cfg=ExplorationConfig(iou_every=0)).result
    scan = simulate_scan(grid, tuple(int(v) for v in result.poses[-1]))
    return Observation(map_name=map_name, observed=result.final_observed,
                       evidence=process_scan(scan).bp_filtered.astype(np.float32), steps=len(result.poses))


def pix2pix_window(window_cells: int, encoding: BpEncoding) -> tuple[np.ndarray, str]:
    """Pix2Pix input float32 ``[1, 1, S, S]``: the raw back-projection of a SPAD scan at the first start pose of
    the first eval map, cropped around the robot and encoded; and the map's name."""
    name = list_maps("eval")[0]
    grid = load_map(name)
    pose = start_poses(name)[0]
    bp = process_scan(simulate_scan(grid, pose)).bp
    return encode_bp_windows(crop_window(bp, pose, window_cells)[None], encoding), name


def eval_sizes() -> list[tuple[str, tuple[int, int]]]:
    """``(map name, (rows, cols))`` of every eval map, largest area first (ties: list order)."""
    maps = [(name, tuple(load_map(name).shape)) for name in list_maps("eval")]
    return sorted(maps, key=lambda item: -item[1][0] * item[1][1])


def parse_sizes(text: str) -> Optional[int]:
    """``--sizes``: ``all`` (None), ``largest`` (1) or a count N >= 1 of the largest distinct padded sizes."""
    if text == "all":
        return None
    if text == "largest":
        return 1
    try:
        count = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--sizes takes 'all', 'largest' or a count, got {text!r}") from None
    if count < 1:
        raise argparse.ArgumentTypeError(f"--sizes count must be >= 1, got {count}")
    return count


# ----------------------------------------------------------------------------------------------- report


def print_model_table(rows: list[dict]) -> None:
    """Markdown table of :func:`bench_pair` rows."""
    print(f"\n## ONNX Runtime vs torch eager ({THREADS} threads, median ms)\n")
    print("| model | map (cells) | input | torch ms | ORT ms | torch / ORT | max abs diff |")
    print("|---|---|---|---:|---:|---:|---:|")
    for r in rows:
        where = f"{r['map']} ({r['map_shape'][0]}x{r['map_shape'][1]})" if "map_shape" in r else r.get("map", "")
        print(f"| {r['model']} | {where} | {'x'.join(map(str, r['input']))} | {r['torch_ms']:.1f} | "
              f"{r['ort_ms']:.1f} | {r['torch_over_ort']:.2f}x | {r['max_abs_diff']:.1e} |")
    if rows:
        ratios = [r["torch_over_ort"] for r in rows]
        print(f"\ntorch / ORT over {len(rows)} (model, size) pairs: median {np.median(ratios):.2f}x "
              f"(min {min(ratios):.2f}x, max {max(ratios):.2f}x); largest |ORT - torch| "
              f"{max(r['max_abs_diff'] for r in rows):.1e}")


def print_ensemble_table(rows: list[dict]) -> None:
    """Markdown table of the ensemble rows."""
    if not rows:
        return
    r0 = rows[0]
    print(f"\n## One ensemble prediction on the largest eval map ({r0['map']}, {r0['map_shape'][0]}x"
          f"{r0['map_shape'][1]} cells, padded {r0['padded_shape'][0]}x{r0['padded_shape'][1]}; ORT, "
          f"{THREADS} threads, median ms)\n")
    print("| ensemble | members | predict ms | per member ms |\n|---|---:|---:|---:|")
    for r in rows:
        print(f"| {r['ensemble']} | {r['members']} | {r['predict_ms']:.0f} | {r['predict_ms'] / r['members']:.0f} |")


def print_fourier_table(rows: list[dict]) -> None:
    """Markdown table of the Fourier-unit rows (``--fft``)."""
    if not rows:
        return
    r0 = rows[0]
    print(f"\n## Fourier unit: DFT-matrix products vs torch.fft / ONNX DFT ({r0['map']}, input "
          f"{'x'.join(map(str, r0['input']))}; {THREADS} threads, median ms)\n")
    print("| export | torch ms | ORT ms | torch / ORT | max abs diff | export s |\n|---|---:|---:|---:|---:|---:|")
    for r in rows:
        export_s = f"{r['export_s']:.0f}" if "export_s" in r else ""
        print(f"| {r['model']} | {r['torch_ms']:.0f} | {r['ort_ms']:.0f} | {r['torch_over_ort']:.2f}x | "
              f"{r['max_abs_diff']:.1e} | {export_s} |")


# ----------------------------------------------------------------------------------------------- main


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=None, help="timed runs per measurement (default 10; "
                        "--quick: 2)")
    parser.add_argument("--warmup", type=int, default=None, help="untimed runs before timing (default 2; --quick: 1)")
    parser.add_argument("--models", nargs="+", default=None, metavar="STEM",
                        help="model stems from the manifest, e.g. pix2pix lama_bp_0 (default: all); table 2 runs "
                             "for the LaMa kinds that have a selected member")
    parser.add_argument("--sizes", type=parse_sizes, default=None, metavar="all|largest|N",
                        help="LaMa input sizes: all distinct padded eval sizes (default), the largest, or the N "
                             "largest (--quick: largest)")
    parser.add_argument("--settle", type=float, default=0.1, metavar="S",
                        help="untimed sleep before every timed call, seconds (default 0.1; see the docstring)")
    parser.add_argument("--steps", type=int, default=100, help="episode steps of the observations (default 100)")
    parser.add_argument("--no-ensemble", action="store_true", help="skip table 2")
    parser.add_argument("--fft", action="store_true",
                        help="table 3: the matmul Fourier unit vs a torch.fft / ONNX DFT export (largest map)")
    parser.add_argument("--quick", action="store_true", help="smoke test: largest size only, 2 repeats, 1 warm-up")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "model_speed" / "bench_models.json")
    args = parser.parse_args(argv)
    repeats = args.repeats if args.repeats is not None else (2 if args.quick else 10)
    warmup = args.warmup if args.warmup is not None else (1 if args.quick else 2)
    size_limit = args.sizes if args.sizes is not None else (1 if args.quick else None)
    if repeats < 1 or warmup < 0 or args.steps < 1 or args.settle < 0:
        parser.error("--repeats and --steps must be >= 1, --warmup and --settle >= 0")

    torch.set_num_threads(THREADS)
    session_cfg = SessionConfig(intra_op_threads=THREADS)
    entries = read_manifest(MODEL_DIR)
    stems = [e.path.stem for e in entries]
    if args.models:
        unknown = sorted(set(args.models) - set(stems))
        if unknown:
            parser.error(f"--models {unknown} not in the manifest (it lists {stems})")
        entries = [e for e in entries if e.path.stem in args.models]

    maps = eval_sizes()
    largest_name, largest_shape = maps[0]
    observations: dict[str, Observation] = {}

    def observation(name: str) -> Observation:
        if name not in observations:
            observations[name] = observe(name, args.steps)
        return observations[name]

    rows = []
    for entry in entries:
        stem = entry.path.stem
        session = make_session(entry.path, session_cfg)
        metadata = model_metadata(session)
        model, kind, checkpoint = torch_model(stem)
        if kind is not entry.kind:
            raise ValueError(f"checkpoint {stem}.pt is a {kind.value} model, the manifest says {entry.kind.value}")
        if kind is ModelKind.PIX2PIX:
            encoding = BpEncoding.from_description(metadata["normalisation"])
            trained = checkpoint.get("train_config", {}).get("input_encoding", BpEncoding.LINEAR.value)
            if trained != encoding.value:
                print(f"warning: {stem}.onnx declares the {encoding.value} encoding, its checkpoint was trained "
                      f"with {trained}", file=sys.stderr)
            inputs, name = pix2pix_window(int(metadata["window_cells"]), encoding)
            rows.append({**bench_pair(entry, session, model, inputs, repeats, warmup, args.settle), "map": name})
            print(f"{stem}: done", file=sys.stderr, flush=True)
            continue
        # One map per distinct padded shape (what the network sees), largest first.
        by_padded: dict[tuple[int, int], tuple[str, tuple[int, int]]] = {}
        for name, shape in maps:
            by_padded.setdefault(lama_padded_shape(metadata, shape), (name, shape))
        chosen = list(by_padded.items())[:size_limit]
        for padded_shape, (name, shape) in chosen:
            obs = observation(name)
            encoded = encode_map(obs.observed, obs.evidence if kind is ModelKind.LAMA_BP else None, kind)
            inputs = pad_encoded(encoded, kind, padded_shape)
            row = bench_pair(entry, session, model, inputs, repeats, warmup, args.settle)
            rows.append({**row, "map": name, "map_shape": list(shape), "known_fraction": obs.known_fraction})
            print(f"{stem} {padded_shape[0]}x{padded_shape[1]}: done", file=sys.stderr, flush=True)
        del session, model

    ensemble_rows = []
    kinds = [k for k in LAMA_KINDS if any(e.kind is k for e in entries)]
    if not args.no_ensemble and kinds:
        obs = observation(largest_name)
        for kind in kinds:
            ensemble = LamaEnsemble.from_manifest(kind, MODEL_DIR, session=session_cfg)
            evidence = obs.evidence if kind is ModelKind.LAMA_BP else None
            ms = median_ms(lambda: ensemble.predict(obs.observed, evidence), repeats, warmup, args.settle)
            ensemble_rows.append({"ensemble": kind.value, "members": ensemble.members, "map": largest_name,
                                  "map_shape": list(largest_shape),
                                  "padded_shape": list(ensemble.padded_shape(largest_shape)),
                                  "known_fraction": obs.known_fraction, "predict_ms": ms})
            print(f"{kind.value} ensemble: done", file=sys.stderr, flush=True)
            del ensemble

    fourier_rows = []
    if args.fft:
        stem = next((e.path.stem for e in entries if e.kind is ModelKind.LAMA_LOS), None)
        if stem is None:
            parser.error("--fft needs a lama_los member among --models")
        obs = observation(largest_name)
        entry = next(e for e in entries if e.path.stem == stem)
        session = make_session(entry.path, session_cfg)
        inputs = pad_encoded(encode_map(obs.observed, None, ModelKind.LAMA_LOS), ModelKind.LAMA_LOS,
                             lama_padded_shape(model_metadata(session), largest_shape))
        model = torch_model(stem)[0]
        fourier_rows = [
            {**bench_pair(entry, session, model, inputs, repeats, warmup, args.settle),
             "model": f"{stem} (DFT matrices, TorchScript exporter; committed)"},
            bench_fourier_unit(stem, inputs, repeats, warmup, args.settle)]
        for row in fourier_rows:
            row.update(map=largest_name, map_shape=list(largest_shape))
        del session, model
        print("Fourier units: done", file=sys.stderr, flush=True)

    print_model_table(rows)
    print_ensemble_table(ensemble_rows)
    print_fourier_table(fourier_rows)

    import onnxruntime

    report = {
        "what": "median wall ms; torch eager (inference_mode) vs ONNX Runtime CPU, same inputs, same process",
        "threads": THREADS, "repeats": repeats, "warmup": warmup, "settle_s": args.settle,
        "episode_steps": args.steps,
        "quick": bool(args.quick),
        "versions": {"python": platform.python_version(), "torch": torch.__version__,
                     "onnxruntime": onnxruntime.__version__, "numpy": np.__version__},
        "machine": {"platform": platform.platform(), "processor": platform.processor()},
        "models": rows, "ensembles": ensemble_rows, "fourier_unit": fourier_rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, report, newline=True)
    try:
        shown = args.out.resolve().relative_to(ROOT)
    except ValueError:
        shown = args.out
    print(f"\nwrote {shown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
