"""ONNX Runtime inference of the learned models: the Pix2Pix back-projection filter and the LaMa ensembles.

Models are exported by :mod:`superex_train.export` into a folder (``exported/`` in the repository) with a
``manifest.json`` that lists every file with its kind, ensemble member index and sha256. Every ``.onnx`` file
carries its own description in ``metadata_props`` (keys in :data:`METADATA_KEYS`): model kind, input channels
and their order, normalisation, resolution, window size or size multiple, ensemble member, training-data hash,
package version. Loading checks the file's sha256 against the manifest (or a hash the caller gives), then the
metadata against what the caller asked for, and raises ``ValueError`` naming the file and the mismatch for a
missing, corrupt or mismatched model. Input and output tensor names are read from the model, not assumed.

Encodings (shared with :mod:`superex_train`, which imports them from here):

* **Pix2Pix** (:attr:`ModelKind.PIX2PIX`): one square window of ``window_cells`` cells of the raw
  back-projection (``superex_deploy.onboard.nlos.back_project``, in [0, 1]) centred on the robot, whose cell is the
  window's ``(S // 2, S // 2)``; fed as ``2 x - 1``; the output is the probability, per cell, of a hidden wall.
* **LaMa** (:attr:`ModelKind.LAMA_BP`, :attr:`ModelKind.LAMA_LOS`): the whole observed map, channels in
  {0, 1} except the evidence: ``observed_wall`` (1 where observed OCCUPIED), ``evidence`` (the filtered
  back-projection in [0, 1], map frame; LAMA_BP only) and ``unknown`` (1 where UNKNOWN). The output is the wall
  probability of every cell.

This module never imports torch.
"""

from __future__ import annotations

import copy
import enum
import hashlib
import importlib.resources
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from superex_deploy.onboard.types import OCCUPIED, UNKNOWN, Prediction, check_observed

__all__ = ["ModelKind", "BpEncoding", "MODEL_CHANNELS", "METADATA_KEYS", "FORMAT_VERSION", "MANIFEST_NAME",
           "DEFAULT_MODEL_DIR", "GraphOptimization", "SessionConfig", "make_session", "sha256_file", "ManifestEntry",
           "read_manifest", "encode_bp_windows", "encode_map", "crop_window", "Pix2PixFilter", "LamaEnsemble",
           "check_member_options"]

PathLike = Union[str, Path]

FORMAT_VERSION = "1"
"""Version of the metadata layout below; a model with another version is refused."""

MANIFEST_NAME = "manifest.json"

def _default_model_dir() -> Path:
    """``$SUPEREX_MODELS`` if set, else the installed package ``superex_deploy.models`` (the repository's
    ``exported/`` in an editable install, ``site-packages/superex_deploy/models`` from the wheel)."""
    override = os.environ.get("SUPEREX_MODELS")
    if override:
        return Path(override).expanduser().resolve()
    try:
        return Path(str(importlib.resources.files("superex_deploy.models"))).resolve()
    except ModuleNotFoundError:  # a checkout on sys.path that was never installed
        return Path(__file__).resolve().parents[2] / "exported"


DEFAULT_MODEL_DIR = _default_model_dir()
"""Where the models are looked up when no folder is given: ``$SUPEREX_MODELS``, else the installed models (see
:func:`_default_model_dir`); ``superex export`` writes to the repository's ``exported/`` by default."""


class ModelKind(enum.Enum):
    """What an exported model is."""

    PIX2PIX = "pix2pix"
    """Back-projection filter: ``[N, 1, S, S]`` window -> wall probability ``[N, 1, S, S]``."""
    LAMA_BP = "lama_bp"
    """Map predictor that reads the filtered back-projection: ``[N, 3, H, W]`` -> ``[N, 1, H, W]``."""
    LAMA_LOS = "lama_los"
    """Line-of-sight map predictor (the baselines'): ``[N, 2, H, W]`` -> ``[N, 1, H, W]``."""


MODEL_CHANNELS: dict[ModelKind, tuple[str, ...]] = {
    ModelKind.PIX2PIX: ("bp",),
    ModelKind.LAMA_BP: ("observed_wall", "evidence", "unknown"),
    ModelKind.LAMA_LOS: ("observed_wall", "unknown"),
}
"""Input channels of each kind, in order."""

