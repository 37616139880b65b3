"""Occupancy grids: the bundled KTH floor plans, image files and ROS map_server YAML.

Bundled maps (``superex_deploy/data/kth``, see its README for provenance and attribution) are 0.1 m/cell,
8-bit grey PNGs with 0 = wall and 255 = free, plus a ``NAME_valid.png`` mask of the area inside the building
that coverage is measured against.

Every map is held to the limits of :func:`superex_deploy.messages.check_map_size` (at most
:func:`~superex_deploy.messages.max_map_cells` cells, ``SUPEREX_MAX_MAP_CELLS`` to change it; no resolution finer
than 1 mm): an image file is measured by its header, before its pixels are decoded.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal, Union

import numpy as np

from superex_deploy.messages import check_map_size, max_map_cells

__all__ = ["OccupancyGrid", "coverage", "load_map", "list_maps", "start_poses", "map_building", "random_start",
           "largest_region_start", "DATA_DIR",
           "MAP_SERVER_MODES", "MAP_SERVER_FREE_THRESH"]

DATA_DIR = Path(__file__).resolve().parent / "data" / "kth"
_SPLITS = ("eval", "train")
_IMAGE_SUFFIXES = (".png", ".pgm", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """A 2-D occupancy grid.

    Attributes:
        occupied: bool ``[H, W]``, True where a wall is; ``[row, col]``, row 0 at the top.
        valid: bool ``[H, W]``, True inside the area an exploration can cover (coverage is measured on it).
        resolution_m: metres per cell (> 0).
        name: a human-readable name (the bundled map's name or the file stem).
        origin_xy: map-frame position (metres) of the grid's lower-left corner, as a map_server YAML's ``origin``
            gives it (``(0, 0)`` for images and bundled maps). The simulator runs with the corner at ``(0, 0)``.

    Raises:
        ValueError: arrays of another type or shape, a bad resolution, a map beyond the size limits
            (:func:`superex_deploy.messages.check_map_size`).
    """

    occupied: np.ndarray
    valid: np.ndarray
    resolution_m: float
    name: str
    origin_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        occupied = np.asarray(self.occupied)
        valid = np.asarray(self.valid)
        if occupied.dtype != np.bool_ or valid.dtype != np.bool_:
            raise ValueError(f"occupied and valid must be bool arrays, got {occupied.dtype} and {valid.dtype}")
        if occupied.ndim != 2 or min(occupied.shape) < 1:
            raise ValueError(f"occupied must be a non-empty 2-D [rows, cols] array, got shape {occupied.shape}")
        if valid.shape != occupied.shape:
            raise ValueError(f"valid has shape {valid.shape} but occupied has shape {occupied.shape}")
        resolution = float(self.resolution_m)
        if not (np.isfinite(resolution) and resolution > 0.0):
            raise ValueError(f"resolution_m must be positive and finite, got {self.resolution_m}")
        check_map_size(occupied.shape, resolution, f"map {self.name!r}")
        # Read-only contiguous copies: a grid is shared by simulators, mappers and caches keyed on it.
        for field_name, array in (("occupied", occupied), ("valid", valid)):
            array = np.ascontiguousarray(array).copy()
            array.flags.writeable = False
            object.__setattr__(self, field_name, array)
        object.__setattr__(self, "resolution_m", resolution)
        try:
            origin = tuple(float(v) for v in self.origin_xy)
        except (TypeError, ValueError):
            raise ValueError(f"origin_xy must be an (x, y) pair of numbers, got {self.origin_xy!r}") from None
        if len(origin) != 2 or not all(np.isfinite(origin)):
            raise ValueError(f"origin_xy must be a finite (x, y) pair, got {self.origin_xy!r}")
        object.__setattr__(self, "origin_xy", origin)

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.occupied.shape  # type: ignore[return-value]

    def is_free(self, rc) -> bool:
        """True if cell ``rc = (row, col)`` is inside the grid and not a wall."""
        r, c = int(rc[0]), int(rc[1])
        return 0 <= r < self.shape[0] and 0 <= c < self.shape[1] and not self.occupied[r, c]

    def check_pose(self, pose_rc) -> tuple[int, int]:
        """Validate a robot cell: inside the grid and not in a wall. Returns it as ``(int, int)``."""
        try:
            r, c = (int(v) for v in pose_rc)
        except (TypeError, ValueError):
            raise ValueError(f"pose must be a (row, col) pair of integers, got {pose_rc!r}") from None
        if not (0 <= r < self.shape[0] and 0 <= c < self.shape[1]):
            raise ValueError(f"pose (row, col) = {(r, c)} lies outside map {self.name!r} of shape {self.shape}")
        if self.occupied[r, c]:
            raise ValueError(f"pose (row, col) = {(r, c)} lies inside a wall of map {self.name!r}")
        return r, c


def coverage(known: np.ndarray, valid: np.ndarray) -> float:
    """Fraction of the valid area that is known: what the world reports while it runs
    (:meth:`World.coverage <superex_deploy.sim.world.World.coverage>`) and the evaluation's coverage series read.

    Args:
        known: bool ``[H, W]`` cells known (seen free, seen wall or carved).
        valid: bool ``[H, W]`` the area coverage is measured on (:attr:`OccupancyGrid.valid`).

    Returns:
        ``|known & valid| / |valid|`` in [0, 1]; 1.0 for an empty valid area.
    """
    known, valid = np.asarray(known), np.asarray(valid)
    if known.shape != valid.shape:
        raise ValueError(f"known has shape {known.shape}, valid has {valid.shape}")
    total = np.count_nonzero(valid)
    return np.count_nonzero(known & valid) / total if total else 1.0


@lru_cache(maxsize=1)
def _manifest() -> dict:
    return json.loads((DATA_DIR / "manifest.json").read_text())


def list_maps(split: Literal["eval", "train"]) -> list[str]:
    """Names of the bundled maps of one split, sorted. ``eval``: the 10-floor benchmark; ``train``: 112 floors
    from other buildings (the only ones models may be trained on)."""
    if split not in _SPLITS:
        raise ValueError(f"split must be one of {_SPLITS}, got {split!r}")
    return sorted(_manifest()[split])


def _split_of(name: str) -> str:
    for split in _SPLITS:
        if name in _manifest()[split]:
            return split
    raise ValueError(f"unknown bundled map {name!r}; see list_maps('eval') and list_maps('train')")


def start_poses(name: str) -> list[tuple[int, int]]:
    """The benchmark's start cells ``(row, col)`` of an eval map (4 per map, as in MapEx)."""
    entry = _manifest()[_split_of(name)][name]
    if "start_poses_rc" not in entry:
        raise ValueError(f"map {name!r} has no benchmark start poses (only eval maps do)")
    return [(int(r), int(c)) for r, c in entry["start_poses_rc"]]


def map_building(name: str) -> int:
    """Building-group id of a bundled map: floors of one building share it (split training data by it)."""
    return int(_manifest()[_split_of(name)][name]["building"])


def _read_image(path: Path, resolution_m: float, source: str) -> np.ndarray:
    """The pixels of an image file, after checking its size (read from the header) against the map limits."""
    from PIL import Image, UnidentifiedImageError

    limit = max_map_cells()
    if Image.MAX_IMAGE_PIXELS is not None and Image.MAX_IMAGE_PIXELS < limit:
        # PIL's decompression-bomb guard must not refuse what SUPEREX_MAX_MAP_CELLS allows: ours is the guard.
        Image.MAX_IMAGE_PIXELS = limit
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # refused below, with the limit named
            image = Image.open(path)
        with image:
            width, height = image.size  # from the header: nothing is decoded yet
            check_map_size((height, width), resolution_m, source)
            image = image.convert("L") if image.mode not in ("L", "I", "I;16", "F") else image
            pixels = np.asarray(image)
    except Image.DecompressionBombError as error:  # PIL's guard: above twice our limit
        raise ValueError(f"{source}: {error}; more than the limit of {limit:,} map cells (the environment variable "
                         f"SUPEREX_MAX_MAP_CELLS raises it)") from None
    except (UnidentifiedImageError, OSError) as error:
        raise ValueError(f"cannot read image {path}: {error}") from None
    if pixels.ndim != 2 or min(pixels.shape) < 1:
        raise ValueError(f"image {path} must be a non-empty 2-D grey image, got shape {pixels.shape}")
    return pixels


def _normalised(pixels: np.ndarray) -> np.ndarray:
    """Map pixel values to [0, 1] brightness whatever the bit depth."""
    pixels = pixels.astype(np.float64)
    top = 255.0 if pixels.max(initial=0.0) <= 255.0 else 65535.0
    return pixels / top


def _grid_from_image(path: Path, resolution_m: float, occupied_thresh: float = 0.65,
                     valid_path: Path | None = None, name: str | None = None,
                     source: str | None = None) -> OccupancyGrid:
    # A plain image: dark is wall, occupancy probability p = (255 - v) / 255 (YAML maps: _load_ros_yaml).
    source = source or f"map image {path}"
    occupied = 1.0 - _normalised(_read_image(path, resolution_m, source)) > occupied_thresh
    if valid_path is not None and valid_path.exists():
        valid_pixels = _read_image(valid_path, resolution_m, f"valid mask {valid_path}")
        if valid_pixels.shape != occupied.shape:
            raise ValueError(f"valid mask {valid_path} has shape {valid_pixels.shape}, map has {occupied.shape}")
        valid = valid_pixels > 127
    else:
        valid = ~occupied
    return OccupancyGrid(occupied=occupied, valid=valid, resolution_m=resolution_m, name=name or path.stem)


MAP_SERVER_MODES = ("trinary", "scale", "raw")
"""The ``mode`` values of a ROS map_server YAML (``trinary`` when absent)."""

MAP_SERVER_FREE_THRESH = 0.196
"""map_server's usual ``free_thresh``, used when a YAML leaves it out (a pixel of map_saver's unknown grey 205 lies
just above it: p = 0.196078)."""


def _number(spec: dict, key: str, path: Path, default=None) -> float:
    value = spec.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ValueError(f"map YAML {path}: {key} must be a finite number, got {value!r}")
    return float(value)


def _load_ros_yaml(path: Path) -> OccupancyGrid:
    """A ROS map_server map (``image``, ``resolution``, ``origin``, ``mode``, ``negate``, ``occupied_thresh``,
    ``free_thresh``) as map_server reads it: each pixel's occupancy probability ``p`` (``trinary`` / ``scale``:
    ``(255 - v) / 255``, or ``v / 255`` with ``negate``; ``raw``: ``v / 100`` for ``v <= 100``, unknown above, and
    ``negate`` ignored, as map_server does) is occupied above ``occupied_thresh``, free below ``free_thresh`` and
    unknown in between (a map without a free pixel is refused). Unknown cells lie **outside the world**: walls to
    the simulator (not traversable, opaque to the LiDAR and the SPAD) and outside the valid area, so that coverage
    counts known free space only.

    ``origin`` ``[x, y, yaw]`` is the map-frame position of the image's lower-left corner: it is checked (a yaw
    other than 0 is refused: rotate the image instead) and kept as :attr:`OccupancyGrid.origin_xy`; the simulator
    itself runs with the corner at ``(0, 0)`` (``--pose`` is given in cells).
    """
    import yaml

    try:
        spec = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ValueError(f"cannot parse map YAML {path}: {error}") from None
    if not isinstance(spec, dict) or "image" not in spec or "resolution" not in spec:
        raise ValueError(f"map YAML {path} must define at least 'image' and 'resolution'")
    image_path = Path(str(spec["image"]))
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    if not image_path.exists():
        raise ValueError(f"map YAML {path} names image {image_path}, which does not exist")
    resolution = _number(spec, "resolution", path)
    if resolution <= 0.0:
        raise ValueError(f"map YAML {path}: resolution must be positive, got {spec['resolution']}")
    occupied_thresh = _number(spec, "occupied_thresh", path, 0.65)
    free_thresh = _number(spec, "free_thresh", path, MAP_SERVER_FREE_THRESH)
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
        raise ValueError(f"map YAML {path}: need 0 <= free_thresh <= occupied_thresh <= 1, got free_thresh "
                         f"{free_thresh} and occupied_thresh {occupied_thresh}")
    mode = spec.get("mode", "trinary")
    if mode not in MAP_SERVER_MODES:
        raise ValueError(f"map YAML {path}: mode must be one of {', '.join(MAP_SERVER_MODES)}, got {mode!r}")
    negate = spec.get("negate", 0)
    if not (isinstance(negate, bool) or (isinstance(negate, (int, float)) and negate in (0, 1))):
        raise ValueError(f"map YAML {path}: negate must be 0 or 1, got {negate!r}")
    origin = spec.get("origin", [0.0, 0.0, 0.0])
    if not isinstance(origin, (list, tuple)) or len(origin) != 3 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in origin):
        raise ValueError(f"map YAML {path}: origin must be three finite numbers [x, y, yaw], got {origin!r}")
    if origin[2] != 0:
        raise ValueError(f"map YAML {path}: a rotated origin (yaw {origin[2]}) is not supported; rotate the image "
                         f"and give yaw 0")
    source = f"map YAML {path} (image {image_path})"
    pixels = _read_image(image_path, resolution, source)
    if mode == "raw":
        values = pixels.astype(np.float64)
        known = values <= 100.0
        occupancy = np.where(known, values / 100.0, np.nan)
    else:
        brightness = _normalised(pixels)
        occupancy = brightness if negate else 1.0 - brightness
    with np.errstate(invalid="ignore"):
        occupied = occupancy > occupied_thresh
        free = occupancy < free_thresh
    if not free.any():  # a world with no free cell: every start would be refused as "inside a wall"
        raise ValueError(f"map YAML {path}: no pixel is free (occupancy below free_thresh {free_thresh} in {mode} "
                         f"mode{', negated' if negate and mode != 'raw' else ''}): check free_thresh, mode and negate")
    return OccupancyGrid(occupied=~free, valid=free & ~occupied, resolution_m=resolution, name=path.stem,
                         origin_xy=(float(origin[0]), float(origin[1])))


