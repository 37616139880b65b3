"""Training data on disk: a shard format with a writer and a (memory-mapped) reader, and synthetic data.

Format (one directory per dataset)::

    index.json                    # see DatasetInfo; written last, so a directory without it is incomplete
    shard_00000.inputs.npy        # float16 [n, C, h, w]  network inputs, already encoded as the ONNX model
                                  #                       expects (superex_deploy.onboard.prediction.inference.encode_*)
    shard_00000.targets.npy       # uint8   [n, h, w]     wall labels, 1 = wall
    shard_00000.mask.npy          # uint8   [n, h, w]     1 where the loss is defined
    shard_00000.groups.npy        # int32   [n]           building id of each sample (validation splits by it)
    shard_00001.*                 # ...

Every sample of a dataset has the same tile size ``h x w`` and the channels ``MODEL_CHANNELS[kind]``. The
index records each file's sha256 and the generator's settings; :attr:`DatasetInfo.data_sha256` (the sha256 of
the index's canonical JSON) identifies the data a model was trained on and is written into its ONNX metadata.
Inputs are stored as float16 (the encodings are exact in it except the back-projection values, which keep
about three significant digits); the reader hands out float32.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np
from scipy import ndimage

from superex_deploy.files import write_atomically
from superex_deploy.onboard.prediction.inference import MODEL_CHANNELS, ModelKind, sha256_file

__all__ = ["DATASET_FORMAT", "DatasetInfo", "ShardWriter", "read_index", "ShardDataset", "synthetic_walls",
           "write_synthetic_dataset", "split_by_group"]

DATASET_FORMAT = "superex-shards/1"
INDEX_NAME = "index.json"
_ARRAYS = ("inputs", "targets", "mask", "groups")

PathLike = Union[str, Path]


@dataclass(frozen=True)
class DatasetInfo:
    """What ``index.json`` says about a dataset.

    Attributes:
        directory: where it is.
        kind: the :class:`~superex_deploy.onboard.prediction.inference.ModelKind` its inputs are encoded for.
        channels: input channel names, in order.
        tile_hw: ``(h, w)`` of every sample (cells).
        shards: ``(name, count)`` of each shard.
        generator: the generator's settings (free-form JSON).
        data_sha256: sha256 of the index's canonical JSON (identifies the data).
    """

    directory: Path
    kind: ModelKind
    channels: tuple[str, ...]
    tile_hw: tuple[int, int]
    shards: tuple[tuple[str, int], ...]
    generator: dict
    data_sha256: str

    @property
    def count(self) -> int:
        """Number of samples."""
        return sum(n for _, n in self.shards)


def _canonical(document: dict) -> bytes:
    return json.dumps(document, sort_keys=True, separators=(",", ":")).encode()


def _save_npy(array: np.ndarray, path: Path) -> None:
    with open(path, "wb") as handle:  # a handle: given a name, np.save would append ".npy" to the temporary's
        np.save(handle, array)


class ShardWriter:
    """Writes a dataset sample by sample (use as a context manager, or call :meth:`close`).

    Args:
        directory: output directory (created; it must not already hold an ``index.json``).
        kind: what the inputs are encoded for (fixes the channels).
        tile_hw: ``(h, w)`` of every sample.
        shard_size: samples per shard file.
        generator: settings of whatever produced the data (stored in the index).
    """

    def __init__(self, directory: PathLike, kind: ModelKind, tile_hw: tuple[int, int], shard_size: int = 256,
                 generator: Optional[dict] = None):
        self.directory = Path(directory)
        if (self.directory / INDEX_NAME).exists():
            raise ValueError(f"{self.directory} already holds a dataset ({INDEX_NAME}); choose another directory")
        if not isinstance(kind, ModelKind):
            raise ValueError(f"kind must be a ModelKind, got {kind!r}")
        h, w = (int(v) for v in tile_hw)
        if h < 1 or w < 1 or int(shard_size) < 1:
            raise ValueError(f"tile_hw and shard_size must be positive, got {tile_hw} and {shard_size}")
        self.directory.mkdir(parents=True, exist_ok=True)
        self.kind, self.tile_hw, self.shard_size = kind, (h, w), int(shard_size)
        self.generator = dict(generator or {})
        self._channels = len(MODEL_CHANNELS[kind])
        self._pending: dict[str, list] = {name: [] for name in _ARRAYS}
        self._shards: list[dict] = []
        self._closed = False

    def add(self, inputs: np.ndarray, target: np.ndarray, mask: Optional[np.ndarray] = None, group: int = 0) -> None:
        """Append one sample.

        Args:
            inputs: float32 ``[C, h, w]`` encoded network input.
            target: bool ``[h, w]`` wall labels.
            mask: bool ``[h, w]`` where the loss is defined (None: everywhere).
            group: building id (validation splits keep a building's samples together).
        """
        if self._closed:
            raise ValueError("this ShardWriter is closed")
        inputs, target = np.asarray(inputs), np.asarray(target)
        expected = (self._channels, *self.tile_hw)
        if inputs.dtype != np.float32 or inputs.shape != expected:
            raise ValueError(f"inputs must be float32 {list(expected)}, got {inputs.dtype} {list(inputs.shape)}")
        if not np.isfinite(inputs).all():
            raise ValueError("inputs must be finite")
        mask = np.ones(self.tile_hw, bool) if mask is None else np.asarray(mask)
        for name, array in (("target", target), ("mask", mask)):
            if array.dtype != np.bool_ or array.shape != self.tile_hw:
                raise ValueError(f"{name} must be bool {list(self.tile_hw)}, got {array.dtype} {list(array.shape)}")
        self._pending["inputs"].append(inputs.astype(np.float16))
        self._pending["targets"].append(target.astype(np.uint8))
        self._pending["mask"].append(mask.astype(np.uint8))
        self._pending["groups"].append(np.int32(group))
        if len(self._pending["inputs"]) >= self.shard_size:
            self._flush()

    def _flush(self) -> None:
        count = len(self._pending["inputs"])
        if count == 0:
            return
        name = f"shard_{len(self._shards):05d}"
        hashes = {}
        for array_name in _ARRAYS:
            path = self.directory / f"{name}.{array_name}.npy"
            array = np.stack(self._pending[array_name])
            write_atomically(path, lambda part: _save_npy(array, part))
            hashes[array_name] = sha256_file(path)
            self._pending[array_name] = []
        self._shards.append({"name": name, "count": count, "sha256": hashes})

    def close(self) -> DatasetInfo:
        """Write the last shard and the index; returns the dataset's :class:`DatasetInfo`."""
        if not self._closed:
            self._flush()
            if not self._shards:
                raise ValueError("no samples were added; an empty dataset is not written")
            index = {"format": DATASET_FORMAT, "kind": self.kind.value, "channels": list(MODEL_CHANNELS[self.kind]),
                     "tile_hw": list(self.tile_hw), "shards": self._shards, "generator": self.generator}
            write_atomically(self.directory / INDEX_NAME, json.dumps(index, indent=1, sort_keys=True))
            self._closed = True
        return read_index(self.directory)

    def __enter__(self) -> "ShardWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()


def read_index(directory: PathLike) -> DatasetInfo:
    """Read and validate ``directory/index.json``.

    Raises:
        ValueError: no index, another format, or inconsistent entries.
    """
    directory = Path(directory)
    path = directory / INDEX_NAME
    if not path.is_file():
        raise ValueError(f"{directory} holds no dataset ({INDEX_NAME} missing; an interrupted writer leaves none)")
    document = json.loads(path.read_text())
    if document.get("format") != DATASET_FORMAT:
        raise ValueError(f"{path} has format {document.get('format')!r}, expected {DATASET_FORMAT!r}")
    kind = ModelKind(document["kind"])
    channels = tuple(document["channels"])
    if channels != MODEL_CHANNELS[kind]:
        raise ValueError(f"{path} lists channels {list(channels)}, {kind.value} inputs are "
                         f"{list(MODEL_CHANNELS[kind])}")
    return DatasetInfo(directory=directory, kind=kind, channels=channels,
                       tile_hw=tuple(int(v) for v in document["tile_hw"]),  # type: ignore[arg-type]
                       shards=tuple((s["name"], int(s["count"])) for s in document["shards"]),
                       generator=document.get("generator", {}),
                       data_sha256=hashlib.sha256(_canonical(document)).hexdigest())


def split_by_group(groups: np.ndarray, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(train, val)`` with whole groups (buildings) on one side; about ``val_fraction`` of the samples
    go to validation, at least one group when there are two or more (none when ``val_fraction`` is 0)."""
    groups = np.asarray(groups)
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must lie in [0, 1), got {val_fraction}")
    unique = np.unique(groups)
    if val_fraction == 0.0 or len(unique) < 2:
        return np.arange(len(groups)), np.zeros(0, np.int64)
    order = np.random.default_rng(seed).permutation(unique)
    val_groups, taken = [], 0
    for group in order[:-1]:
        if val_groups and taken >= val_fraction * len(groups):
            break
        val_groups.append(group)
        taken += int(np.count_nonzero(groups == group))
    is_val = np.isin(groups, val_groups)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


class ShardDataset:
    """Random access to a dataset (memory-mapped shards), as a ``torch.utils.data.Dataset``.

    ``dataset[i]`` is ``(inputs, target, mask)``: float32 tensors ``[C, h, w]``, ``[1, h, w]``, ``[1, h, w]``.

    Args:
        directory: the dataset.
        kind: if given, the dataset must be of this kind.
        verify: recompute every file's sha256 against the index (slow for large datasets).

    Attributes:
        shard_arrays: ``"inputs"``, ``"targets"``, ``"mask"`` and ``"groups"`` -> that array of every shard, in
            the index's order (memory-mapped numpy arrays, one row per sample).
    """

    def __init__(self, directory: PathLike, kind: Optional[ModelKind] = None, verify: bool = False):
        self.info = read_index(directory)
        if kind is not None and self.info.kind is not kind:
            raise ValueError(f"{directory} holds {self.info.kind.value} data, expected {kind.value}")
        index = json.loads((self.info.directory / INDEX_NAME).read_text())
        self.shard_arrays: dict[str, list[np.ndarray]] = {name: [] for name in _ARRAYS}
        for shard in index["shards"]:
            for name in _ARRAYS:
                path = self.info.directory / f"{shard['name']}.{name}.npy"
                if not path.is_file():
                    raise ValueError(f"dataset file {path} is missing")
                if verify and sha256_file(path) != shard["sha256"][name]:
                    raise ValueError(f"dataset file {path} does not match the sha256 in the index")
                array = np.load(path, mmap_mode="r")
                if len(array) != shard["count"]:
                    raise ValueError(f"dataset file {path} holds {len(array)} samples, the index says "
                                     f"{shard['count']}")
                self.shard_arrays[name].append(array)
        counts = np.array([n for _, n in self.info.shards])
        self._starts = np.concatenate([[0], np.cumsum(counts)])
        self.groups = np.concatenate([np.asarray(g, np.int64) for g in self.shard_arrays["groups"]])

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _locate(self, index: int) -> tuple[int, int]:
        if not 0 <= index < len(self):
            raise IndexError(f"sample {index} out of range for {len(self)} samples")
        shard = int(np.searchsorted(self._starts, index, side="right") - 1)
        return shard, index - int(self._starts[shard])

    def arrays(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample ``index`` as numpy: float32 inputs ``[C, h, w]``, bool target and mask ``[h, w]``."""
        shard, row = self._locate(int(index))
        return (np.asarray(self.shard_arrays["inputs"][shard][row], np.float32),
                np.asarray(self.shard_arrays["targets"][shard][row]).astype(bool),
                np.asarray(self.shard_arrays["mask"][shard][row]).astype(bool))

    def __getitem__(self, index: int):
        import torch

        inputs, target, mask = self.arrays(index)
        return (torch.from_numpy(inputs), torch.from_numpy(target[None].astype(np.float32)),
                torch.from_numpy(mask[None].astype(np.float32)))


def synthetic_walls(rng: np.random.Generator, shape: tuple[int, int], room_cells: tuple[int, int] = (20, 60)
                    ) -> np.ndarray:
    """A random floor plan: bool ``[H, W]`` with one-cell walls splitting the area into rooms recursively,
    each split wall with a 6-10-cell door, and an outer wall."""
    height, width = shape
    walls = np.zeros(shape, bool)
    walls[0, :] = walls[-1, :] = walls[:, 0] = walls[:, -1] = True
    boxes = [(0, height - 1, 0, width - 1)]
    while boxes:
        r0, r1, c0, c1 = boxes.pop()
        tall, wide = r1 - r0, c1 - c0
        if max(tall, wide) < 2 * room_cells[0] or (max(tall, wide) < room_cells[1] and rng.random() < 0.5):
            continue
        if wide >= tall:
            c = int(rng.integers(c0 + room_cells[0], c1 - room_cells[0] + 1))
            walls[r0:r1 + 1, c] = True
            door = min(int(rng.integers(6, 11)), tall - 2)  # strictly inside the box: junctions stay closed
            d = int(rng.integers(r0 + 1, r1 - door + 1))
            walls[d:d + door, c] = False
            boxes += [(r0, r1, c0, c), (r0, r1, c, c1)]
        else:
            r = int(rng.integers(r0 + room_cells[0], r1 - room_cells[0] + 1))
            walls[r, c0:c1 + 1] = True
            door = min(int(rng.integers(6, 11)), wide - 2)
            d = int(rng.integers(c0 + 1, c1 - door + 1))
            walls[r, d:d + door] = False
            boxes += [(r0, r, c0, c1), (r, r1, c0, c1)]
    return walls


def _synthetic_pix2pix(rng: np.random.Generator, size: int) -> tuple[np.ndarray, np.ndarray]:
    """A window whose 'back-projection' is the hidden walls smeared along arcs plus clutter, and the walls."""
    walls = synthetic_walls(rng, (size, size), (max(size // 8, 4), max(size // 3, 8)))
    hidden = walls & (rng.random((size, size)) < 0.9)
    smeared = ndimage.gaussian_filter(hidden.astype(np.float64), sigma=float(rng.uniform(1.0, 2.5)))
    yy, xx = np.mgrid[:size, :size] - size / 2
    rings = np.cos(np.hypot(yy, xx) * rng.uniform(0.3, 0.8) + rng.uniform(0, 2 * np.pi)) ** 8
    bp = smeared + 0.05 * rings * rng.random() + 0.02 * rng.random((size, size))
    bp = (bp / bp.max()).astype(np.float32)
    return bp, walls


def _synthetic_map(rng: np.random.Generator, size: int, kind: ModelKind) -> tuple[np.ndarray, np.ndarray]:
    """An encoded observed map (a disc of the plan seen around a random point) and the full plan."""
    from superex_deploy.onboard.prediction.inference import encode_map

    walls = synthetic_walls(rng, (size, size), (max(size // 8, 4), max(size // 3, 8)))
    yy, xx = np.mgrid[:size, :size]
    centre = rng.uniform(0.25, 0.75, 2) * size
    seen = np.hypot(yy - centre[0], xx - centre[1]) < rng.uniform(0.2, 0.45) * size
    observed = np.full((size, size), -1, np.int8)
    observed[seen] = walls[seen].astype(np.int8)
    evidence = None
    if kind is ModelKind.LAMA_BP:
        hidden = walls & ~seen & (np.hypot(yy - centre[0], xx - centre[1]) < 0.6 * size)
        evidence = ndimage.gaussian_filter(hidden.astype(np.float64), 1.0)
        evidence = (evidence / max(evidence.max(), 1e-9)).astype(np.float32)
    return encode_map(observed, evidence, kind)[0], walls


def write_synthetic_dataset(directory: PathLike, kind: ModelKind, n_samples: int, tile: int, seed: int = 0,
                            shard_size: int = 256) -> DatasetInfo:
    """A synthetic dataset of random rectangular floor plans, for sanity training and tests (never for models
    that are reported). Pix2Pix samples smear the walls into a fake back-projection; LaMa samples show a disc
    of the plan and (LAMA_BP) the blurred hidden walls as evidence. Groups cycle over 8 fake buildings."""
    from superex_deploy.onboard.prediction.inference import encode_bp_windows

    rng = np.random.default_rng(seed)
    generator = {"source": "synthetic", "n_samples": int(n_samples), "tile": int(tile), "seed": int(seed)}
    with ShardWriter(directory, kind, (tile, tile), shard_size, generator) as writer:
        for i in range(int(n_samples)):
            if kind is ModelKind.PIX2PIX:
                bp, walls = _synthetic_pix2pix(rng, tile)
                inputs = encode_bp_windows(bp[None])[0]
            else:
                inputs, walls = _synthetic_map(rng, tile, kind)
            writer.add(inputs, walls, group=i % 8)
    return read_index(directory)