class BpEncoding(enum.Enum):
    """How a back-projection window in [0, 1] is mapped to the Pix2Pix input range [-1, 1]."""

    LINEAR = "linear"
    """``2 x - 1`` (the committed model's)."""
    LOG = "log"
    """``2 log1p(100 x) / log(101) - 1``: a normalised back-projection is dominated by the brightest votes near
    the robot; the logarithm lifts the faint arcs of distant hidden walls."""

    @property
    def description(self) -> str:
        """The ``normalisation`` metadata string of a model that reads this encoding."""
        return _BP_DESCRIPTIONS[self]

    @classmethod
    def from_description(cls, text: str) -> "BpEncoding":
        """The encoding whose :attr:`description` is ``text`` (ValueError if none)."""
        for encoding, description in _BP_DESCRIPTIONS.items():
            if description == text:
                return encoding
        raise ValueError(f"unknown back-projection normalisation {text!r}; this package knows "
                         f"{[d for d in _BP_DESCRIPTIONS.values()]}")

    def apply(self, windows: np.ndarray) -> np.ndarray:
        """Encode float ``windows`` in [0, 1] (any shape); float32."""
        windows = np.asarray(windows, np.float32)
        if self is BpEncoding.LOG:
            return (2.0 * np.log1p(100.0 * windows) / np.log(101.0) - 1.0).astype(np.float32)
        return (2.0 * windows - 1.0).astype(np.float32)


_BP_DESCRIPTIONS = {
    BpEncoding.LINEAR: "bp: 2 * x - 1, x = back-projection in [0, 1] (normalised by its maximum)",
    BpEncoding.LOG: ("bp: 2 * log1p(100 x) / log(101) - 1, x = back-projection in [0, 1] (normalised by its "
                     "maximum)"),
}

NORMALISATION: dict[ModelKind, str] = {
    ModelKind.PIX2PIX: BpEncoding.LINEAR.description,
    ModelKind.LAMA_BP: "observed_wall, unknown: {0, 1}; evidence: filtered back-projection in [0, 1]",
    ModelKind.LAMA_LOS: "observed_wall, unknown: {0, 1}",
}
"""How each kind's inputs are encoded (written into the metadata and compared at load). A Pix2Pix model may
declare any :class:`BpEncoding`'s description; this is the default one (datasets store windows in it)."""

METADATA_KEYS = ("format_version", "model_kind", "channels", "normalisation", "resolution_m", "window_cells",
                 "size_multiple", "min_size", "output", "ensemble_member", "training_data_sha256",
                 "superex_version", "architecture")
"""``metadata_props`` written at export. ``channels`` and ``architecture`` are JSON; ``window_cells`` is set
for Pix2Pix, ``size_multiple``/``min_size`` (cells) for LaMa; ``ensemble_member`` is the member index."""

RESOLUTION_M = 0.1
"""Grid resolution the models are trained at (metres per cell)."""


class GraphOptimization(enum.Enum):
    """ONNX Runtime graph optimisation level."""

    DISABLED = "ORT_DISABLE_ALL"
    BASIC = "ORT_ENABLE_BASIC"
    EXTENDED = "ORT_ENABLE_EXTENDED"
    ALL = "ORT_ENABLE_ALL"


