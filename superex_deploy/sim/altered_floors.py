"""The altered floors of ``superex benchmark --suite altered``: one fixed seed per scenario, and a cache on disk.

Every eval scenario (map, start cell) gets its floor from :func:`superex_deploy.sim.alterations.alter_floor_with_record`
with the default :class:`~superex_deploy.sim.alterations.AlterationConfig` (fixed on the train floors) and the seed
:func:`alteration_seed`: ``zlib.crc32(f"{map}:{row}:{col}")`` of the map's name and the start cell. The seed depends
on nothing else (not the row, not the planner's seed), so every row of the suite meets the same floor, and a rerun
anywhere makes it again. A scenario where no passage qualifies keeps its floor unaltered (no dead end) and stays in
the suite, as the eval scenarios are fixed.

Making a floor takes tens of seconds, and every row of the suite needs it: the suite makes each floor once, in a
first pass, into ``OUT/floors/`` (:func:`make_floor`), and the episodes read it back (:func:`load_floor`). A cached
file records its seed and generator configuration and is remade when either differs.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import asdict
from pathlib import Path
from typing import Optional, Union

import numpy as np

from superex_deploy.maps import OccupancyGrid
from superex_deploy.sim.dead_ends import DeadEnd

__all__ = ["ALTERATION_SEED_RULE", "alteration_seed", "floor_path", "record_arrays", "make_floor", "load_floor",
           "floor_summary"]

ALTERATION_SEED_RULE = 'zlib.crc32(f"{map}:{row}:{col}")'
"""How :func:`alteration_seed` derives a scenario's seed (recorded in the suite's settings)."""


def alteration_seed(map_name: str, start_rc) -> int:
    """The alteration seed of a scenario: ``zlib.crc32(f"{map_name}:{row}:{col}")`` (an integer in [0, 2**32)).

    Raises:
        ValueError: an empty map name or a start that is not two integers.
    """
    if not isinstance(map_name, str) or not map_name:
        raise ValueError(f"map_name must be a non-empty string, got {map_name!r}")
    row, col = _cell(start_rc)
    return zlib.crc32(f"{map_name}:{row}:{col}".encode())


def _cell(start_rc) -> tuple[int, int]:
    values = tuple(start_rc)
    if len(values) != 2 or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in values):
        raise ValueError(f"start_rc must be two integers (row, col), got {start_rc!r}")
    return int(values[0]), int(values[1])


def floor_path(folder: Union[str, Path], map_name: str, start_rc) -> Path:
    """Where a scenario's altered floor is cached: ``FOLDER/MAP_ROW_COL.npz``."""
    row, col = _cell(start_rc)
    return Path(folder) / f"{map_name}_{row}_{col}.npz"


def _config_json(cfg) -> dict:
    return json.loads(json.dumps(asdict(cfg)))


def _cached_meta(path: Path, seed: int, cfg) -> Optional[dict]:
    """The meta of a cached floor made with ``seed`` and ``cfg``, or None (no file, or another seed or config)."""
    if not path.is_file():
        return None
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
    return meta if meta.get("seed") == seed and meta.get("config") == _config_json(cfg) else None


def record_arrays(record) -> tuple[dict[str, np.ndarray], list[dict]]:
    """What an altered floor's file holds of an :class:`~superex_deploy.sim.alterations.AlteredFloor`: the
    arrays (the altered grid's ``occupied`` and ``valid``; per dead end ``i`` its ``pocket_i``, ``depth_i``,
    ``mouth_i``, ``face_i``) and one JSON-ready summary per alteration (kind, segment, dead-end length / hidden
    metres / area, cut cells)."""
    arrays = {"occupied": record.grid.occupied, "valid": record.grid.valid}
    alterations = []
    for i, alteration in enumerate(record.alterations):
        dead_end = alteration.dead_end
        arrays[f"pocket_{i}"], arrays[f"depth_{i}"] = dead_end.pocket, dead_end.depth_m
        arrays[f"mouth_{i}"], arrays[f"face_{i}"] = dead_end.mouth, dead_end.face
        alterations.append({"kind": alteration.kind, "segment_rc": alteration.segment_rc.tolist(),
                            "length_m": dead_end.length_m, "hidden_m": dead_end.hidden_m,
                            "area_m2": dead_end.area_m2, "cut_cells": int(alteration.cut.sum())})
    return arrays, alterations


def make_floor(map_name: str, start_rc, folder: Union[str, Path], cfg=None, seed: Optional[int] = None) -> dict:
    """Make (or find cached) the altered floor of one scenario under ``folder`` and return its summary
    (:func:`floor_summary`). ``cfg``: the generator's configuration, by default ``AlterationConfig()``; ``seed``:
    by default the scenario's :func:`alteration_seed`."""
    from superex_deploy.files import write_atomically
    from superex_deploy.maps import load_map
    from superex_deploy.sim.alterations import AlterationConfig, alter_floor_with_record

    cfg = AlterationConfig() if cfg is None else cfg
    seed = alteration_seed(map_name, start_rc) if seed is None else int(seed)
    path = floor_path(folder, map_name, start_rc)
    meta = _cached_meta(path, seed, cfg)
    if meta is not None:
        return floor_summary(meta)
    record = alter_floor_with_record(load_map(map_name), _cell(start_rc), seed, cfg)
    arrays, alterations = record_arrays(record)
    meta = {"map": map_name, "start_rc": list(_cell(start_rc)), "seed": seed, "config": _config_json(cfg),
            "resolution_m": record.grid.resolution_m, "kept_fraction": record.kept_fraction,
            "candidates_tried": record.candidates_tried, "alterations": alterations}
    path.parent.mkdir(parents=True, exist_ok=True)

    def write(part: Path) -> None:
        with open(part, "wb") as handle:  # a file object: np.savez would add ".npz" to the temporary name
            np.savez_compressed(handle, meta=json.dumps(meta), **arrays)

    write_atomically(path, write)
    return floor_summary(meta)


def load_floor(map_name: str, start_rc, folder: Union[str, Path], cfg=None, seed: Optional[int] = None
               ) -> tuple[OccupancyGrid, list[DeadEnd], dict]:
    """``(altered grid, its dead ends, meta)`` of one scenario, made first when not cached under ``folder`` with
    this ``seed`` (by default :func:`alteration_seed`) and ``cfg`` (by default ``AlterationConfig()``).

    The grid keeps the map's name; the dead ends are those of :attr:`AlteredFloor.dead_ends
    <superex_deploy.sim.alterations.AlteredFloor.dead_ends>` (empty where no passage qualified)."""
    make_floor(map_name, start_rc, folder, cfg, seed)
    with np.load(floor_path(folder, map_name, start_rc)) as data:
        meta = json.loads(str(data["meta"]))
        grid = OccupancyGrid(occupied=data["occupied"], valid=data["valid"], resolution_m=meta["resolution_m"],
                             name=map_name)
        dead_ends = [DeadEnd(pocket=data[f"pocket_{i}"], depth_m=data[f"depth_{i}"], mouth=data[f"mouth_{i}"],
                             face=data[f"face_{i}"], length_m=m["length_m"], hidden_m=m["hidden_m"],
                             area_m2=m["area_m2"]) for i, m in enumerate(meta["alterations"])]
    return grid, dead_ends, meta


def floor_summary(meta: dict) -> dict:
    """A cached floor's meta without its configuration: map, start, seed, kept share, the alterations."""
    return {key: value for key, value in meta.items() if key != "config"}
