"""Export trained checkpoints to ONNX (metadata, parity check, manifest with sha256)."""

from __future__ import annotations

import argparse
from pathlib import Path


def _checkpoints(path: Path) -> list[Path]:
    """A checkpoint file, a run folder holding checkpoint.pt, or an ensemble folder of member_*/ runs."""
    if path.is_file():
        return [path]
    if (path / "checkpoint.pt").is_file():
        return [path / "checkpoint.pt"]
    members = sorted(path.glob("member_*/checkpoint.pt"))
    if not members:
        raise ValueError(f"{path} holds no checkpoint.pt and no member_*/checkpoint.pt")
    return members


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR

    parser.add_argument("--pix2pix", type=Path, help="Pix2Pix run folder or checkpoint")
    parser.add_argument("--lama-bp", type=Path, nargs="*", default=[],
                        help="LaMa (with back-projection) ensemble folder(s) or member checkpoints")
    parser.add_argument("--lama-los", type=Path, nargs="*", default=[],
                        help="line-of-sight LaMa ensemble folder(s) or member checkpoints")
    parser.add_argument("--out", type=Path, default=DEFAULT_MODEL_DIR, help="model folder (default: exported/)")
    parser.add_argument("--exporter", choices=("torchscript", "dynamo"), default="torchscript")
    parser.add_argument("--opset", type=int, default=18)
    parser.add_argument("--calibration", type=Path, default=None,
                        help="JSON from `superex train calibrate`: Platt parameters the LaMa graphs apply")


def run(args: argparse.Namespace) -> int:
    from superex_train.export import ExportConfig, Exporter, export_models

    from superex_train.calibration import read_calibration

    cfg = ExportConfig(opset=args.opset, exporter=Exporter(args.exporter))
    calibration = read_calibration(args.calibration) if args.calibration is not None else None
    records = export_models(args.out, pix2pix=args.pix2pix,
                            lama_bp=[c for p in args.lama_bp for c in _checkpoints(p)],
                            lama_los=[c for p in args.lama_los for c in _checkpoints(p)], cfg=cfg,
                            calibration=calibration)
    for r in records:
        print(f"{r.path.name:<16} {r.kind.value:<9} member {r.member}  {r.bytes / 1e6:5.2f} MB  "
              f"{r.parameters:>8,d} parameters  ORT-torch max |diff| {r.max_abs_error:.1e}  sha256 {r.sha256[:12]}")
    print(f"total {sum(r.bytes for r in records) / 1e6:.2f} MB; manifest: {args.out / 'manifest.json'}")
    return 0
