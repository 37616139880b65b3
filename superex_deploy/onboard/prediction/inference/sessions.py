"""The one place that makes ONNX Runtime sessions (:class:`SessionConfig`, :func:`make_session`) and opens an
exported model file with its checks (:func:`load_model`).

Loading checks the file's sha256 against the manifest (or a hash the caller gives), then its ``metadata_props``
(:data:`~superex_deploy.onboard.prediction.inference.manifest.METADATA_KEYS`) against what the caller asked for, and raises
``ValueError`` naming the file and the mismatch for a missing, corrupt or mismatched model. Input and output tensor
names are read from the model, not assumed. ``onnxruntime`` is imported only when a session is made.
"""

from __future__ import annotations

import enum
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from superex_deploy.configs import JsonConfig
from superex_deploy.onboard.prediction.inference.encoding import NORMALISATION, BpEncoding
from superex_deploy.onboard.prediction.inference.manifest import FORMAT_VERSION, MODEL_CHANNELS, ModelKind, PathLike, sha256_file

__all__ = ["GraphOptimization", "SessionConfig", "make_session", "LoadedModel", "load_model", "available_cores",
           "ThreadBudget"]


class GraphOptimization(enum.Enum):
    """ONNX Runtime graph optimisation level."""

    DISABLED = "ORT_DISABLE_ALL"
    BASIC = "ORT_ENABLE_BASIC"
    EXTENDED = "ORT_ENABLE_EXTENDED"
    ALL = "ORT_ENABLE_ALL"


@dataclass(frozen=True)
class SessionConfig(JsonConfig):
    """How ONNX Runtime sessions are made (one factory for every model: :func:`make_session`).

    Attributes:
        intra_op_threads: threads inside one operator (0: ONNX Runtime's default, one per core).
        inter_op_threads: threads across independent operators (1: sequential execution).
        providers: execution providers in order of preference.
        graph_optimization: :class:`GraphOptimization` level.
        allow_spinning: let the intra-op threads busy-wait for work between operators (ONNX Runtime's
            default): each operator then starts without waking its threads (a LaMa member runs a little faster;
            measured in docs/benchmarks/models.md).
        stop_spinning_after_run: make the spinning threads stop at the end of every run
            (``session.force_spinning_stop``). Without it they keep spinning after a run and take the cores
            from the numba and numpy work the exploration loop does next (measured in docs/benchmarks/models.md).
    """

    intra_op_threads: int = 2
    inter_op_threads: int = 1
    providers: tuple[str, ...] = ("CPUExecutionProvider",)
    graph_optimization: GraphOptimization = GraphOptimization.ALL
    allow_spinning: bool = True
    stop_spinning_after_run: bool = True

    def __post_init__(self) -> None:
        if int(self.intra_op_threads) < 0 or int(self.inter_op_threads) < 0:
            raise ValueError(f"thread counts must be >= 0, got intra {self.intra_op_threads}, "
                             f"inter {self.inter_op_threads}")
        if not self.providers:
            raise ValueError("SessionConfig.providers must name at least one execution provider")
        if not isinstance(self.graph_optimization, GraphOptimization):
            raise ValueError(f"graph_optimization must be a GraphOptimization, got {self.graph_optimization!r}")


