"""ONNX export of the trained generators, with metadata and a manifest.

Each generator is wrapped in :class:`WallProbabilityModel` (logits -> sigmoid probabilities) and exported at
opset 18 with one named input (``bp_window`` for Pix2Pix, ``map_channels`` for LaMa), one named output
(``wall_probability``) and dynamic axes: the batch for Pix2Pix (its window size is fixed), batch, height and
width for LaMa. The metadata of :data:`superex_deploy.onboard.prediction.inference.METADATA_KEYS` goes into ``metadata_props``,
the model is checked with ``onnx.checker``, and one ONNX Runtime run on the export's dummy input (for LaMa also
on a second, non-square size) must match torch to ``parity_atol``. :func:`export_models` writes a folder of
models and its ``manifest.json`` (file, kind, member, sha256, bytes per model, and the reference ``.npz``
of the post-export check, so parity can be re-tested from the folder alone).

Exporter choice (measured with torch 2.13, onnxruntime 1.31, 2 CPU threads; ``scripts/bench_models.py``):

* ``torch.fft.rfft2`` cannot be exported by the TorchScript exporter ("aten::fft_rfft2 ... not supported");
  the dynamo exporter maps it to ONNX ``DFT`` (parity 6e-8) but ONNX Runtime then runs the default LaMa about
  3x slower than torch eager on a 448 x 1328 map.
* The Fourier unit written as DFT-matrix products (:func:`superex_train.models.rfft2_ortho`) exports with
  either exporter, keeps dynamic height and width, and runs about 1.3-1.4x faster in ONNX Runtime than in torch.
* Both exporters give the same parity and about the same ORT speed for it; the TorchScript exporter (deprecated
  by torch, still present in the pinned 2.13) exports the default LaMa in ~5 s against 30-100 s for dynamo and
  writes one self-contained file, so it is the default; :attr:`Exporter.DYNAMO` stays selectable (and is the
  only way to export :attr:`~superex_train.models.SpectralBackend.TORCH_FFT`).
"""

from __future__ import annotations

import dataclasses
import enum
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import nn

import superex_deploy
from superex_deploy.files import write_atomically
from superex_deploy.onboard.prediction.inference import (FORMAT_VERSION, MANIFEST_NAME, MODEL_CHANNELS, NORMALISATION, RESOLUTION_M,
                                      BpEncoding, ModelKind, SessionConfig, make_session, sha256_file)
from superex_train.models import (LamaConfig, LamaGenerator, Pix2PixConfig, SpectralBackend, UNetGenerator,
                                  calibrate_batchnorm, count_parameters)
from superex_train.calibration import LogitCalibration
from superex_train.training import CHECKPOINT_NAME, build_generator, load_checkpoint

__all__ = ["Exporter", "ExportConfig", "WallProbabilityModel", "ExportRecord", "INPUT_NAMES", "OUTPUT_NAME",
           "export_generator", "export_checkpoint", "export_models", "write_manifest", "model_file_name",
           "untrained_generator"]

PathLike = Union[str, Path]

INPUT_NAMES = {ModelKind.PIX2PIX: "bp_window", ModelKind.LAMA_BP: "map_channels", ModelKind.LAMA_LOS: "map_channels"}
OUTPUT_NAME = "wall_probability"


class Exporter(enum.Enum):
    """Which torch ONNX exporter writes the graph."""

    TORCHSCRIPT = "torchscript"
    """``torch.onnx.export(..., dynamo=False)`` with ``dynamic_axes`` (default: fast, one file)."""
    DYNAMO = "dynamo"
    """``torch.onnx.export(..., dynamo=True)`` with ``dynamic_shapes``."""


@dataclass(frozen=True)
class ExportConfig:
    """Export settings.

    Attributes:
        opset: ONNX opset (18: opset 20+ with dynamic shapes has written wrong ``DFT`` output shapes).
        exporter: :class:`Exporter`.
        spectral: Fourier backend LaMa checkpoints are rebuilt with before export (the weights are the same
            for both backends).
        parity_atol: the ORT run after export must match torch within this (absolute, on probabilities).
        seed: seed of the dummy inputs.
    """

    opset: int = 18
    exporter: Exporter = Exporter.TORCHSCRIPT
    spectral: SpectralBackend = SpectralBackend.MATMUL
    parity_atol: float = 1e-4
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.exporter, Exporter) or not isinstance(self.spectral, SpectralBackend):
            raise ValueError("ExportConfig.exporter must be an Exporter and spectral a SpectralBackend")
        if self.opset < 17:
            raise ValueError(f"ExportConfig.opset must be >= 17 (LayerNorm-era ops, DFT), got {self.opset}")


