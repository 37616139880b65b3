"""What an exported model is and where it lives: model kinds, the metadata format, the default model folder and
the ``manifest.json`` that lists the files.

:mod:`superex_train.export` writes a folder (``exported/`` in the repository) with a ``manifest.json`` listing
every file with its kind, ensemble member index and sha256; every ``.onnx`` file carries its own description in
``metadata_props`` (keys in :data:`METADATA_KEYS`). This module reads the manifest; checking a file against it
and its metadata is :func:`superex_deploy.onboard.prediction.inference.sessions.load_model`'s job.
"""

from __future__ import annotations

import enum
import hashlib
import importlib.resources
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

__all__ = ["PathLike", "FORMAT_VERSION", "MANIFEST_NAME", "METADATA_KEYS", "ModelKind", "MODEL_CHANNELS",
           "DEFAULT_MODEL_DIR", "sha256_file", "ManifestEntry", "read_manifest", "manifest_entries",
           "manifest_resolution"]

PathLike = Union[str, Path]

FORMAT_VERSION = "1"
"""Version of the metadata layout below; a model with another version is refused."""

MANIFEST_NAME = "manifest.json"

METADATA_KEYS = ("format_version", "model_kind", "channels", "normalisation", "resolution_m", "window_cells",
                 "size_multiple", "min_size", "output", "ensemble_member", "training_data_sha256",
                 "superex_version", "architecture")
"""``metadata_props`` written at export. ``channels`` and ``architecture`` are JSON; ``window_cells`` is set
for Pix2Pix, ``size_multiple``/``min_size`` (cells) for LaMa; ``ensemble_member`` is the member index."""


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


def _default_model_dir() -> Path:
    """``$SUPEREX_MODELS`` if set, else the installed package ``superex_deploy.models`` (the repository's
    ``exported/`` in an editable install, ``site-packages/superex_deploy/models`` from the wheel)."""
    override = os.environ.get("SUPEREX_MODELS")
    if override:
        return Path(override).expanduser().resolve()
    try:
        return Path(str(importlib.resources.files("superex_deploy.models"))).resolve()
    except ModuleNotFoundError:  # a checkout on sys.path that was never installed
        # this file is <root>/superex_deploy/onboard/prediction/inference/manifest.py
        return Path(__file__).resolve().parents[4] / "exported"


DEFAULT_MODEL_DIR = _default_model_dir()
"""Where the models are looked up when no folder is given: ``$SUPEREX_MODELS``, else the installed models (see
:func:`_default_model_dir`); ``superex export`` writes to the repository's ``exported/`` by default."""


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
        resolution_m: metres per cell of the maps the model was trained on (None: a manifest written before the
            field existed; the file's own ``resolution_m`` metadata is then the only record).
    """

    path: Path
    kind: ModelKind
    member: int
    sha256: str
    resolution_m: Optional[float] = None


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
                              member=int(item["member"]), sha256=str(item["sha256"]),
                              resolution_m=_resolution(item.get("resolution_m")))
                for item in manifest["models"]]
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as error:
        raise ValueError(f"malformed model manifest {path}: {error}") from error


def _resolution(value) -> Optional[float]:
    """A manifest entry's ``resolution_m``: None if absent, else a positive finite float (ValueError)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value > 0):
        raise ValueError(f"resolution_m must be a positive number of metres, got {value!r}")
    return float(value)


def manifest_resolution(entries: list[ManifestEntry]) -> Optional[float]:
    """The one training resolution (metres per cell) the manifest gives ``entries`` (members of one model), None
    where it gives none.

    Raises:
        ValueError: entries that give different resolutions (an ensemble's members must share their scale).
    """
    given = {e.resolution_m for e in entries if e.resolution_m is not None}
    if len(given) > 1:
        raise ValueError(f"the manifest gives the {entries[0].kind.value} members different resolutions "
                         f"{sorted(given)} m/cell; an ensemble's members must be trained at one")
    return given.pop() if given else None


def manifest_entries(directory: PathLike, kind: ModelKind) -> list[ManifestEntry]:
    """The ``kind`` models listed in ``directory/manifest.json``, in member order.

    Raises:
        ValueError: the manifest is missing or malformed, lists no ``kind`` model, or lists a member index twice.
    """
    entries = sorted((e for e in read_manifest(directory) if e.kind is kind), key=lambda e: e.member)
    if not entries:
        raise ValueError(f"the manifest in {directory} lists no {kind.value} model; export one with "
                         f"`superex export`")
    members = [e.member for e in entries]
    if len(set(members)) != len(members):
        raise ValueError(f"the manifest in {directory} lists {kind.value} member indices {members} more than once")
    return entries
