"""One benchmark episode from names, run in a worker process: what ``superex benchmark`` and its paper suite
(:mod:`superex_deploy.commands.paper_benchmark`) hand to :func:`superex_deploy.parallel.run_tasks`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Optional

__all__ = ["ScenarioTask", "run_scenario", "make_altered_floor", "with_noise", "with_spad_noise",
           "default_sensing_settings"]


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
        seed: the planner's seed and the SPAD noise's.
        planner_options: overrides of the planner's config (``--planner-option``).
        iou_every, iou_dense_until: when the map IoU is evaluated (see
            :class:`~superex_deploy.sim.exploration.ExplorationConfig`); by default every 50 steps.
        profile: the real-time profile's name (:data:`superex_deploy.pipeline.PROFILES`); None (the default):
            :func:`~superex_deploy.pipeline.resolve_profile` (:data:`~superex_deploy.pipeline.DEFAULT_PROFILE` where
            the planner can use it). The paper suite names ``full``.
        pose_noise: ``(sigma_m, sigma_deg)`` of the localisation error, or None (see :func:`with_noise`).
        lidar_noise: ``(sigma_m, dropout, spurious)`` of the LiDAR, or None.
        spad_noise: the SPAD photon budget's preset name (:data:`superex_deploy.spad_types.SPAD_PRESETS`).
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
    pose_noise: Optional[tuple[float, float]] = None
    lidar_noise: Optional[tuple[float, float, float]] = None
    spad_noise: str = "off"
    alteration_seed: Optional[int] = None
    floors_dir: Optional[str] = None

    def __post_init__(self) -> None:
        if self.alteration_seed is not None and not self.floors_dir:
            raise ValueError("ScenarioTask: an alteration_seed needs floors_dir (where the altered floors are cached)")


def with_noise(cfg, pose_noise: Optional[tuple[float, float]], lidar_noise: Optional[tuple[float, float, float]],
               seed: int):
    """The :class:`~superex_deploy.sim.exploration.ExplorationConfig` ``cfg`` with the simulator's noise: the
    localisation error :meth:`PoseNoise.from_sigmas <superex_deploy.sim.noise.pose.PoseNoise.from_sigmas>` of
    ``pose_noise = (sigma_m, sigma_deg)`` and the LiDAR noise ``lidar_noise = (sigma_m, dropout, spurious)``, both
    seeded with ``seed``; None leaves that noise off (``cfg`` unchanged when both are None). With LiDAR noise the
    explorer's map is told the sensor's range sigma (``OccupancyConfig.range_sigma_m``: the robot's calibration is
    the simulated sensor's sigma), as a robot's configuration would be."""
    from superex_deploy.sim.noise.lidar import LidarNoise
    from superex_deploy.sim.noise.pose import PoseNoise

    if pose_noise is None and lidar_noise is None:
        return cfg
    if lidar_noise is not None:
        explorer = cfg.explorer
        cfg = replace(cfg, explorer=replace(explorer, occupancy=replace(explorer.occupancy,
                                                                        range_sigma_m=float(lidar_noise[0]))))
    return replace(cfg, pose_noise=None if pose_noise is None else PoseNoise.from_sigmas(*pose_noise, seed=seed),
                   lidar_noise=None if lidar_noise is None else LidarNoise(
                       sigma_m=lidar_noise[0], dropout_prob=lidar_noise[1], spurious_prob=lidar_noise[2], seed=seed))


def with_spad_noise(sensing, preset: str):
    """The episode's :class:`~superex_deploy.sim.sensing.SpadSensing` (or None) with the sensor model of the
    photon-budget ``preset`` (:func:`superex_deploy.spad_types.spad_preset`), on both the simulator's and the
    onboard processing's side; unchanged for ``off``."""
    from superex_deploy.spad_types import spad_preset

    if sensing is None or preset == "off":
        return sensing
    return replace(sensing, spad=spad_preset(preset, sensing.spad))


def default_sensing_settings(spad_noise: str = "off") -> dict:
    """The SPAD sensing a simulated benchmark episode runs (the default :class:`~superex_deploy.sim.sensing.SpadSensing`
    with the photon budget of ``spad_noise``) as a benchmark's settings record it:
    :func:`~superex_deploy.recording.metadata.sensing_settings`."""
    from superex_deploy.recording.metadata import sensing_settings
    from superex_deploy.sim.sensing import SpadSensing

    sensing = with_spad_noise(SpadSensing(), spad_noise)
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
    cfg = with_noise(profile.episode_config(iou_every=task.iou_every, iou_dense_until=task.iou_dense_until),
                     task.pose_noise, task.lidar_noise, task.seed)
    sensing = with_spad_noise(make_sensing(task.predictor, task.spad, task.seed, profile=profile), task.spad_noise)
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