class WallProbabilityModel(nn.Module):
    """Export wrapper: ``sigmoid(logit_scale * z + logit_offset)`` of a generator's wall logits ``z``, so the
    graph outputs (calibrated, :mod:`superex_train.calibration`) probabilities; identity calibration by default."""

    def __init__(self, generator: nn.Module, calibration: Optional[LogitCalibration] = None):
        super().__init__()
        self.generator = generator
        calibration = calibration or LogitCalibration()
        self.logit_scale, self.logit_offset = float(calibration.logit_scale), float(calibration.logit_offset)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logits = self.generator(x)
        if (self.logit_scale, self.logit_offset) != (1.0, 0.0):
            logits = logits * self.logit_scale + self.logit_offset
        return torch.sigmoid(logits)


@dataclass(frozen=True)
class ExportRecord:
    """One exported file: where, what, its sha256 and size, the generator's parameter count, the largest
    absolute difference between ONNX Runtime and torch seen in the post-export check, and the ``.npz`` of that
    check's inputs and torch outputs (``input_i``, ``output_i``), kept so that parity can be re-checked later
    without the checkpoint."""

    path: Path
    kind: ModelKind
    member: int
    sha256: str
    bytes: int
    parameters: int
    max_abs_error: float
    training_data_sha256: str
    reference: Path


def model_file_name(kind: ModelKind, member: int) -> str:
    """``pix2pix.onnx``, ``lama_bp_<member>.onnx`` or ``lama_los_<member>.onnx``."""
    return "pix2pix.onnx" if kind is ModelKind.PIX2PIX else f"{kind.value}_{member}.onnx"


def _kind_of(generator: nn.Module, kind: ModelKind) -> None:
    if kind is ModelKind.PIX2PIX:
        if not isinstance(generator, UNetGenerator):
            raise ValueError(f"a pix2pix export needs a UNetGenerator, got {type(generator).__name__}")
        return
    if not isinstance(generator, LamaGenerator):
        raise ValueError(f"a {kind.value} export needs a LamaGenerator, got {type(generator).__name__}")
    if generator.cfg.in_channels != len(MODEL_CHANNELS[kind]):
        raise ValueError(f"a {kind.value} model takes {len(MODEL_CHANNELS[kind])} channels, this generator takes "
                         f"{generator.cfg.in_channels}")


def dummy_inputs(generator: nn.Module, kind: ModelKind, seed: int = 0) -> list[torch.Tensor]:
    """Inputs of the export and of its check: one window batch for Pix2Pix; two LaMa maps of different,
    non-square sizes (the second one checks the dynamic height and width)."""
    rng = torch.Generator().manual_seed(seed)
    if kind is ModelKind.PIX2PIX:
        size = generator.cfg.window_cells
        return [torch.rand(2, 1, size, size, generator=rng) * 2.0 - 1.0]
    m = generator.cfg.size_multiple
    out = []
    for rows, cols in ((4 * m, 6 * m), (3 * m, 5 * m)):
        x = (torch.rand(1, generator.cfg.in_channels, rows, cols, generator=rng) < 0.3).float()
        if kind is ModelKind.LAMA_BP:
            x[:, 1] = torch.rand(rows, cols, generator=rng)
        out.append(x)
    return out


def _metadata(generator: nn.Module, kind: ModelKind, member: int, training_data_sha256: str,
              cfg: ExportConfig, bp_encoding: BpEncoding, calibration: LogitCalibration) -> dict[str, str]:
    metadata = {
        "format_version": FORMAT_VERSION,
        "model_kind": kind.value,
        "channels": json.dumps(list(MODEL_CHANNELS[kind])),
        "normalisation": bp_encoding.description if kind is ModelKind.PIX2PIX else NORMALISATION[kind],
        "resolution_m": repr(RESOLUTION_M),
        "output": f"{OUTPUT_NAME}: [N, 1, H, W] probability that the cell is a wall "
                  f"(sigmoid(logit_scale * logits + logit_offset))",
        "logit_scale": repr(float(calibration.logit_scale)),
        "logit_offset": repr(float(calibration.logit_offset)),
        "ensemble_member": str(int(member)),
        "training_data_sha256": training_data_sha256,
        "superex_version": superex_deploy.__version__,
        "architecture": json.dumps(generator.cfg.to_dict(), sort_keys=True),
        "exporter": f"{cfg.exporter.value}, opset {cfg.opset}, torch {torch.__version__}",
    }
    if kind is ModelKind.PIX2PIX:
        metadata["window_cells"] = str(generator.cfg.window_cells)
    else:
        metadata["size_multiple"] = str(generator.cfg.size_multiple)
        metadata["min_size"] = str(2 * generator.cfg.size_multiple)
    return metadata


