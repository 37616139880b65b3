"""One benchmark episode from names or objects: what every script's worker calls, so a planner, predictor and
sensing are built the same way everywhere (:func:`superex_deploy.pipeline.make_predictor` /
:func:`~superex_deploy.pipeline.make_sensing` under one real-time profile) and each script keeps only its own
question (what it measures from the result)."""

from __future__ import annotations

import time
from typing import Callable, NamedTuple, Optional, Union

from superex_deploy.maps import OccupancyGrid, load_map
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.pipeline import PROFILES, RealtimeProfile, make_predictor, make_sensing, resolve_profile
from superex_deploy.sim.episode import EpisodeResult, ExplorationConfig, run_episode

__all__ = ["EpisodeRun", "run_benchmark_episode"]


class EpisodeRun(NamedTuple):
    """An episode's result, the floor it ran on, and its wall-clock seconds (the episode alone: building the
    planner, predictor and sensing excluded)."""

    result: EpisodeResult
    grid: OccupancyGrid
    seconds: float


def run_benchmark_episode(floor: Union[str, OccupancyGrid], start_rc, planner, predictor="observed", *,
                          steps: int, planner_options: Optional[dict] = None, seed: int = 0,
                          cfg: Optional[ExplorationConfig] = None, profile: Optional[RealtimeProfile] = None,
                          spad: bool = False, sensing=None, cores: Optional[int] = None,
                          on_step: Optional[Callable] = None,
                          on_observation: Optional[Callable] = None) -> EpisodeRun:
    """Explore ``floor`` from ``start_rc`` for ``steps`` steps (:func:`superex_deploy.sim.episode.run_episode`).

    Args:
        floor: a bundled map's name (loaded with :func:`~superex_deploy.maps.load_map`) or a grid (an altered
            floor).
        start_rc: the start cell ``(row, col)``.
        planner: a planner name (:func:`~superex_deploy.onboard.planning.planners.make_planner`, with
            ``planner_options``) or a planner object.
        predictor: a predictor name (:func:`~superex_deploy.pipeline.make_predictor` on the floor under
            ``profile``) or a predictor object.
        steps: step budget.
        seed: the episode's seed (and the SPAD noise's when the sensing is made here).
        cfg: the episode's config; by default the profile's (:meth:`RealtimeProfile.episode_config
            <superex_deploy.pipeline.RealtimeProfile.episode_config>`, on the simulated clock).
        profile: the real-time profile the predictor, the sensing and the default ``cfg`` are made under; None: the
            default profile where the planner can use it, else ``full``
            (:func:`~superex_deploy.pipeline.resolve_profile`). ``PROFILES["full"]`` with ``cfg`` left out is the
            unskipped pipeline (``ExplorationConfig()``).
        spad: the SPAD sensing of a named ``predictor`` (:func:`~superex_deploy.pipeline.make_sensing`, None
            without ``spad``); ignored when ``sensing`` is given.
        sensing: the episode's SPAD sensing object, instead of making one.
        cores: the cores a named predictor's sessions get (:func:`~superex_deploy.pipeline.make_predictor`).
        on_step, on_observation: passed to ``run_episode``.

    Raises:
        ValueError: ``spad`` with a predictor object and no ``sensing`` (the sensing is made for a predictor name).
    """
    grid = load_map(floor) if isinstance(floor, str) else floor
    if isinstance(planner, str):
        planner = make_planner(planner, **(planner_options or {}))
    if profile is None:
        name = predictor if isinstance(predictor, str) else getattr(predictor, "name", type(predictor).__name__)
        profile = PROFILES[resolve_profile(None, planner, name)]
    if isinstance(predictor, str):
        name, predictor = predictor, make_predictor(predictor, grid, profile=profile, cores=cores)
        if sensing is None:
            sensing = make_sensing(name, spad, seed, profile=profile)
    elif spad and sensing is None:
        raise ValueError("spad=True makes the sensing for a named predictor: pass sensing= with a predictor object")
    clock = time.perf_counter()
    result = run_episode(grid, tuple(start_rc), planner, predictor, steps=steps, seed=seed,
                         cfg=profile.episode_config() if cfg is None else cfg, sensing=sensing, on_step=on_step,
                         on_observation=on_observation)
    return EpisodeRun(result, grid, time.perf_counter() - clock)
