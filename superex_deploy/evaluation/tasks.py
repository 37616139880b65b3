"""One benchmark episode from names, run in a worker process: what ``superex benchmark`` and its paper suite
(:mod:`superex_deploy.commands.paper_benchmark`) hand to :func:`superex_deploy.parallel.run_tasks`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

from superex_deploy.sim.noise.model import SimNoise

__all__ = ["ScenarioTask", "run_scenario", "make_altered_floor", "default_sensing_settings"]


@dataclass(frozen=True, kw_only=True)
class ScenarioTask:
    """One benchmark episode, by names (picklable: it travels to worker processes and Ray tasks).

    Attributes:
        map_name: bundled map name.
        start_index: index of the start pose among the map's start poses (recorded in the summary).
        start_rc: the start cell (row, col).
        planner: planner name (``planners.make_planner``).
        predictor: predictor name (:data:`superex_deploy.pipeline.PREDICTORS`).
        spad: simulate the SPAD LiDAR every step.
        carving: with ``spad``, write the carved cells into the map (False: the ablation "without carving"; the
            evidence is made as with it, :attr:`NlosSkips.carving <superex_deploy.onboard.nlos.processing.NlosSkips>`).
        steps: step budget.
        seed: the planner's seed and the noise's (:meth:`SimNoise.seeded
            <superex_deploy.sim.noise.model.SimNoise.seeded>`).
        planner_options: overrides of the planner's config (``--planner-option``).
        iou_every, iou_dense_until: when the map IoU is evaluated (see
            :class:`~superex_deploy.sim.exploration.ExplorationConfig`); by default every 50 steps.
        profile: the real-time profile's name (:data:`superex_deploy.pipeline.PROFILES`); None (the default):
            :func:`~superex_deploy.pipeline.resolve_profile` (:data:`~superex_deploy.pipeline.DEFAULT_PROFILE` where
            the planner can use it). The paper suite names ``full``.
        noise: the simulator's noise (:class:`~superex_deploy.sim.noise.model.SimNoise`: localisation error, LiDAR
            noise, SPAD photon budget), seeded with ``seed`` for the episode.
        alteration_seed: None (the default): the bundled floor as it is. Else the episode runs on the floor altered
            with this seed (:func:`superex_deploy.sim.alterations.alter_floor`; ``superex benchmark --suite
            altered`` passes :func:`~superex_deploy.sim.altered_floors.alteration_seed`), cached under
            ``floors_dir``, and its summary gains ``dead_ends`` (:func:`superex_deploy.sim.dead_ends.dead_end_entries`)
            and ``alteration`` (the seed, the dead ends made, the reachable share kept).
        floors_dir: where the altered floors are cached (:func:`superex_deploy.sim.altered_floors.make_floor`); needed
            with ``alteration_seed``.
    """

    map_name: str
    start_index: int
    start_rc: tuple[int, int]
    planner: str
    predictor: str
    spad: bool
    steps: int
    seed: int
    carving: bool = True
    planner_options: dict = field(default_factory=dict)
    iou_every: int = 50
    iou_dense_until: float = 1.0
    profile: Optional[str] = None
    noise: SimNoise = SimNoise()
    alteration_seed: Optional[int] = None
    floors_dir: Optional[str] = None

    def __post_init__(self) -> None:
        if not isinstance(self.noise, SimNoise):
            raise ValueError(f"ScenarioTask: noise must be a SimNoise, got {type(self.noise).__name__}")
        if self.alteration_seed is not None and not self.floors_dir:
            raise ValueError("ScenarioTask: an alteration_seed needs floors_dir (where the altered floors are cached)")


def default_sensing_settings(spad_noise: str = "off") -> dict:
    """The SPAD sensing a simulated benchmark episode runs (the default :class:`~superex_deploy.sim.sensing.SpadSensing`
    with the photon budget of ``spad_noise``) as a benchmark's settings record it:
    :func:`~superex_deploy.recording.metadata.sensing_settings`."""
    from superex_deploy.recording.metadata import sensing_settings
    from superex_deploy.sim.sensing import SpadSensing

    sensing = SimNoise(spad=spad_noise).sensing(SpadSensing())
    return sensing_settings(sensing.spad, sensing.nlos_cfg)


def run_scenario(task: ScenarioTask) -> dict:
    """One benchmark episode in a worker process; returns its JSON summary (no poses, no per-step timings), with
    the task's ``start_index`` and ``profile`` (and, on an altered floor, ``alteration`` and ``dead_ends``)."""
    from superex_deploy.messages import MapFrame
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import build_explorer, check_profile, make_sensing, resolve_profile
    from superex_deploy.evaluation.episodes import run_episode
    from superex_deploy.maps import load_map

    planner = make_planner(task.planner, **task.planner_options)
    profile_name = resolve_profile(task.profile, planner, task.predictor)
    profile = check_profile(profile_name, planner, task.predictor)
    dead_ends = alteration = None
    if task.alteration_seed is None:
        grid = load_map(task.map_name)
    else:
        from superex_deploy.sim.altered_floors import load_floor

        grid, dead_ends, meta = load_floor(task.map_name, task.start_rc, task.floors_dir, seed=task.alteration_seed)
        alteration = {"seed": meta["seed"], "dead_ends": len(dead_ends), "kept_fraction": meta["kept_fraction"]}
    noise = task.noise.seeded(task.seed)
    cfg = noise.episode_config(profile.episode_config(iou_every=task.iou_every, iou_dense_until=task.iou_dense_until))
    sensing = noise.sensing(make_sensing(task.predictor, task.spad, task.seed, profile=profile))
    if sensing is not None and not task.carving:
        sensing = replace(sensing, skips=replace(sensing.skips, carving=True))
    explorer = build_explorer(MapFrame(grid.shape, grid.resolution_m), planner, task.predictor, profile=profile_name,
                              spad=False if sensing is None else sensing.processing(), seed=task.seed,
                              cfg=cfg.explorer, grid=grid)
    result = run_episode(grid, task.start_rc, explorer=explorer, steps=task.steps, seed=task.seed, cfg=cfg,
                         sensing=sensing)
    summary = result.to_json()
    summary["start_index"] = task.start_index
    summary["profile"] = profile_name
    if alteration is not None:
        from superex_deploy.sim.dead_ends import dead_end_entries

        summary["alteration"] = alteration
        summary["dead_ends"] = dead_end_entries(dead_ends, result.poses, result.path_length_m).to_json()
    summary.pop("poses")
    summary.pop("timings_s")
    return summary


def make_altered_floor(task: tuple) -> dict:
    """``superex benchmark --suite altered``'s first pass, in a worker process: the altered floor of one scenario,
    ``task = (map_name, start_rc, folder)``, made once into ``folder``
    (:func:`superex_deploy.sim.altered_floors.make_floor`); returns its summary."""
    from superex_deploy.sim.altered_floors import make_floor

    map_name, start_rc, folder = task
    return make_floor(map_name, tuple(start_rc), folder)