def _shorten_names(graph) -> None:
    """Rename nodes and intermediate values to short ids (``n12``, ``v34``): the exporters' scoped names
    (``/generator/blocks.0/first/g2g/fourier/MatMul_output_0``) are ~13 % of a LaMa file. Graph inputs, outputs
    and initializers (the weights' names) keep theirs. Graphs with subgraphs are left as they are."""
    if any(attribute.type in (5, 10) for node in graph.node for attribute in node.attribute):  # GRAPH(S)
        return
    keep = {v.name for v in graph.input} | {v.name for v in graph.output} | {i.name for i in graph.initializer}
    mapping: dict[str, str] = {}
    for index, node in enumerate(graph.node):
        node.name = f"n{index}"
        for position, name in enumerate(node.output):
            if name and name not in keep:
                mapping.setdefault(name, f"v{len(mapping)}")
                node.output[position] = mapping[name]
    for node in graph.node:
        for position, name in enumerate(node.input):
            if name in mapping:
                node.input[position] = mapping[name]
    for value in graph.value_info:
        value.name = mapping.get(value.name, value.name)


def export_generator(generator: nn.Module, kind: ModelKind, path: PathLike, member: int = 0,
                     training_data_sha256: str = "untrained", cfg: ExportConfig = ExportConfig(),
                     bp_encoding: BpEncoding = BpEncoding.LINEAR,
                     calibration: Optional[LogitCalibration] = None) -> ExportRecord:
    """Export one generator (in eval mode) to ``path`` with metadata, then check it with one ORT run.

    Args:
        generator: a :class:`~superex_train.models.UNetGenerator` (PIX2PIX) or
            :class:`~superex_train.models.LamaGenerator` (LAMA_BP / LAMA_LOS) with the kind's channel count.
        kind: what it is.
        path: the ``.onnx`` file to write (its folder is created).
        member: ensemble member index (metadata ``ensemble_member``).
        training_data_sha256: the training dataset's ``data_sha256`` (``"untrained"`` for fresh models).
        cfg: export settings.
        bp_encoding: the input encoding a Pix2Pix generator was trained on (written as its ``normalisation``).
        calibration: Platt parameters applied to the logits in the graph (None: identity).

    Raises:
        ValueError: a generator that does not fit the kind, a TORCH_FFT LaMa with the TorchScript exporter,
            or an ORT result further than ``cfg.parity_atol`` from torch.
    """
    import onnx

    _kind_of(generator, kind)
    if (cfg.exporter is Exporter.TORCHSCRIPT and isinstance(generator, LamaGenerator)
            and generator.cfg.spectral is SpectralBackend.TORCH_FFT):
        raise ValueError("the TorchScript exporter cannot export torch.fft (aten::fft_rfft2); use "
                         "Exporter.DYNAMO or a SpectralBackend.MATMUL generator")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    generator = generator.eval()
    calibration = calibration or LogitCalibration()
    wrapper = WallProbabilityModel(generator, calibration).eval()
    inputs = dummy_inputs(generator, kind, cfg.seed)
    input_name = INPUT_NAMES[kind]
    spatial = kind is not ModelKind.PIX2PIX
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice, tracer warnings
        if cfg.exporter is Exporter.TORCHSCRIPT:
            axes = {0: "batch", 2: "height", 3: "width"} if spatial else {0: "batch"}
            torch.onnx.export(wrapper, (inputs[0],), str(path), input_names=[input_name],
                              output_names=[OUTPUT_NAME], opset_version=cfg.opset, dynamo=False,
                              do_constant_folding=True,
                              dynamic_axes={input_name: axes, OUTPUT_NAME: axes})
        else:
            dims = {0: torch.export.Dim("batch", min=1, max=1024)}
            if spatial:
                dims.update({2: torch.export.Dim.DYNAMIC, 3: torch.export.Dim.DYNAMIC})
            torch.onnx.export(wrapper, (inputs[0],), str(path), input_names=[input_name],
                              output_names=[OUTPUT_NAME], opset_version=cfg.opset, dynamo=True,
                              dynamic_shapes={"x": dims}, external_data=False, verbose=False)
    model = onnx.load(str(path))
    del model.metadata_props[:]
    for key, value in _metadata(generator, kind, member, training_data_sha256, cfg, bp_encoding,
                                calibration).items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    _shorten_names(model.graph)
    model.producer_name = "superex"
    model.doc_string = f"SuperEx {kind.value} model (member {member})"
    onnx.checker.check_model(model)
    onnx.save(model, str(path))

    session = make_session(path, SessionConfig())
    worst = 0.0
    reference = {}
    with torch.no_grad():
        for i, x in enumerate(inputs):
            expected = wrapper(x).numpy()
            got = session.run([OUTPUT_NAME], {input_name: x.numpy()})[0]
            if got.shape != expected.shape:
                raise ValueError(f"{path}: ONNX Runtime returned shape {got.shape}, torch {expected.shape}")
            worst = max(worst, float(np.abs(got - expected).max()))
            reference[f"input_{i}"], reference[f"output_{i}"] = x.numpy(), expected
    if worst > cfg.parity_atol:
        raise ValueError(f"{path}: ONNX Runtime differs from torch by {worst:.2e} > {cfg.parity_atol:.0e}")
    reference_path = path.with_name(path.stem + ".reference.npz")
    np.savez_compressed(reference_path, **reference)
    return ExportRecord(path=path, kind=kind, member=int(member), sha256=sha256_file(path),
                        bytes=path.stat().st_size, parameters=count_parameters(generator), max_abs_error=worst,
                        training_data_sha256=training_data_sha256, reference=reference_path)