def available_cores() -> int:
    """The cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count`` where that does not
    exist): a container's or ``taskset``'s limit, not the machine's."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class ThreadBudget(JsonConfig):
    """How the cores given to the explorer are split between its control loop and its prediction worker, so that
    the two never ask for more threads than there are cores (oversubscribed cores stretch the step time's tail).

    With a worker thread, the worker gets ``max(1, cores // 2)`` threads (ONNX Runtime's intra-op threads of the
    predictor's sessions, numba's in the worker thread) and the control loop the rest, at least one (numba's
    threads in the thread that calls ``Explorer.step``): 2 cores give 1 and 1. Without one (the ``inline`` and
    ``simulated`` schedules) the control loop does everything and gets every core.

    Attributes:
        cores: the cores given (``available_cores()`` by default: the process's CPU affinity).
        worker: whether a prediction worker thread runs beside the control loop.
    """

    cores: int
    worker: bool

    def __post_init__(self) -> None:
        if isinstance(self.cores, bool) or not isinstance(self.cores, int) or self.cores < 1:
            raise ValueError(f"cores must be an integer >= 1, got {self.cores!r}")

    @classmethod
    def for_cores(cls, cores: Optional[int], worker: bool) -> "ThreadBudget":
        """The budget of ``cores`` cores (None: :func:`available_cores`)."""
        return cls(available_cores() if cores is None else cores, bool(worker))

    @property
    def worker_threads(self) -> int:
        """Threads of the prediction worker (0 without one)."""
        return max(1, self.cores // 2) if self.worker else 0

    @property
    def control_threads(self) -> int:
        """numba threads of the control loop."""
        return max(1, self.cores - self.worker_threads)

    def session(self, cfg: SessionConfig) -> SessionConfig:
        """``cfg`` with the intra-op threads of this budget's predictor: the worker's threads, or every core
        without a worker."""
        from dataclasses import replace

        return replace(cfg, intra_op_threads=self.worker_threads if self.worker else self.cores)


def make_session(path: PathLike, cfg: SessionConfig = SessionConfig()):
    """An ``onnxruntime.InferenceSession`` for the model file at ``path``.

    Raises:
        ValueError: the file is missing, ONNX Runtime cannot load it (corrupt or not ONNX), or none of
            ``cfg.providers`` is available.
    """
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file {path} is missing")
    available = ort.get_available_providers()
    providers = [p for p in cfg.providers if p in available]
    if not providers:
        raise ValueError(f"none of the providers {cfg.providers} is available (ONNX Runtime has {available})")
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(cfg.intra_op_threads)
    options.inter_op_num_threads = int(cfg.inter_op_threads)
    options.graph_optimization_level = getattr(ort.GraphOptimizationLevel, cfg.graph_optimization.value)
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if cfg.allow_spinning else "0")
    options.add_session_config_entry("session.force_spinning_stop", "1" if cfg.stop_spinning_after_run else "0")
    try:
        return ort.InferenceSession(str(path), options, providers=providers)
    except Exception as error:  # ORT raises its own exception types (InvalidProtobuf, Fail, ...)
        raise ValueError(f"model file {path} could not be loaded by ONNX Runtime (corrupt or not an ONNX "
                         f"model): {str(error).splitlines()[0]}") from error


@dataclass(frozen=True)
class LoadedModel:
    """An open model file and what :func:`load_model` read from it.

    Attributes:
        session: its ``onnxruntime.InferenceSession``.
        path: the file.
        kind: its :class:`~superex_deploy.onboard.prediction.inference.manifest.ModelKind` (from the metadata).
        metadata: its ``metadata_props``.
        input_name, output_name: its one input and one output tensor.
        input_shape: the input's declared shape ``[N, C, H, W]`` (symbolic dimensions as ONNX Runtime gives them).
        resolution_m: metres per cell of the maps it was trained on (its ``resolution_m`` metadata): inputs are
            brought to that scale (:mod:`superex_deploy.onboard.prediction.scale`).
    """

    session: object
    path: Path
    kind: ModelKind
    metadata: dict
    input_name: str
    output_name: str
    input_shape: tuple
    resolution_m: float


def load_model(path: PathLike, kinds: Sequence[ModelKind], expected_sha256: Optional[str],
               session_cfg: SessionConfig, expected_resolution_m: Optional[float] = None) -> LoadedModel:
    """Open one model and check its hash, metadata and input shape against the expected kinds.

    Args:
        path: the ``.onnx`` file.
        kinds: the kinds the caller accepts.
        expected_sha256: hex sha256 the file must have (None: not checked).
        session_cfg: ONNX Runtime settings (:func:`make_session`).
        expected_resolution_m: the training resolution (metres per cell) the manifest gives it (None: not checked).

    Raises:
        ValueError: the file is missing, changed since export, not loadable, or its metadata, channels,
            normalisation or input shape differ from what this package encodes, its resolution is missing or
            not a positive number of metres, or differs from ``expected_resolution_m``.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file {path} is missing")
    if expected_sha256 is not None:
        actual = sha256_file(path)
        if actual != expected_sha256.lower():
            raise ValueError(f"model file {path} has sha256 {actual}, expected {expected_sha256}: it changed "
                             f"after export (re-export it, or use the manifest that came with it)")
    session = make_session(path, session_cfg)
    metadata = dict(session.get_modelmeta().custom_metadata_map)
    missing = [k for k in ("format_version", "model_kind", "channels", "normalisation") if k not in metadata]
    if missing:
        raise ValueError(f"model file {path} lacks the metadata {missing}; it was not written by superex export")
    if metadata["format_version"] != FORMAT_VERSION:
        raise ValueError(f"model file {path} has metadata format {metadata['format_version']!r}, this package "
                         f"reads {FORMAT_VERSION!r}")
    try:
        kind = ModelKind(metadata["model_kind"])
    except ValueError:
        raise ValueError(f"model file {path} has unknown model_kind {metadata['model_kind']!r}") from None
    if kind not in kinds:
        raise ValueError(f"model file {path} is a {kind.value} model, expected "
                         f"{' or '.join(k.value for k in kinds)}")
    channels = tuple(json.loads(metadata["channels"]))
    if channels != MODEL_CHANNELS[kind]:
        raise ValueError(f"model file {path} declares input channels {list(channels)}, a {kind.value} model "
                         f"takes {list(MODEL_CHANNELS[kind])}")
    if kind is ModelKind.PIX2PIX:
        try:
            BpEncoding.from_description(metadata["normalisation"])
        except ValueError as error:
            raise ValueError(f"model file {path}: {error}") from None
    elif metadata["normalisation"] != NORMALISATION[kind]:
        raise ValueError(f"model file {path} declares normalisation {metadata['normalisation']!r}, this package "
                         f"encodes {kind.value} inputs as {NORMALISATION[kind]!r}")
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if len(inputs) != 1 or len(outputs) != 1:
        raise ValueError(f"model file {path} has {len(inputs)} inputs and {len(outputs)} outputs, expected one each")
    shape = tuple(inputs[0].shape)
    if len(shape) != 4 or shape[1] != len(channels):
        raise ValueError(f"model file {path} takes input shape {list(shape)}, expected [N, {len(channels)}, H, W] "
                         f"for its channels {list(channels)}")
    try:
        resolution = float(metadata.get("resolution_m", "nan"))
    except ValueError:
        resolution = float("nan")
    if not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"model file {path} gives no training resolution (resolution_m metadata "
                         f"{metadata.get('resolution_m')!r}); it was not written by superex export")
    if expected_resolution_m is not None and not np.isclose(resolution, expected_resolution_m, rtol=1e-9, atol=0):
        raise ValueError(f"model file {path} was trained at {resolution} m/cell, its manifest says "
                         f"{expected_resolution_m} m/cell")
    return LoadedModel(session=session, path=path, kind=kind, metadata=metadata, input_name=inputs[0].name,
                       output_name=outputs[0].name, input_shape=shape, resolution_m=resolution)
