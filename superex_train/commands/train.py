"""Generate training data, train the Pix2Pix filter or a LaMa ensemble (or write a synthetic dataset for a sanity
run)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from superex_deploy.commands.options import add_parallel_options, make_backend


def _common(parser: argparse.ArgumentParser, epochs: int, batch_size: int, lr: float, wall_weight: float,
            lr_schedule: str = "constant") -> None:
    parser.add_argument("--data", required=True, type=Path, help="dataset folder (superex_train.datasets format)")
    parser.add_argument("--out", required=True, type=Path, help="run folder (checkpoint.pt, history.json)")
    parser.add_argument("--epochs", type=int, default=epochs)
    parser.add_argument("--batch-size", type=int, default=batch_size)
    parser.add_argument("--lr", type=float, default=lr)
    parser.add_argument("--wall-weight", type=float, default=wall_weight,
                        help="loss weight of a wall cell relative to a free cell")
    parser.add_argument("--val-fraction", type=float, default=0.2,
                        help="share of samples (whole buildings) held out with --random-heldout")
    parser.add_argument("--random-heldout", action="store_true",
                        help="hold out random buildings of the dataset instead of the package's fixed held-out "
                             "KTH buildings (superex_train.generate.heldout_buildings)")
    parser.add_argument("--no-augment", action="store_true", help="no random rotations / reflections")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--device", default="cpu", help="cpu (the reference), cuda[:n], or auto")
    parser.add_argument("--max-batches", type=int, default=0, help="batches per epoch (0: all)")
    parser.add_argument("--fresh", action="store_true", help="ignore an existing checkpoint in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--lr-schedule", choices=("constant", "cosine"), default=lr_schedule,
                        help="per-epoch learning rate: constant, or cosine decay to 0 over --epochs")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="model", required=True)
    data = sub.add_parser("data", help="generate a dataset from exploration episodes on the KTH train maps")
    data.add_argument("what", choices=("pix2pix", "lama"),
                      help="pix2pix: BP windows -> hidden walls; lama: map tiles (writes OUT/lama_bp, OUT/lama_los)")
    data.add_argument("--out", required=True, type=Path, help="dataset folder (lama: parent of both datasets)")
    data.add_argument("--pix2pix-model", type=Path, default=None,
                      help="lama: the Pix2Pix .onnx that filters the evidence (default: exported/pix2pix.onnx)")
    data.add_argument("--laplacian", action="store_true",
                      help="lama: filter the evidence with the Laplacian baseline instead (ablations)")
    data.add_argument("--episodes-per-map", type=int, default=1)
    data.add_argument("--steps", type=int, default=300)
    data.add_argument("--sample-every", type=int, default=12)
    data.add_argument("--window", type=int, default=160, help="pix2pix window side (cells)")
    data.add_argument("--tile", type=int, default=128, help="lama tile side (cells)")
    data.add_argument("--tiles-per-sample", type=int, default=2)
    data.add_argument("--maps", nargs="*", default=None, help="train map names (default: all)")
    add_parallel_options(data)
    data.add_argument("--seed", type=int, default=0)
    data.add_argument("--quiet", action="store_true", help="no progress bar")
    pix2pix = sub.add_parser("pix2pix", help="the back-projection filter (U-Net + PatchGAN)")
    _common(pix2pix, epochs=8, batch_size=16, lr=1e-3, wall_weight=12.0, lr_schedule="cosine")
    pix2pix.add_argument("--l1-weight", type=float, default=1.0)
    pix2pix.add_argument("--no-adversarial", action="store_true", help="no discriminator")
    pix2pix.add_argument("--adversarial-weight", type=float, default=0.01)
    pix2pix.add_argument("--bce-weight", type=float, default=1.0,
                         help="weight of a wall-weighted BCE term on the logits (0: none)")
    pix2pix.add_argument("--dice-weight", type=float, default=1.0,
                         help="weight of a soft Dice term pooled over each batch (0: none)")
    pix2pix.add_argument("--input-encoding", choices=("linear", "log"), default="log",
                         help="how the back-projection window is fed (linear: 2x-1; log: log-compressed)")
    pix2pix.add_argument("--channels", type=int, nargs="+", default=[16, 32, 64, 96, 96],
                         help="U-Net encoder channels, one per stride-2 stage")

    lama = sub.add_parser("lama", help="a LaMa (FFC) ensemble, one run folder per member")
    _common(lama, epochs=16, batch_size=16, lr=1e-3, wall_weight=10.0)
    lama.add_argument("--kind", choices=("bp", "los"), default="bp",
                      help="bp: observed map + filtered back-projection; los: observed map only (baselines)")
    lama.add_argument("--members", type=int, default=3,
                      help="ensemble members, trained one after the other on disjoint parts of the training split")
    lama.add_argument("--only-member", type=int, default=None,
                      help="train just this member (e.g. to train the members in parallel processes)")
    lama.add_argument("--focal-gamma", type=float, default=0.0)
    lama.add_argument("--l1-weight", type=float, default=1.0)
    lama.add_argument("--known-weight", type=float, default=0.1, help="loss weight of observed cells")
    lama.add_argument("--base-channels", type=int, default=16)
    lama.add_argument("--max-channels", type=int, default=96)
    lama.add_argument("--blocks", type=int, default=5, help="FFC residual blocks")
    lama.add_argument("--init-from", default="",
                      help="start each member from this LaMa checkpoint ('{member}' is replaced by the member "
                           "index), e.g. exported/checkpoints/lama_los_{member}.pt to fine-tune LaMa-BP from "
                           "LaMa-LOS (input channels matched by name; a new channel starts with zero weights)")

    synthetic = sub.add_parser("synthetic", help="write a synthetic dataset (random floor plans; sanity runs only)")
    synthetic.add_argument("--kind", choices=("pix2pix", "lama_bp", "lama_los"), required=True)
    synthetic.add_argument("--samples", type=int, default=512)
    synthetic.add_argument("--tile", type=int, default=64, help="sample side (cells)")
    synthetic.add_argument("--seed", type=int, default=0)
    synthetic.add_argument("--out", required=True, type=Path)

    calibrate = sub.add_parser("calibrate", help="fit the LaMa ensembles' probability calibration (Platt scaling) "
                                                 "on exploration episodes of the training buildings")
    calibrate.add_argument("--models", type=Path, default=None,
                           help="model folder with the uncalibrated ensembles (default: exported/)")
    calibrate.add_argument("--kinds", nargs="+", choices=("bp", "los"), default=["bp", "los"])
    calibrate.add_argument("--out", required=True, type=Path, help="calibration JSON (for superex export)")
    calibrate.add_argument("--max-maps", type=int, default=0,
                           help="use the first N calibration maps (0: every train map outside the held-out "
                                "buildings)")
    calibrate.add_argument("--steps", type=int, default=400)
    calibrate.add_argument("--jobs", type=int, default=max(1, os.cpu_count() or 1), help="worker processes")
    calibrate.add_argument("--seed", type=int, default=0)
    calibrate.add_argument("--keep-from", type=Path, default=None,
                           help="a calibration JSON whose other kinds are written beside the fitted ones (an "
                                "ensemble that was not retrained keeps its fit)")


def run(args: argparse.Namespace) -> int:
    from superex_deploy.onboard.prediction.inference import DEFAULT_MODEL_DIR, ModelKind

    if args.model == "data":
        from superex_train.generate import GenerationConfig, generate_lama, generate_pix2pix

        cfg = GenerationConfig(maps=tuple(args.maps or ()), episodes_per_map=args.episodes_per_map,
                               steps=args.steps, sample_every=args.sample_every, window_cells=args.window,
                               tile_cells=args.tile, tiles_per_sample=args.tiles_per_sample, jobs=args.jobs,
                               seed=args.seed)
        backend = make_backend(args) if args.backend == "ray" else None  # local: cfg.jobs processes
        if args.what == "pix2pix":
            infos = [generate_pix2pix(args.out, cfg, progress=not args.quiet, backend=backend)]
        else:
            model = None if args.laplacian else (args.pix2pix_model or DEFAULT_MODEL_DIR / "pix2pix.onnx")
            infos = list(generate_lama(args.out / "lama_bp", args.out / "lama_los", model, cfg,
                                       progress=not args.quiet, backend=backend))
        for info in infos:
            print(f"wrote {info.count} {info.kind.value} samples of {info.tile_hw} to {info.directory} "
                  f"(data sha256 {info.data_sha256[:12]})")
        return 0

    if args.model == "calibrate":
        from superex_train.calibration import CalibrationConfig, calibration_maps, calibrate, read_calibration

        if args.max_maps < 0:
            raise ValueError(f"--max-maps must be >= 0, got {args.max_maps}")
        maps = tuple(calibration_maps(CalibrationConfig()))
        cfg = CalibrationConfig(maps=maps[:args.max_maps] if args.max_maps else maps, steps=args.steps,
                                seed=args.seed)
        kinds = [ModelKind.LAMA_BP if k == "bp" else ModelKind.LAMA_LOS for k in args.kinds]
        keep = read_calibration(args.keep_from) if args.keep_from is not None else None
        result = calibrate(kinds, args.models or DEFAULT_MODEL_DIR, cfg, args.jobs, args.out, keep=keep)
        for kind, fit in result.items():
            if kind not in kinds:
                print(f"{kind.value}: kept from {args.keep_from}")
                continue
            print(f"{kind.value}: logit_scale {fit.logit_scale:.3f}, logit_offset {fit.logit_offset:.3f} on "
                  f"{fit.cells:,} cells ({fit.wall_fraction:.1%} walls); NLL {fit.nll_before:.3f} -> "
                  f"{fit.nll_after:.3f}; predicted walls at 0.5 {fit.predicted_walls_before:.1%} -> "
                  f"{fit.predicted_walls_after:.1%}")
        print(f"wrote {args.out}")
        return 0

    if args.model == "synthetic":
        from superex_train.datasets import write_synthetic_dataset

        info = write_synthetic_dataset(args.out, ModelKind(args.kind), args.samples, args.tile, args.seed)
        print(f"wrote {info.count} {info.kind.value} samples of {info.tile_hw} to {args.out} "
              f"(data sha256 {info.data_sha256[:12]})")
        return 0

    from superex_train.models import LamaConfig, Pix2PixConfig
    from superex_train.training import LamaTrainConfig, Pix2PixTrainConfig, train_lama, train_pix2pix

    common = dict(data_dir=str(args.data), epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
                  wall_weight=args.wall_weight, val_fraction=args.val_fraction, augment=not args.no_augment,
                  seed=args.seed, threads=args.threads, max_batches=args.max_batches, progress=not args.quiet,
                  l1_weight=args.l1_weight, device=args.device, lr_schedule=args.lr_schedule)
    if not args.random_heldout:
        from superex_train.generate import heldout_buildings

        common["val_groups"] = heldout_buildings()
    if args.model == "pix2pix":
        from superex_train.datasets import read_index

        window = read_index(args.data).tile_hw[0]
        cfg = Pix2PixTrainConfig(out_dir=str(args.out), model=Pix2PixConfig(window_cells=window,
                                                                            channels=tuple(args.channels)),
                                 adversarial=not args.no_adversarial,
                                 adversarial_weight=args.adversarial_weight, bce_weight=args.bce_weight,
                                 dice_weight=args.dice_weight,
                                 input_encoding=args.input_encoding, **common)
        result = train_pix2pix(cfg, resume=not args.fresh)
        print(json.dumps(result.history[-1] if result.history else {}, indent=1))
        print(f"checkpoint: {result.checkpoint}")
        return 0

    if args.members < 1:
        raise ValueError(f"--members must be >= 1, got {args.members}")
    kind = ModelKind.LAMA_BP if args.kind == "bp" else ModelKind.LAMA_LOS
    model = LamaConfig(in_channels=3 if kind is ModelKind.LAMA_BP else 2, base_channels=args.base_channels,
                       max_channels=args.max_channels, n_blocks=args.blocks)
    if args.only_member is not None and not 0 <= args.only_member < args.members:
        raise ValueError(f"--only-member must lie in [0, {args.members}), got {args.only_member}")
    for member in range(args.members) if args.only_member is None else [args.only_member]:
        cfg = LamaTrainConfig(out_dir=str(args.out / f"member_{member}"), kind=kind, model=model, member=member,
                              focal_gamma=args.focal_gamma, known_weight=args.known_weight,
                              subsets=args.members, init_from=args.init_from,
                              **common)
        result = train_lama(cfg, resume=not args.fresh)
        last = result.history[-1] if result.history else {}
        print(f"member {member}: {json.dumps(last)}\ncheckpoint: {result.checkpoint}")
    return 0