def load_map(name_or_path: Union[str, Path], resolution_m: float = 0.1) -> OccupancyGrid:
    """Load a bundled map by name, an image file (PNG/PGM/...; dark = wall) or a ROS map_server YAML.

    Args:
        name_or_path: a bundled map name (see :func:`list_maps`), or a path to an image or ``.yaml`` file.
            For an image ``X.png``, a sibling ``X_valid.png`` (255 = inside) is used as the valid mask if present;
            otherwise every free cell is valid. A ``.yaml`` is read with map_server's semantics (thresholds,
            ``mode``, ``negate``, ``origin``), its unknown cells outside the world (see :func:`_load_ros_yaml`).
        resolution_m: metres per cell for plain image files (ignored for bundled maps and YAML, which carry
            their own).

    Returns:
        The :class:`OccupancyGrid`.

    Raises:
        ValueError: missing file, unreadable image, empty or 1-D image, resolution <= 0, malformed YAML, a map
            beyond the size limits (:func:`superex_deploy.messages.check_map_size`; checked on the image header).
    """
    key = str(name_or_path)
    if not isinstance(name_or_path, Path) and key in set(_manifest()["eval"]) | set(_manifest()["train"]):
        split = _split_of(key)
        return _grid_from_image(DATA_DIR / split / f"{key}.png", float(_manifest()["resolution_m"]),
                                occupied_thresh=0.5, valid_path=DATA_DIR / split / f"{key}_valid.png", name=key)
    path = Path(name_or_path)
    if not path.exists():
        raise ValueError(f"no bundled map named {key!r} and no such file; bundled maps: list_maps('eval'), "
                         f"list_maps('train')")
    if path.is_dir():
        raise ValueError(f"{path} is a directory, not a map file")
    if path.suffix.lower() in (".yaml", ".yml"):
        return _load_ros_yaml(path)
    if path.suffix.lower() not in _IMAGE_SUFFIXES:
        raise ValueError(f"unsupported map file type {path.suffix!r}; use an image ({', '.join(_IMAGE_SUFFIXES)}) "
                         f"or a ROS map_server .yaml")
    if not (float(resolution_m) > 0.0 and np.isfinite(float(resolution_m))):
        raise ValueError(f"resolution_m must be positive, got {resolution_m}")
    return _grid_from_image(path, float(resolution_m), valid_path=path.with_name(f"{path.stem}_valid.png"))