def export_checkpoint(checkpoint_path: PathLike, path: PathLike, cfg: ExportConfig = ExportConfig(),
                      calibration: Optional[LogitCalibration] = None) -> ExportRecord:
    """Export the generator of a training checkpoint (``checkpoint.pt`` or the run folder holding it), with an
    optional logit calibration (:mod:`superex_train.calibration`)."""
    checkpoint = load_checkpoint(checkpoint_path)
    kind = checkpoint["kind"]
    model_config = dict(checkpoint["model_config"])
    if kind is not ModelKind.PIX2PIX:
        model_config["spectral"] = cfg.spectral.value
    generator = build_generator(kind, model_config)
    generator.load_state_dict(checkpoint["state"]["generator"])
    encoding = BpEncoding(checkpoint["train_config"].get("input_encoding", BpEncoding.LINEAR.value))
    return export_generator(generator, kind, path, int(checkpoint["member"]), checkpoint["training_data_sha256"],
                            cfg, encoding, calibration)


def write_manifest(directory: PathLike, records: Sequence[ExportRecord]) -> Path:
    """Write ``directory/manifest.json`` listing ``records`` (files relative to ``directory``)."""
    directory = Path(directory)
    def relative(path: Path) -> str:
        return path.resolve().relative_to(directory.resolve()).as_posix()

    models = [{"file": relative(r.path), "kind": r.kind.value, "member": r.member, "sha256": r.sha256,
               "resolution_m": RESOLUTION_M, "bytes": r.bytes, "parameters": r.parameters,
               "max_abs_error": r.max_abs_error,
               "training_data_sha256": r.training_data_sha256, "reference": relative(r.reference),
               "reference_sha256": sha256_file(r.reference)}
              for r in records]
    manifest = {"format_version": FORMAT_VERSION, "models": models, "total_bytes": sum(r.bytes for r in records)}
    path = directory / MANIFEST_NAME
    path.write_text(json.dumps(manifest, indent=1) + "\n")
    return path


CHECKPOINT_DIR = "checkpoints"
"""Sub-folder of a model folder with each exported model's generator checkpoint (the parity tests' torch side)."""


def _checkpoint_file(path: PathLike) -> Path:
    path = Path(path)
    return path / CHECKPOINT_NAME if path.is_dir() else path


def write_generator_checkpoint(checkpoint_path: PathLike, out_path: PathLike) -> Path:
    """Save the generator part of a training checkpoint: its weights and the run's record (model and training
    config, data hash, history), without the discriminator and optimiser states (a third of the size). This is
    what the parity tests rebuild the torch model from, next to the ONNX file exported from the same
    checkpoint."""
    checkpoint = load_checkpoint(checkpoint_path)
    out_path = Path(out_path)
    if out_path.exists() and out_path.resolve() == _checkpoint_file(checkpoint_path).resolve() \
            and set(checkpoint["state"]) == {"generator"} and not checkpoint["optimizers"]:
        return out_path  # exported from its own slim checkpoint: keep the file as it is
    slim = {key: value for key, value in checkpoint.items() if key not in ("state", "optimizers")}
    slim["kind"] = checkpoint["kind"].value
    slim["state"] = {"generator": checkpoint["state"]["generator"]}
    slim["optimizers"] = {}
    out_path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(out_path, lambda part: torch.save(slim, part))
    return out_path


