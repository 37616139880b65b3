"""``superex warmup``: compile every numba kernel once (numba caches them on disk) and check the models load.

The first episode in a fresh install otherwise spends ~30 s on its first step compiling; ``superex explore`` says
so when it finds the cache cold.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--models", type=Path, default=None, help="folder of exported models (default: installed)")


def numba_cache_is_warm() -> bool:
    """Whether numba's on-disk cache holds the SPAD simulator's and the NLOS processing's kernels (the slowest to
    compile) for this Python."""
    from superex_deploy.onboard.nlos import back_projection, carving, filters, los, normals
    from superex_deploy.sim.spad import fans, histograms, scene, tracer

    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    return all(any((Path(module.__file__).parent / "__pycache__").glob(f"{Path(module.__file__).stem}.*{tag}.nbi"))
               for module in (scene, tracer, fans, histograms, los, normals, carving, back_projection, filters))


def warm_up(models=None) -> float:
    """Run a few steps of every planner with SPAD sensing on a small synthetic floor (compiling every kernel on the
    way) and load the learned models (every predictor's of :data:`~superex_deploy.pipeline.PREDICTORS`); returns the
    seconds it took."""
    from superex_deploy.maps import OccupancyGrid
    from superex_deploy.onboard.planning.planners import PLANNERS, make_planner
    from superex_deploy.pipeline import PREDICTORS, PROFILES, make_predictor, make_sensing
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.sim.exploration import ExplorationConfig

    started = time.perf_counter()
    walls = np.zeros((40, 60), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:, 30] = True
    walls[15:22, 30] = False
    grid = OccupancyGrid(walls, ~walls, 0.1, "warm-up")
    full = PROFILES["full"]  # every frame's evidence, every LaMa member: every kernel and every model
    for planner in PLANNERS:
        run_episode(grid, (10, 10), make_planner(planner), make_predictor("evidence"), steps=4,
                    cfg=ExplorationConfig(iou_every=2), sensing=make_sensing("evidence", True, 0, models, full))
    for name, kind in PREDICTORS.items():
        if kind.models:
            make_predictor(name, models=models, profile=full)
    return time.perf_counter() - started


def run(args: argparse.Namespace) -> int:
    cold = not numba_cache_is_warm()
    print(f"superex warmup: {'compiling the numba kernels (once; numba caches them)' if cold else 'cache warm'}, "
          f"loading the models...", flush=True)
    seconds = warm_up(args.models)
    print(f"superex warmup: done in {seconds:.1f} s")
    return 0
