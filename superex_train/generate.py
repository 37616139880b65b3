"""Training data from the simulator: exploration episodes on the KTH ``train`` maps, sampled along the way.

Partial observations must look like the ones the models see when deployed, so samples are taken inside
exploration episodes (random free start cells, planners cycled over ``planners``), never from random masks.

* **Pix2Pix** (:func:`generate_pix2pix`): every ``sample_every`` steps a SPAD scan is simulated at the robot's
  cell and back-projected with the cells known at that step skipped (as :class:`~superex_deploy.sim.sensing.
  SpadSensing` does). Input: the raw back-projection window (``window_cells`` square, robot at its centre cell).
  Target: the scan's ``h2`` cells (simulator truth, :func:`~superex_deploy.sim.spad.nlos_ground_truth`) that are
  still unknown. Loss mask: unknown cells of the map's area or walls (``valid | occupied``: ``valid`` excludes wall cells;
  known cells receive no votes, and are known anyway).
* **LaMa** (:func:`generate_lama`): the episodes run the SuperEx sensing (SPAD scan, carving and evidence at
  every step, the evidence filtered by a given Pix2Pix model), and every ``sample_every`` steps
  ``tiles_per_sample`` tiles of ``tile_cells`` are cut around the robot (centres jittered by up to half a tile).
  The same tiles go into two datasets: LAMA_BP (observed map with carving, evidence, unknown mask) and
  LAMA_LOS (the line-of-sight observation alone, as the baselines see it). Target: the ground-truth walls;
  loss mask: cells inside the map.

Every sample carries its building id (:func:`superex_deploy.maps.map_building`); training holds out whole
buildings (:data:`HELDOUT_FRACTION` of them, :func:`heldout_buildings`). Episodes run in ``jobs`` worker
processes; their results are written in a fixed order, so a dataset depends on its configuration only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Optional, Sequence, Union

import numpy as np

from superex_deploy.evaluation.episodes import EpisodeState, run_episode
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.onboard.types import UNKNOWN
from superex_deploy.onboard.prediction.inference import (ModelKind, Pix2PixFilter, crop_window, encode_bp_windows, encode_map,
                                      sha256_file)
from superex_deploy.maps import list_maps, load_map, map_building, random_start
from superex_deploy.onboard.nlos import NlosConfig, back_project, estimate_los
from superex_deploy.sim.spad import nlos_ground_truth
from superex_deploy.parallel import LocalBackend
from superex_deploy.spad_types import SpadConfig
from superex_deploy.sim.spad import simulate_scan
from superex_train.datasets import DatasetInfo, ShardWriter

__all__ = ["GenerationConfig", "HELDOUT_FRACTION", "heldout_buildings", "random_start", "generate_pix2pix",
           "generate_lama"]

PathLike = Union[str, Path]

HELDOUT_FRACTION = 0.2
"""Share of the ``train`` maps' buildings held out of training (validation and reported IoUs)."""