def export_models(out_dir: PathLike, pix2pix: Optional[PathLike] = None, lama_bp: Sequence[PathLike] = (),
                  lama_los: Sequence[PathLike] = (), cfg: ExportConfig = ExportConfig(),
                  calibration: Optional[dict[ModelKind, LogitCalibration]] = None) -> list[ExportRecord]:
    """Export checkpoints into ``out_dir`` and write its manifest.

    Args:
        out_dir: the model folder (``exported/``).
        pix2pix: the Pix2Pix checkpoint, or None.
        lama_bp, lama_los: the ensembles' member checkpoints (each member's index comes from its checkpoint and
            must be unique within its ensemble).
        cfg: export settings.
        calibration: per LaMa kind, the Platt parameters its members' graphs apply (kinds absent: identity).

    Files that the folder's previous manifest listed and this export does not rewrite are deleted, so the
    folder never holds a model the manifest does not describe. Each model's generator checkpoint goes to
    ``out_dir/checkpoints/<model>.pt`` (:func:`write_generator_checkpoint`).
    """
    out_dir = Path(out_dir)
    records: list[ExportRecord] = []
    sources: list[Path] = []
    if pix2pix is not None:
        records.append(export_checkpoint(pix2pix, out_dir / model_file_name(ModelKind.PIX2PIX, 0), cfg))
        sources.append(Path(pix2pix))
    for kind, checkpoints in ((ModelKind.LAMA_BP, lama_bp), (ModelKind.LAMA_LOS, lama_los)):
        seen = set()
        for checkpoint_path in checkpoints:
            checkpoint = load_checkpoint(checkpoint_path)
            if checkpoint["kind"] is not kind:
                raise ValueError(f"{checkpoint_path} holds a {checkpoint['kind'].value} model, expected {kind.value}")
            member = int(checkpoint["member"])
            if member in seen:
                raise ValueError(f"two {kind.value} checkpoints are member {member}")
            seen.add(member)
            records.append(export_checkpoint(checkpoint_path, out_dir / model_file_name(kind, member), cfg,
                                             (calibration or {}).get(kind)))
            sources.append(Path(checkpoint_path))
    if not records:
        raise ValueError("nothing to export: give at least one checkpoint")
    for record, source in zip(records, sources):
        write_generator_checkpoint(source, out_dir / CHECKPOINT_DIR / f"{record.path.stem}.pt")
    old_manifest = out_dir / MANIFEST_NAME
    if old_manifest.is_file():
        written = {p.resolve() for r in records for p in (r.path, r.reference)}
        for item in json.loads(old_manifest.read_text()).get("models", []):
            for key in ("file", "reference"):
                if key not in item:
                    continue
                stale = (out_dir / item[key]).resolve()
                if stale not in written and stale.is_file() and stale.parent == out_dir.resolve():
                    stale.unlink()
    write_manifest(out_dir, records)
    return records


def untrained_generator(kind: ModelKind, model_config: Union[Pix2PixConfig, LamaConfig, None] = None,
                        seed: int = 0) -> nn.Module:
    """A freshly initialised generator of ``kind`` (eval mode) for tests, benchmarks and pipeline checks; never
    a result. Deterministic for a seed: the weights come from ``torch.manual_seed(seed)`` and the BatchNorm
    statistics are calibrated (:func:`~superex_train.models.calibrate_batchnorm`) on seeded random inputs, so
    the output varies like a trained network's instead of being nearly constant.

    Args:
        kind: what to build.
        model_config: the architecture (default: the default config; a LaMa config's ``in_channels`` is set to
            the kind's channel count).
        seed: weights and calibration seed.
    """
    torch.manual_seed(seed)
    if kind is ModelKind.PIX2PIX:
        generator = UNetGenerator(model_config or Pix2PixConfig())
    else:
        lama = dataclasses.replace(model_config or LamaConfig(), in_channels=len(MODEL_CHANNELS[kind]))
        generator = LamaGenerator(lama)
    batches = [torch.cat(dummy_inputs(generator, kind, seed + i)[:1] * 2) for i in range(2)]
    return calibrate_batchnorm(generator, batches)