def random_start(grid: OccupancyGrid, rng: np.random.Generator, min_clearance_m: float) -> tuple[int, int]:
    """A uniformly drawn valid free cell at least ``min_clearance_m`` from every wall (the clearest cell if
    none is that clear): start cells for maps without benchmark start poses (the train floors)."""
    from scipy import ndimage

    clearance = ndimage.distance_transform_edt(~grid.occupied) * grid.resolution_m
    candidates = grid.valid & ~grid.occupied & (clearance >= min_clearance_m)
    cells = np.argwhere(candidates)
    if len(cells) == 0:
        cells = np.argwhere(clearance == clearance.max())
    r, c = cells[rng.integers(len(cells))]
    return int(r), int(c)


def largest_region_start(grid: OccupancyGrid, rng: np.random.Generator, min_clearance_m: float) -> tuple[int, int]:
    """A start cell drawn uniformly from the largest connected free region of the valid area (4-connected free,
    valid cells), among its cells at least ``min_clearance_m`` from every wall (the region's clearest cell if none
    is that clear): for a user's floor that has no benchmark start poses, a start from which the building, not a
    closet or a pocket outside it, can be explored.

    Raises:
        ValueError: a map with no free valid cell.
    """
    from scipy import ndimage

    free = grid.valid & ~grid.occupied
    labels, count = ndimage.label(free)
    if count == 0:
        raise ValueError(f"map {grid.name!r} has no free cell inside its valid area to start from")
    sizes = np.bincount(labels.ravel())[1:]
    region = labels == (int(np.argmax(sizes)) + 1)
    clearance = ndimage.distance_transform_edt(~grid.occupied) * grid.resolution_m
    candidates = region & (clearance >= min_clearance_m)
    cells = np.argwhere(candidates)
    if len(cells) == 0:
        cells = np.argwhere(region & (clearance == clearance[region].max()))
    r, c = cells[rng.integers(len(cells))]
    return int(r), int(c)