@dataclass(frozen=True)
class SessionConfig:
    """How ONNX Runtime sessions are made (one factory for every model: :func:`make_session`).

    Attributes:
        intra_op_threads: threads inside one operator (0: ONNX Runtime's default, one per core).
        inter_op_threads: threads across independent operators (1: sequential execution).
        providers: execution providers in order of preference.
        graph_optimization: :class:`GraphOptimization` level.
        allow_spinning: let the intra-op threads busy-wait for work between operators (ONNX Runtime's
            default): each operator then starts without waking its threads (LaMa members 2-6 % faster on 2 cores).
        stop_spinning_after_run: make the spinning threads stop at the end of every run
            (``session.force_spinning_stop``). Without it they keep spinning after a run and take the cores
            from the numba and numpy work the exploration loop does next (measured on 2 cores: three 600 x 600
            matmuls right after a LaMa run took 26-50 ms with spinning left on, 13 ms with it stopped or off).
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


def sha256_file(path: PathLike) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class ManifestEntry:
    """One model of a manifest.

    Attributes:
        path: absolute path of the file.
        kind: its :class:`ModelKind`.
        member: ensemble member index (0 for Pix2Pix).
        sha256: hex sha256 of the file as exported.
    """

    path: Path
    kind: ModelKind
    member: int
    sha256: str


def read_manifest(directory: PathLike = DEFAULT_MODEL_DIR) -> list[ManifestEntry]:
    """The models listed in ``directory/manifest.json`` (possibly none).

    Raises:
        ValueError: the manifest is missing or malformed.
    """
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    if not path.is_file():
        raise ValueError(f"no model manifest at {path}; export models with `superex export`")
    try:
        manifest = json.loads(path.read_text())
        if str(manifest["format_version"]) != FORMAT_VERSION:
            raise ValueError(f"format_version {manifest['format_version']!r}, this package reads {FORMAT_VERSION}")
        return [ManifestEntry(path=(directory / item["file"]).resolve(), kind=ModelKind(item["kind"]),
                              member=int(item["member"]), sha256=str(item["sha256"]))
                for item in manifest["models"]]
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as error:
        raise ValueError(f"malformed model manifest {path}: {error}") from error


def _entries_of(directory: PathLike, kind: ModelKind) -> list[ManifestEntry]:
    entries = sorted((e for e in read_manifest(directory) if e.kind is kind), key=lambda e: e.member)
    if not entries:
        raise ValueError(f"the manifest in {directory} lists no {kind.value} model; export one with "
                         f"`superex export`")
    members = [e.member for e in entries]
    if len(set(members)) != len(members):
        raise ValueError(f"the manifest in {directory} lists {kind.value} member indices {members} more than once")
    return entries


@dataclass(frozen=True)
class _LoadedModel:
    session: object
    path: Path
    kind: ModelKind
    metadata: dict
    input_name: str
    output_name: str
    input_shape: tuple


def _load_model(path: PathLike, kinds: Sequence[ModelKind], expected_sha256: Optional[str],
                session_cfg: SessionConfig) -> _LoadedModel:
    """Open one model and check its hash, metadata and input shape against the expected kinds."""
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
    resolution = float(metadata.get("resolution_m", "nan"))
    if not np.isclose(resolution, RESOLUTION_M):
        raise ValueError(f"model file {path} was trained at {resolution} m/cell, this package maps at "
                         f"{RESOLUTION_M} m/cell")
    return _LoadedModel(session=session, path=path, kind=kind, metadata=metadata, input_name=inputs[0].name,
                        output_name=outputs[0].name, input_shape=shape)


def encode_bp_windows(windows: np.ndarray, encoding: BpEncoding = BpEncoding.LINEAR) -> np.ndarray:
    """Pix2Pix input: float32 ``[N, 1, S, S]``, back-projection windows ``[N, S, S]`` in [0, 1] encoded by
    ``encoding`` (default ``2 x - 1``)."""
    windows = np.asarray(windows)
    if windows.ndim != 3 or windows.dtype != np.float32:
        raise ValueError(f"windows must be float32 [N, S, S], got {windows.dtype} with shape {windows.shape}")
    if not np.isfinite(windows).all() or windows.min(initial=0.0) < 0.0 or windows.max(initial=0.0) > 1.0:
        raise ValueError("back-projection windows must be finite and lie in [0, 1]")
    return encoding.apply(windows)[:, None]


def encode_map(observed: np.ndarray, evidence: Optional[np.ndarray], kind: ModelKind) -> np.ndarray:
    """LaMa input: float32 ``[1, C, H, W]`` with the channels of ``MODEL_CHANNELS[kind]``.

    Args:
        observed: int8 ``[H, W]`` observed map (UNKNOWN / FREE / OCCUPIED).
        evidence: float32 ``[H, W]`` filtered back-projection in [0, 1] (required for LAMA_BP; ignored for
            LAMA_LOS, whose baselines do not use NLOS evidence).
        kind: LAMA_BP or LAMA_LOS.
    """
    observed = check_observed(observed, codes=True)
    wall = (observed == OCCUPIED).astype(np.float32)
    unknown = (observed == UNKNOWN).astype(np.float32)
    if kind is ModelKind.LAMA_LOS:
        return np.stack([wall, unknown])[None]
    if kind is not ModelKind.LAMA_BP:
        raise ValueError(f"encode_map encodes LaMa inputs, got {kind}")
    if evidence is None:
        raise ValueError("a lama_bp model needs the filtered back-projection as evidence (extra), got None")
    evidence = np.asarray(evidence)
    if evidence.dtype != np.float32 or evidence.shape != observed.shape:
        raise ValueError(f"evidence must be float32 of the observed map's shape {observed.shape}, got "
                         f"{evidence.dtype} {evidence.shape}")
    if not np.isfinite(evidence).all() or evidence.min(initial=0.0) < 0.0 or evidence.max(initial=0.0) > 1.0:
        raise ValueError("evidence must be finite and lie in [0, 1]")
    return np.stack([wall, evidence, unknown])[None]


def crop_window(array: np.ndarray, pose_rc, size: int, fill: float = 0.0) -> np.ndarray:
    """The ``size x size`` window of a 2-D ``array`` whose cell ``(size // 2, size // 2)`` is ``pose_rc``.

    Cells beyond the array's edges take ``fill``. Window cell ``(i, j)`` is array cell
    ``(r - size // 2 + i, c - size // 2 + j)``. Same dtype as ``array``.
    """
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"array must be 2-D, got shape {array.shape}")
    if int(size) < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    r0, c0 = int(pose_rc[0]) - size // 2, int(pose_rc[1]) - size // 2
    out = np.full((size, size), fill, dtype=array.dtype)
    rows = slice(max(r0, 0), min(r0 + size, array.shape[0]))
    cols = slice(max(c0, 0), min(c0 + size, array.shape[1]))
    if rows.start < rows.stop and cols.start < cols.stop:
        out[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = array[rows, cols]
    return out


def _paste_window(window: np.ndarray, pose_rc, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`crop_window`: a zero float32 ``shape`` map holding ``window`` where it came from."""
    size = window.shape[0]
    r0, c0 = int(pose_rc[0]) - size // 2, int(pose_rc[1]) - size // 2
    out = np.zeros(shape, np.float32)
    rows = slice(max(r0, 0), min(r0 + size, shape[0]))
    cols = slice(max(c0, 0), min(c0 + size, shape[1]))
    if rows.start < rows.stop and cols.start < cols.stop:
        out[rows, cols] = window[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0]
    return out


class Pix2PixFilter:
    """The learned back-projection filter (numpy in, numpy out).

    Args:
        path: the ``.onnx`` file.
        expected_sha256: hex sha256 the file must have (None: not checked; :meth:`from_manifest` passes the
            manifest's).
        session: ONNX Runtime settings.

    Attributes:
        window_cells: side ``S`` of the window the model reads (cells; from the metadata).
        encoding: the :class:`BpEncoding` the model reads (from the metadata's ``normalisation``).
        metadata: the model's ``metadata_props``.
    """

    def __init__(self, path: PathLike, expected_sha256: Optional[str] = None, session: SessionConfig = SessionConfig()):
        self._model = _load_model(path, (ModelKind.PIX2PIX,), expected_sha256, session)
        self.metadata = self._model.metadata
        self.window_cells = int(self.metadata.get("window_cells", -1))
        self.encoding = BpEncoding.from_description(self.metadata["normalisation"])
        if self._model.input_shape[2:] != (self.window_cells, self.window_cells):
            raise ValueError(f"model file {path} takes windows of {list(self._model.input_shape[2:])} cells but its "
                             f"metadata says window_cells = {self.window_cells}")

    @classmethod
    def from_manifest(cls, directory: PathLike = DEFAULT_MODEL_DIR,
                      session: SessionConfig = SessionConfig()) -> "Pix2PixFilter":
        """The Pix2Pix model listed in ``directory/manifest.json``, its sha256 checked."""
        entries = _entries_of(directory, ModelKind.PIX2PIX)
        if len(entries) != 1:
            raise ValueError(f"the manifest in {directory} lists {len(entries)} pix2pix models, expected one")
        return cls(entries[0].path, entries[0].sha256, session)

    def filter_windows(self, windows: np.ndarray) -> np.ndarray:
        """Wall probability of back-projection windows.

        Args:
            windows: float32 ``[S, S]`` or ``[N, S, S]`` raw back-projection in [0, 1], robot at ``(S//2, S//2)``.

        Returns:
            float32 of the same shape, in [0, 1].
        """
        windows = np.asarray(windows)
        single = windows.ndim == 2
        batch = windows[None] if single else windows
        if batch.ndim != 3 or batch.shape[1:] != (self.window_cells, self.window_cells):
            raise ValueError(f"windows must be [{self.window_cells}, {self.window_cells}] or [N, "
                             f"{self.window_cells}, {self.window_cells}], got shape {windows.shape}")
        out = self._model.session.run([self._model.output_name],
                                      {self._model.input_name: encode_bp_windows(batch, self.encoding)})[0][:, 0]
        out = np.clip(out, 0.0, 1.0).astype(np.float32)
        return out[0] if single else out

    def filter_map(self, bp: np.ndarray, pose_rc) -> np.ndarray:
        """Filter the window of a map-frame back-projection around the robot.

        Args:
            bp: float32 ``[H, W]`` raw back-projection in [0, 1] (``superex_deploy.onboard.nlos.back_project``).
            pose_rc: the robot cell (row, col) the scan was taken from.

        Returns:
            float32 ``[H, W]`` wall probability inside the window (zero outside it).
        """
        bp = np.asarray(bp)
        if bp.ndim != 2 or bp.dtype != np.float32:
            raise ValueError(f"bp must be a float32 [H, W] map, got {bp.dtype} with shape {bp.shape}")
        window = crop_window(bp, pose_rc, self.window_cells)
        return _paste_window(self.filter_windows(window), pose_rc, bp.shape)


def check_member_options(max_members: Optional[int], agreement_stop: Optional[float],
                         members: Optional[int] = None) -> None:
    """Validate :meth:`LamaEnsemble.with_members`'s options (``members``: the ensemble's size, None: not known yet).

    Raises:
        ValueError: ``max_members`` not an integer in 1..members (or >= 1), ``agreement_stop`` not in [0, 1].
    """
    if max_members is not None and (not isinstance(max_members, (int, np.integer)) or isinstance(max_members, bool)
                                    or max_members < 1 or (members is not None and max_members > members)):
        allowed = f"in 1..{members}" if members is not None else ">= 1"
        raise ValueError(f"max_members must be an integer {allowed} or None, got {max_members!r}")
    if agreement_stop is not None and not (isinstance(agreement_stop, (int, float, np.floating))
                                           and not isinstance(agreement_stop, bool)
                                           and 0.0 <= agreement_stop <= 1.0):
        raise ValueError(f"agreement_stop must lie in [0, 1] or be None, got {agreement_stop!r}")


class LamaEnsemble:
    """An ensemble of LaMa map predictors: a :class:`~superex_deploy.onboard.types.MapPredictor`.

    ``predict`` encodes the observed map (and the evidence, for LAMA_BP), pads it at the bottom and right with
    unknown cells to a size the network takes (multiples of ``size_multiple``, at least ``min_size``), runs every
    member, crops back and returns the members' mean and (population) variance. With ``keep_observed`` the
    observed cells keep their observed value with zero variance (observations agree with the ground truth in
    simulation); only unknown cells carry the networks' predictions. The members are separate files (each with
    its own member index), so they run one after the other, each on all ``intra_op_threads``.

    Two settings trade members for time (:meth:`with_members`): ``max_members`` runs only the first members, and
    ``agreement_stop`` stops after the first two when they agree: their mean absolute difference over the
    unknown cells is at most that (wall probability). The variance is then the two members' (one member: zero).

    Args:
        paths: the members' ``.onnx`` files (all of one kind).
        expected_sha256: one hex sha256 per file, or None (not checked; :meth:`from_manifest` passes them).
        session: ONNX Runtime settings.
        keep_observed: see above.

    Attributes:
        kind: LAMA_BP or LAMA_LOS.
        name: ``"lama_bp"`` or ``"lama_los"`` (the predictor's name in episode logs).
        size_multiple, min_size: padding targets (cells).
        max_members: members run per prediction (None: all).
        agreement_stop: see above (None: never stop early).
        members_run: how many members the latest prediction ran.
    """

    accepts_crops = True  # a fully convolutional network: any sub-map is a valid input

    def __init__(self, paths: Sequence[PathLike], expected_sha256: Optional[Sequence[str]] = None,
                 session: SessionConfig = SessionConfig(), keep_observed: bool = True):
        paths = list(paths)
        if not paths:
            raise ValueError("a LamaEnsemble needs at least one member file")
        if expected_sha256 is not None and len(expected_sha256) != len(paths):
            raise ValueError(f"got {len(expected_sha256)} hashes for {len(paths)} member files")
        hashes = list(expected_sha256) if expected_sha256 is not None else [None] * len(paths)
        self._members = [_load_model(p, (ModelKind.LAMA_BP, ModelKind.LAMA_LOS), h, session)
                         for p, h in zip(paths, hashes)]
        first = self._members[0]
        self.kind = first.kind
        self.name = self.kind.value
        self.size_multiple = int(first.metadata.get("size_multiple", 0))
        self.min_size = int(first.metadata.get("min_size", 0))
        if self.size_multiple < 1 or self.min_size < 1:
            raise ValueError(f"model file {first.path} lacks a valid size_multiple / min_size in its metadata")
        for member in self._members[1:]:
            if member.kind is not self.kind:
                raise ValueError(f"ensemble members differ in kind: {first.path} is {self.kind.value}, "
                                 f"{member.path} is {member.kind.value}")
            if (int(member.metadata.get("size_multiple", 0)), int(member.metadata.get("min_size", 0))) != (
                    self.size_multiple, self.min_size):
                raise ValueError(f"ensemble members {first.path} and {member.path} need different input sizes")
        self.keep_observed = bool(keep_observed)
        self.max_members: Optional[int] = None
        self.agreement_stop: Optional[float] = None
        self.members_run = 0

    def with_members(self, max_members: Optional[int] = None, agreement_stop: Optional[float] = None
                     ) -> "LamaEnsemble":
        """This ensemble (sharing its sessions) running at most ``max_members`` members, stopping after two that
        agree within ``agreement_stop`` (see the class docstring).

        Raises:
            ValueError: ``max_members`` outside 1..members, ``agreement_stop`` not in [0, 1].
        """
        check_member_options(max_members, agreement_stop, len(self._members))
        view = copy.copy(self)
        view.max_members = None if max_members is None else int(max_members)
        view.agreement_stop = None if agreement_stop is None else float(agreement_stop)
        view.members_run = 0
        return view

    @classmethod
    def from_manifest(cls, kind: ModelKind, directory: PathLike = DEFAULT_MODEL_DIR,
                      session: SessionConfig = SessionConfig(), keep_observed: bool = True) -> "LamaEnsemble":
        """Every ``kind`` member listed in ``directory/manifest.json``, in member order, sha256 checked."""
        if kind not in (ModelKind.LAMA_BP, ModelKind.LAMA_LOS):
            raise ValueError(f"a LamaEnsemble is made of lama_bp or lama_los models, got {kind}")
        entries = _entries_of(directory, kind)
        return cls([e.path for e in entries], [e.sha256 for e in entries], session, keep_observed)

    @property
    def members(self) -> int:
        """Number of ensemble members."""
        return len(self._members)

    def padded_shape(self, shape: tuple[int, int]) -> tuple[int, int]:
        """The ``(rows, cols)`` a map of ``shape`` is padded to."""
        m = self.size_multiple
        return tuple(max(-(-int(n) // m) * m, self.min_size) for n in shape)  # type: ignore[return-value]

    def predict_members(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> np.ndarray:
        """Each member's wall probability: float32 ``[M, H, W]`` in [0, 1] (before ``keep_observed``); ``M`` is the
        members run (see ``max_members`` and ``agreement_stop``)."""
        encoded = encode_map(observed, extra, self.kind)
        height, width = observed.shape
        rows, cols = self.padded_shape((height, width))
        padded = np.zeros((1, encoded.shape[1], rows, cols), np.float32)
        padded[:, MODEL_CHANNELS[self.kind].index("unknown")] = 1.0  # the padding is unknown space
        padded[:, :, :height, :width] = encoded
        members = self._members if self.max_members is None else self._members[:self.max_members]
        out = np.empty((len(members), height, width), np.float32)
        unknown = observed == UNKNOWN
        for i, member in enumerate(members):
            result = member.session.run([member.output_name], {member.input_name: padded})[0]
            out[i] = np.clip(result[0, 0, :height, :width], 0.0, 1.0)
            if i == 1 and self.agreement_stop is not None and len(members) > 2:
                disagreement = float(np.abs(out[0] - out[1])[unknown].mean()) if unknown.any() else 0.0
                if disagreement <= self.agreement_stop:
                    out = out[:2]
                    break
        self.members_run = len(out)
        return out

    def predict(self, observed: np.ndarray, extra: Optional[np.ndarray] = None) -> Prediction:
        """Mean and variance over the members (see the class docstring). ``observed`` int8 ``[H, W]``;
        ``extra`` float32 ``[H, W]`` filtered back-projection (LAMA_BP: required; LAMA_LOS: ignored)."""
        members = self.predict_members(observed, extra)
        mean = members.mean(axis=0)
        variance = members.var(axis=0)
        if self.keep_observed:
            known = observed != UNKNOWN
            mean[known] = (observed[known] == OCCUPIED)
            variance[known] = 0.0
        return Prediction(mean=mean.astype(np.float32), variance=variance.astype(np.float32))