def heldout_buildings(fraction: float = HELDOUT_FRACTION, seed: int = 0) -> tuple[int, ...]:
    """The building ids of the ``train`` maps held out of training: buildings drawn in a ``seed``-ed order until
    they hold at least ``fraction`` of the maps. Fixed for the package, so the Pix2Pix model that feeds the LaMa data
    and the LaMa models are validated on the same buildings."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must lie in (0, 1), got {fraction}")
    maps_per_building: dict[int, int] = {}
    for name in list_maps("train"):
        building = map_building(name)
        maps_per_building[building] = maps_per_building.get(building, 0) + 1
    order = np.random.default_rng(seed).permutation(sorted(maps_per_building))
    chosen, maps = [], 0
    for building in order[:-1]:
        if maps >= fraction * sum(maps_per_building.values()):
            break
        chosen.append(int(building))
        maps += maps_per_building[int(building)]
    return tuple(sorted(chosen))


@dataclass(frozen=True)
class GenerationConfig:
    """How a dataset is generated.

    Attributes:
        maps: bundled map names (default: every ``train`` map; ``eval`` maps are refused).
        episodes_per_map: episodes per map (start cell and planner differ).
        steps: steps per episode (episodes end earlier when no frontier is left).
        planners: planner names cycled over the episodes (``superex_deploy.onboard.planning.planners.PLANNERS``).
        sample_every: steps between samples (the first sample is at a random step below this).
        window_cells: Pix2Pix window side (cells).
        tile_cells: LaMa tile side (cells).
        tiles_per_sample: LaMa tiles cut per sampled step.
        min_clearance_m: start cells are at least this far from any wall.
        jobs: worker processes.
        seed: seeds start cells, planners' generators and tile jitter.
        spad, nlos_cfg, exploration: simulator, processing and episode settings.
    """

    maps: tuple[str, ...] = ()
    episodes_per_map: int = 1
    steps: int = 300
    planners: tuple[str, ...] = ("nearest", "hector", "mapex")
    sample_every: int = 12
    window_cells: int = 160
    tile_cells: int = 128
    tiles_per_sample: int = 2
    min_clearance_m: float = 0.4
    jobs: int = 1
    seed: int = 0
    spad: SpadConfig = field(default_factory=SpadConfig)
    nlos_cfg: NlosConfig = field(default_factory=NlosConfig)
    exploration: ExplorationConfig = field(default_factory=ExplorationConfig)

    def __post_init__(self) -> None:
        maps = tuple(self.maps) or tuple(list_maps("train"))
        eval_maps = set(list_maps("eval"))
        leaked = [m for m in maps if m in eval_maps]
        if leaked:
            raise ValueError(f"training data must not come from the eval maps, got {leaked}")
        object.__setattr__(self, "maps", maps)
        object.__setattr__(self, "planners", tuple(self.planners))
        for name in ("episodes_per_map", "steps", "sample_every", "window_cells", "tile_cells",
                     "tiles_per_sample", "jobs"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"GenerationConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not self.planners:
            raise ValueError("GenerationConfig.planners must name at least one planner")
        for planner in self.planners:
            make_planner(planner)  # raises ValueError for unknown names
        if not self.min_clearance_m >= 0.0:
            raise ValueError(f"GenerationConfig.min_clearance_m must be >= 0, got {self.min_clearance_m}")

    def describe(self) -> dict:
        """JSON-ready settings (stored in the dataset index)."""
        return {"maps": list(self.maps), "episodes_per_map": self.episodes_per_map, "steps": self.steps,
                "planners": list(self.planners), "sample_every": self.sample_every,
                "window_cells": self.window_cells, "tile_cells": self.tile_cells,
                "tiles_per_sample": self.tiles_per_sample, "min_clearance_m": self.min_clearance_m,
                "seed": self.seed, "spad": repr(self.spad), "nlos": repr(self.nlos_cfg),
                "exploration": repr(self.exploration)}


@dataclass(frozen=True)
class _Episode:
    map_name: str
    index: int
    planner: str
    seed: tuple[int, ...]


def _episodes(cfg: GenerationConfig) -> list[_Episode]:
    out = []
    for m, name in enumerate(cfg.maps):
        for e in range(cfg.episodes_per_map):
            planner = cfg.planners[(m * cfg.episodes_per_map + e) % len(cfg.planners)]
            out.append(_Episode(name, e, planner, (cfg.seed, m, e)))
    return out


def _sample_steps(rng: np.random.Generator, cfg: GenerationConfig) -> set[int]:
    return set(range(int(rng.integers(cfg.sample_every)), cfg.steps, cfg.sample_every))


Sample = tuple[np.ndarray, np.ndarray, np.ndarray]


def _pix2pix_episode(episode: _Episode, cfg: GenerationConfig) -> list[Sample]:
    grid = load_map(episode.map_name)
    rng = np.random.default_rng(episode.seed)
    start = random_start(grid, rng, cfg.min_clearance_m)
    take = _sample_steps(rng, cfg)
    size = cfg.window_cells
    samples: list[Sample] = []

    def on_step(state: EpisodeState) -> None:
        if state.step not in take:
            return
        known = state.observed != UNKNOWN
        scan = simulate_scan(grid, state.pose, cfg.spad)
        bp = back_project(scan, estimate_los(scan, cfg.nlos_cfg), cfg.nlos_cfg, known)
        truth = nlos_ground_truth(scan) & ~known
        window = crop_window(bp, state.pose, size, 0.0)
        samples.append((encode_bp_windows(window[None])[0], crop_window(truth, state.pose, size, False),
                        crop_window((grid.valid | grid.occupied) & ~known, state.pose, size, False)))

    run_episode(grid, start, make_planner(episode.planner), ObservedAsPrediction(), cfg.steps,
                seed=int(rng.integers(2 ** 31)), cfg=cfg.exploration, on_step=on_step)
    return samples


_WORKER_FILTER: dict[str, Optional[Pix2PixFilter]] = {}


def _lama_episode(episode: _Episode, cfg: GenerationConfig, pix2pix_path: Optional[str]
                  ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Tiles ``(bp_inputs [3, t, t], los_inputs [2, t, t], walls, mask)``."""
    from superex_deploy.onboard.prediction.inference import SessionConfig

    if pix2pix_path not in _WORKER_FILTER:  # one ONNX Runtime session per worker process
        _WORKER_FILTER[pix2pix_path] = (None if pix2pix_path is None else
                                        Pix2PixFilter(pix2pix_path, session=SessionConfig(intra_op_threads=1)))
    bp_filter = _WORKER_FILTER[pix2pix_path]
    grid = load_map(episode.map_name)
    rng = np.random.default_rng(episode.seed)
    start = random_start(grid, rng, cfg.min_clearance_m)
    take = _sample_steps(rng, cfg)
    sensing = SpadSensing(spad=cfg.spad, nlos_cfg=cfg.nlos_cfg,
                          bp_filter=None if bp_filter is None else bp_filter.filter_map)
    tile = cfg.tile_cells
    samples = []

    def on_step(state: EpisodeState) -> None:
        if state.step not in take:
            return
        evidence = sensing.evidence
        line_of_sight = state.mapper.observed(include_carved=False)
        for _ in range(cfg.tiles_per_sample):
            centre = (np.asarray(state.pose) + rng.integers(-tile // 2, tile // 2 + 1, 2)).clip(
                0, np.asarray(grid.shape) - 1)
            observed = crop_window(state.observed, centre, tile, UNKNOWN)
            samples.append((
                encode_map(observed, crop_window(evidence, centre, tile, 0.0), ModelKind.LAMA_BP)[0],
                encode_map(crop_window(line_of_sight, centre, tile, UNKNOWN), None, ModelKind.LAMA_LOS)[0],
                crop_window(grid.occupied, centre, tile, False),
                crop_window(grid.valid | grid.occupied, centre, tile, False)))

    run_episode(grid, start, make_planner(episode.planner), ObservedAsPrediction(), cfg.steps,
                seed=int(rng.integers(2 ** 31)), cfg=cfg.exploration, sensing=sensing, on_step=on_step)
    return samples


def _indexed(payload):
    worker, index, episode = payload
    return index, worker(episode)


def _run_all(worker: Callable, episodes: Sequence[_Episode], jobs: int, progress: bool, label: str,
             backend=None) -> Iterator:
    """``(episode, worker(episode))`` in episode order, whatever order the backend finishes them in (so the
    dataset is the same on every backend); ``backend`` None: ``jobs`` local processes (in this one if 1)."""
    from tqdm import tqdm

    with tqdm(total=len(episodes), desc=label, unit="episode", disable=not progress) as bar:
        if backend is None and jobs == 1:
            for episode in episodes:
                yield episode, worker(episode)
                bar.update(1)
            return
        backend = backend or LocalBackend(jobs)
        waiting, next_index = {}, 0
        with backend.imap_unordered(_indexed, [(worker, i, e) for i, e in enumerate(episodes)]) as finished:
            for index, result in finished:
                waiting[index] = result
                while next_index in waiting:
                    yield episodes[next_index], waiting.pop(next_index)
                    next_index += 1
                    bar.update(1)


class _Bound:
    """A picklable ``episode -> samples`` closure for the worker pool."""

    def __init__(self, function: Callable, *args):
        self.function, self.args = function, args

    def __call__(self, episode: _Episode):
        return self.function(episode, *self.args)


def generate_pix2pix(out_dir: PathLike, cfg: GenerationConfig = GenerationConfig(), progress: bool = True,
                     backend=None) -> DatasetInfo:
    """Write the Pix2Pix dataset (see the module docstring) to ``out_dir``; returns its :class:`DatasetInfo`.
    ``backend``: a :class:`~superex_deploy.parallel.RayBackend` or :class:`~superex_deploy.parallel.LocalBackend`
    (default: ``cfg.jobs`` local processes); the dataset is the same on every backend."""
    generator = {"source": "superex_train.generate.generate_pix2pix", **cfg.describe()}
    size = cfg.window_cells
    with ShardWriter(out_dir, ModelKind.PIX2PIX, (size, size), generator=generator) as writer:
        for episode, samples in _run_all(_Bound(_pix2pix_episode, cfg), _episodes(cfg), cfg.jobs, progress,
                                         "pix2pix data", backend):
            building = map_building(episode.map_name)
            for inputs, target, mask in samples:
                writer.add(inputs, target, mask, group=building)
    return writer.close()


def generate_lama(bp_dir: PathLike, los_dir: PathLike, pix2pix_model: Optional[PathLike],
                  cfg: GenerationConfig = GenerationConfig(), progress: bool = True, backend=None
                  ) -> tuple[DatasetInfo, DatasetInfo]:
    """Write the LAMA_BP dataset to ``bp_dir`` and the LAMA_LOS dataset of the same tiles to ``los_dir``.

    Args:
        pix2pix_model: the Pix2Pix ``.onnx`` that filters the evidence (None: the Laplacian baseline, for tests
            and ablations only).
    """
    model = None if pix2pix_model is None else str(Path(pix2pix_model).resolve())
    if model is not None:
        Pix2PixFilter(model)  # fail here, with the loader's message, rather than in a worker
    # The file name, not the path: the sha256 identifies the model, and the data's hash must not depend on where
    # the repository was checked out.
    generator = {"source": "superex_train.generate.generate_lama",
                 "pix2pix_model": None if model is None else Path(model).name,
                 "pix2pix_sha256": None if model is None else sha256_file(model), **cfg.describe()}
    tile = (cfg.tile_cells, cfg.tile_cells)
    with ShardWriter(bp_dir, ModelKind.LAMA_BP, tile, generator=generator) as bp_writer, \
            ShardWriter(los_dir, ModelKind.LAMA_LOS, tile, generator=generator) as los_writer:
        for episode, samples in _run_all(_Bound(_lama_episode, cfg, model), _episodes(cfg), cfg.jobs, progress,
                                         "lama data", backend):
            building = map_building(episode.map_name)
            for bp_inputs, los_inputs, walls, mask in samples:
                bp_writer.add(bp_inputs, walls, mask, group=building)
                los_writer.add(los_inputs, walls, mask, group=building)
    return bp_writer.close(), los_writer.close()
