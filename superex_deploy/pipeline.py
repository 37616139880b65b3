"""One place that assembles the pipeline from names: :func:`build_explorer` (the explorer of a planner, a predictor
and a profile, with its predictor and SPAD processing; used by the CLI, the replay, the benchmarks, the Gymnasium
environment and the scripts), and its parts: the map predictor, the simulated SPAD sensing and the onboard SPAD
processing.

The onboard pieces it builds read no ground truth: :func:`make_predictor` for every predictor but ``oracle`` (those
come from :mod:`superex_deploy.onboard.prediction.registry`) and :func:`make_processing`; :func:`make_sensing` and the oracle
belong to simulations.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Optional

from superex_deploy.configs import JsonConfig
from superex_deploy.messages import MapFrame
from superex_deploy.onboard.explorer import Explorer, ExplorerConfig, PredictionSchedule
from superex_deploy.onboard.prediction.inference import SessionConfig, ThreadBudget, check_member_options
from superex_deploy.onboard.prediction.registry import (ENSEMBLE_PREDICTORS, EVIDENCE_MODEL, EVIDENCE_PREDICTORS,
                                                        PREDICTORS, TRUTH_PREDICTORS, exported_model, kind_of,
                                                        make_onboard_predictor, models_dir)
from superex_deploy.onboard.prediction.reuse import PredictionReuse
from superex_deploy.onboard.nlos.processing import NlosSkips

__all__ = ["PREDICTORS", "EVIDENCE_PREDICTORS", "ENSEMBLE_PREDICTORS", "TRUTH_PREDICTORS", "RealtimeProfile",
           "PROFILES", "DEFAULT_PROFILE", "resolve_profile", "check_profile", "Pipeline", "PIPELINES",
           "DEFAULT_PIPELINE", "build_explorer", "make_predictor", "make_sensing", "make_processing"]

@dataclass(frozen=True)
class RealtimeProfile(JsonConfig):
    """How the onboard pipeline trades accuracy for run time (``scripts/bench_realtime.py`` measures each knob:
    docs/benchmarks/realtime.md). The default instance is the unskipped pipeline: the whole ensemble on the whole
    map, inside the step whose planner asks, every SPAD frame processed in full.

    Attributes:
        schedule: when the predictor runs on the robot (:class:`~superex_deploy.onboard.explorer.PredictionSchedule`;
            :meth:`explorer_config`, ``superex explore``).
        simulated_schedule: when it runs in simulated benchmark episodes (:meth:`episode_config`: ``superex
            benchmark``, the scripts), or None: ``schedule``. A never-waiting robot schedule (``free``) depends on
            the machine's speed; benchmarks replace it by the ``simulated`` clock, on which the worker's latency is
            a fixed number of steps, so that their rows are reproducible on any machine.
        reuse: what is kept of the last prediction (:class:`~superex_deploy.onboard.prediction.reuse.PredictionReuse`).
        nlos_skips: SPAD frames and filter runs left out (:class:`~superex_deploy.onboard.nlos.processing.NlosSkips`).
        max_members: LaMa ensemble members run (None: all; see ``LamaEnsemble.with_members``).
        session: ONNX Runtime settings of the LaMa ensemble (an asynchronous predictor is best given one
            intra-op thread and no spinning, so that it leaves a core to the control loop); the Pix2Pix filter runs
            inside the step with the default settings.
    """

    schedule: PredictionSchedule = field(default_factory=PredictionSchedule)
    simulated_schedule: Optional[PredictionSchedule] = None
    reuse: PredictionReuse = field(default_factory=PredictionReuse)
    nlos_skips: NlosSkips = field(default_factory=NlosSkips)
    max_members: Optional[int] = None
    session: SessionConfig = field(default_factory=SessionConfig)

    def __post_init__(self) -> None:
        for name, kind in (("schedule", PredictionSchedule), ("reuse", PredictionReuse), ("nlos_skips", NlosSkips),
                           ("session", SessionConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}")
        if self.simulated_schedule is not None and not isinstance(self.simulated_schedule, PredictionSchedule):
            raise ValueError(f"simulated_schedule must be a PredictionSchedule or None, got "
                             f"{type(self.simulated_schedule).__name__}")
        check_member_options(self.max_members)

    def explorer_config(self, clock: str = "robot") -> ExplorerConfig:
        """The explorer's configuration under this profile: its prediction schedule (``clock="robot"``:
        ``schedule``; ``"simulated"``: ``simulated_schedule``, or ``schedule`` where that is None) and reuse, the
        defaults otherwise (motion, frontier size).

        Raises:
            ValueError: another clock.
        """
        if clock not in ("robot", "simulated"):
            raise ValueError(f"clock must be 'robot' or 'simulated', got {clock!r}")
        schedule = self.schedule
        if clock == "simulated" and self.simulated_schedule is not None:
            schedule = self.simulated_schedule
        return ExplorerConfig(prediction=schedule, reuse=self.reuse)

    def episode_config(self, clock: str = "simulated", **episode):
        """A simulated episode's :class:`~superex_deploy.sim.exploration.ExplorationConfig` under this profile: the
        explorer of :meth:`explorer_config` on the simulated clock (the benchmarks: reproducible on any machine;
        ``clock="robot"``: the robot's schedule, as ``superex explore`` runs it) under the simulated benchmarks'
        finishing rules (:meth:`~superex_deploy.onboard.config.ExplorerConfig.for_simulation`), and ``episode``'s
        fields (``lidar``, ``iou_every``, ``iou_dense_until``) or their defaults."""
        from superex_deploy.sim.exploration import ExplorationConfig

        return ExplorationConfig(explorer=self.explorer_config(clock).for_simulation(), **episode)

    def session_config(self, cores: Optional[int] = None) -> SessionConfig:
        """The ONNX Runtime settings of the predictor's sessions: ``session``, with ``cores`` given and a schedule
        that runs a prediction worker, its intra-op threads set to the worker's share of the
        :class:`~superex_deploy.onboard.prediction.inference.ThreadBudget` (2 cores: 1), so that the worker never takes the
        control loop's core. Without ``cores`` (the benchmarks) the fixed ``session``."""
        if cores is None or not self.schedule.threaded:
            return self.session
        return ThreadBudget.for_cores(cores, worker=True).session(self.session)

    def to_json(self) -> dict:
        """The profile's values as JSON (recorded beside its name in settings and recordings: a later version may
        define the name differently)."""
        return json.loads(json.dumps(asdict(self), default=str))


PROFILES: dict[str, RealtimeProfile] = {
    "full": RealtimeProfile(),
    "realtime": RealtimeProfile(
        schedule=PredictionSchedule("free", wait_first=True),
        simulated_schedule=PredictionSchedule("simulated", every_steps=2, apply_after_steps=2, wait_first=True),
        reuse=PredictionReuse(crop_margin_m=6.4), max_members=1, nlos_skips=NlosSkips(evidence_every=2),
        session=SessionConfig(intra_op_threads=1, allow_spinning=False)),
}
"""Named profiles: ``full`` (the unskipped pipeline, what the paper table measured) and ``realtime`` (chosen on the
held-out train floors with ``scripts/bench_realtime.py``: the lowest p99 step time of the settings measured; the
predictor runs on a crop around what changed with 6.4 m of context, one ensemble member, one ONNX Runtime thread;
the SPAD back-projection and its filter run on every 2nd frame, carving on every frame (decided on train floors;
measured in docs/benchmarks/realtime.md, "SPAD skips").
On the robot it runs in the explorer's worker thread and no step waits for it (``free``: a step takes the newest
finished prediction; only the first step waits for its own, while the robot stands at its start); in simulated
benchmarks on the simulated clock: the map of every 2nd step is predicted and applied 2 steps later (the worker's
latency as 2 steps, as the deterministic thread mode the profile was measured in)."""

DEFAULT_PROFILE = "realtime"
"""The profile every entry point uses unless told otherwise: :func:`build_explorer`, ``superex explore`` and
``superex benchmark``, :class:`~superex_deploy.evaluation.tasks.ScenarioTask`,
:func:`~superex_deploy.evaluation.run_benchmark_episode` and the Gymnasium environment (each through
:func:`resolve_profile`), :func:`make_predictor` and :func:`make_sensing`; the profile of every named pipeline of
:data:`PIPELINES` but those whose planner reads the ensemble's variance. The paper suite names ``full``, the
pipeline its table measured."""


def resolve_profile(profile_name: Optional[str], planner, predictor: str) -> str:
    """The profile a run uses: ``profile_name`` if given, else :data:`DEFAULT_PROFILE` where the planner can use it
    and ``full`` where it cannot (a planner that reads the ensemble's variance with a one-member default): the
    profile :data:`PIPELINES` names for each of its planner and predictor pairs."""
    if profile_name is not None:
        return profile_name
    default = PROFILES[DEFAULT_PROFILE]
    if default.max_members == 1 and kind_of(predictor).ensemble and planner.reads_variance:
        return "full"
    return DEFAULT_PROFILE


def check_profile(profile_name: str, planner, predictor: str) -> RealtimeProfile:
    """The profile called ``profile_name``, checked against the planner (a Planner instance) and predictor name.

    Raises:
        ValueError: an unknown profile; a profile that runs one ensemble member with a learned predictor and a
            planner that reads the ensemble's variance (it would read zeros everywhere).
    """
    if profile_name not in PROFILES:
        raise ValueError(f"unknown profile {profile_name!r}; choose one of {', '.join(PROFILES)}")
    profile = PROFILES[profile_name]
    if profile.max_members == 1 and kind_of(predictor).ensemble and planner.reads_variance:
        raise ValueError(f"the {profile_name} profile runs one LaMa member, so the variance the {planner.name} planner "
                         f"reads would be zero everywhere: use --profile full")
    return profile


@dataclass(frozen=True)
class Pipeline(JsonConfig):
    """A named pipeline: a planner, a map predictor, the SPAD sensing and the profile it runs under, one entry of
    :data:`PIPELINES`.

    Attributes:
        name: its key in :data:`PIPELINES` (``superex explore --pipeline NAME``, a row of the paper's table).
        planner: planner name (``planners.make_planner``).
        predictor: predictor name (:data:`PREDICTORS`).
        spad: a SPAD scan every step (carving, and the Pix2Pix evidence for the predictors of
            :data:`EVIDENCE_PREDICTORS`, which need it).
        profile: the :data:`PROFILES` name it runs under (``superex explore``, ``superex benchmark``, the
            Gymnasium environment): :data:`DEFAULT_PROFILE`, or ``full`` where the planner reads the ensemble's
            variance with a LaMa predictor (:func:`check_profile` refuses one member there). The paper's table
            measures every pipeline under ``full`` (``superex benchmark --suite paper``).
        label: what it is, for tables.
        carving: with ``spad``, the carved cells join the map (False: the ablation without carving; the evidence is
            made as with carving on).

    Raises:
        ValueError: an unknown predictor or profile, an evidence predictor without ``spad``, ``carving`` off without
            ``spad``.
    """

    name: str
    planner: str
    predictor: str
    spad: bool
    profile: str
    label: str
    carving: bool = True

    def __post_init__(self) -> None:
        if self.predictor not in PREDICTORS:
            raise ValueError(f"pipeline {self.name}: unknown predictor {self.predictor!r}")
        if self.profile not in PROFILES:
            raise ValueError(f"pipeline {self.name}: unknown profile {self.profile!r}")
        if kind_of(self.predictor).reads_evidence and not self.spad:
            raise ValueError(f"pipeline {self.name}: the {self.predictor} predictor reads the SPAD evidence: spad=True")
        if not self.carving and not self.spad:
            raise ValueError(f"pipeline {self.name}: carving=False turns off the SPAD's carving: spad=True")


PIPELINES: dict[str, Pipeline] = {p.name: p for p in (
    Pipeline("nearest", "nearest", "observed", False, DEFAULT_PROFILE, "nearest frontier"),
    Pipeline("hector_lama_los", "hector", "lama_los", False, DEFAULT_PROFILE, "IG-Hector on LaMa-LOS"),
    # MapEx and UPEN read the ensemble's variance: every member, so the full profile.
    Pipeline("upen_lama_los", "upen", "lama_los", False, "full", "UPEN on LaMa-LOS"),
    Pipeline("mapex_lama_los", "mapex", "lama_los", False, "full", "MapEx on LaMa-LOS"),
    Pipeline("mapex_observed", "mapex", "observed", False, DEFAULT_PROFILE, "MapEx, observed map"),
    Pipeline("superex_observed", "superex", "observed", False, DEFAULT_PROFILE, "superex planner, observed map"),
    Pipeline("superex_lama_los", "superex", "lama_los", False, DEFAULT_PROFILE, "superex planner on LaMa-LOS"),
    Pipeline("superex", "superex", "lama_bp", True, DEFAULT_PROFILE, "SuperEx: superex planner, LaMa-BP + SPAD"),
    Pipeline("superex_oracle", "superex", "oracle", False, DEFAULT_PROFILE, "superex planner, true map (ceiling)"),
    Pipeline("no_pix2pix", "superex", "lama_los", True, DEFAULT_PROFILE,
             "ablation no Pix2Pix: LaMa-LOS + SPAD carving"),
    Pipeline("no_lama", "superex", "evidence", True, DEFAULT_PROFILE,
             "ablation no LaMa: SPAD carving + Pix2Pix evidence"),
    Pipeline("no_carving", "superex", "lama_bp", True, DEFAULT_PROFILE,
             "ablation no carving: LaMa-BP + Pix2Pix evidence", carving=False),
    Pipeline("carving_only", "superex", "observed", True, DEFAULT_PROFILE,
             "ablation carving only: observed map + SPAD carving"),
)}
"""The named pipelines, the one list of them: ``superex explore --pipeline NAME`` (default
:data:`DEFAULT_PIPELINE`), the rows of the paper's table (``superex benchmark --suite paper``, in this order), the
Gymnasium environment's default profile and the scripts that run a named pipeline read it. ``superex`` is the
project's own (the superex planner on the LaMa-BP ensemble with the SPAD's carving and Pix2Pix evidence);
``mapex_lama_los`` is MapEx as published (the paper table's reference); ``nearest`` the nearest frontier on the
observed map."""

DEFAULT_PIPELINE = "superex"
"""The pipeline ``superex explore`` runs without ``--pipeline``; its profile is :data:`DEFAULT_PROFILE`."""


def _pix2pix_filter(models=None):
    return exported_model(EVIDENCE_MODEL.value, models_dir(models)).filter_map


def make_predictor(name: str, grid=None, models=None, profile: Optional[RealtimeProfile] = None,
                   cores: Optional[int] = None):
    """The map predictor called ``name`` (one of :data:`PREDICTORS`); ``grid`` is read by ``oracle`` only;
    ``profile`` sets the ensemble's members and sessions (:meth:`RealtimeProfile.session_config` of ``cores``: on
    the robot, give the cores the explorer gets; None: the :data:`DEFAULT_PROFILE`'s, one member: give
    ``PROFILES["full"]`` for a planner that reads the ensemble's variance). Every predictor but ``oracle`` is the
    robot's own (:func:`~superex_deploy.onboard.prediction.registry.make_onboard_predictor`).

    Raises:
        ValueError: an unknown name, ``oracle`` without a grid, models that are missing or do not match.
    """
    if kind_of(name).reads_truth and grid is not None:  # the oracle, the one predictor that reads the truth
        from superex_deploy.sim.oracle import OraclePredictor

        return OraclePredictor(grid)
    # The oracle without a grid and unknown names are refused there.
    profile = PROFILES[DEFAULT_PROFILE] if profile is None else profile
    return make_onboard_predictor(name, models, profile.session_config(cores), profile.max_members)


def make_sensing(predictor: str, spad: bool, seed: int, models=None, profile: Optional[RealtimeProfile] = None):
    """The episode's SPAD sensing (``None`` without ``spad``); the :data:`EVIDENCE_PREDICTORS` get the Pix2Pix
    filter's evidence; the processing leaves out what ``profile.nlos_skips`` says (None: the
    :data:`DEFAULT_PROFILE`'s).

    Raises:
        ValueError: a predictor of :data:`EVIDENCE_PREDICTORS` without ``spad`` (it reads the SPAD evidence).
    """
    if kind_of(predictor).reads_evidence and not spad:
        raise ValueError(f"--predictor {predictor} reads the SPAD evidence: add --spad")
    if not spad:
        return None
    from superex_deploy.sim.sensing import SpadSensing

    bp_filter = None
    if kind_of(predictor).reads_evidence:
        bp_filter = _pix2pix_filter(models)
    return SpadSensing(seed=seed, bp_filter=bp_filter,
                       skips=(PROFILES[DEFAULT_PROFILE] if profile is None else profile).nlos_skips)


def make_processing(predictor: str, sensor=None, nlos_cfg=None, models=None, skips: Optional[NlosSkips] = None):
    """The onboard :class:`~superex_deploy.onboard.nlos.processing.SpadProcessing` for ``predictor``: with the
    Pix2Pix filter for the evidence predictors, the Laplacian filter otherwise.

    Args:
        predictor: a name of :data:`PREDICTORS`.
        sensor: the sensor model (:class:`~superex_deploy.spad_types.SpadConfig`; default: the simulator's).
        nlos_cfg: the processing parameters (:class:`~superex_deploy.onboard.nlos.NlosConfig`; default).
        models: folder of exported models (default: the repository's ``exported/``).
        skips: work the processing may leave out (default: none).
    """
    from superex_deploy.onboard.nlos import NlosConfig
    from superex_deploy.onboard.nlos.processing import SpadProcessing
    from superex_deploy.spad_types import SpadConfig

    bp_filter: Optional[object] = _pix2pix_filter(models) if kind_of(predictor).reads_evidence else None
    return SpadProcessing(sensor=sensor or SpadConfig(), nlos_cfg=nlos_cfg or NlosConfig(), bp_filter=bp_filter,
                          skips=skips or NlosSkips())


def build_explorer(frame: MapFrame, planner, predictor, *, profile: Optional[str] = None, cores: Optional[int] = None,
                   spad=False, models=None, seed: int = 0, clock: str = "robot", cfg: Optional[ExplorerConfig] = None,
                   grid=None, sensor=None, nlos_cfg=None) -> Explorer:
    """The :class:`~superex_deploy.onboard.explorer.Explorer` of ``planner`` and ``predictor`` under a profile:
    the one way the CLI, the replay, the benchmarks and the Gymnasium environment build theirs.

    Args:
        frame: the map frame of the observations (:class:`~superex_deploy.messages.MapFrame`).
        planner: a planner name (``planners.make_planner`` with its defaults) or a Planner instance.
        predictor: a name of :data:`PREDICTORS` (built by :func:`make_predictor` under the profile, for ``cores``,
            from ``models``) or a :class:`~superex_deploy.onboard.types.MapPredictor` instance, used as it is.
        profile: a name of :data:`PROFILES`; None: :func:`resolve_profile` (:data:`DEFAULT_PROFILE` where the
            planner can use it).
        cores: the cores the explorer gets (None: the process's CPU affinity for its threads, and the profile's
            fixed ONNX Runtime settings: the benchmarks'); the predictor's sessions get the worker's share.
        spad: False (no SPAD frames), True (the onboard processing of :func:`make_processing` for the predictor,
            with ``sensor``, ``nlos_cfg`` and the profile's skips), or a ready
            :class:`~superex_deploy.onboard.nlos.processing.SpadProcessing` (a simulation's, whose evidence it reads).
        models: folder of exported models (default: the repository's ``exported/``).
        seed: seed of the generator handed to the planner.
        clock: ``"robot"`` (the profile's schedule) or ``"simulated"`` (its benchmark schedule:
            :meth:`RealtimeProfile.explorer_config`).
        cfg: the whole :class:`~superex_deploy.onboard.explorer.ExplorerConfig` instead of the profile's (a
            replay's recorded one, a simulation's with its noise calibration).
        grid: the ground truth, read by the ``oracle`` predictor only (simulations).
        sensor, nlos_cfg: the SPAD sensor model and processing parameters with ``spad=True`` (default: the
            simulator's sensor, the default parameters).

    Raises:
        ValueError: an unknown planner, predictor or profile, a profile the planner cannot use with the predictor
            (:func:`check_profile`), an evidence predictor without SPAD processing, models that are missing.
    """
    from superex_deploy.onboard.nlos.processing import SpadProcessing
    from superex_deploy.onboard.planning.planners import make_planner

    if isinstance(planner, str):
        planner = make_planner(planner)
    if not isinstance(predictor, str) and not callable(getattr(predictor, "predict", None)):
        raise ValueError(f"predictor must be a predictor name or have a predict(observed, extra) method, got "
                         f"{type(predictor).__name__}")
    name = predictor if isinstance(predictor, str) else getattr(predictor, "name", type(predictor).__name__)
    if isinstance(predictor, str) and predictor not in PREDICTORS:
        raise ValueError(f"unknown predictor {predictor!r}; choose one of {', '.join(PREDICTORS)}")
    profile_name = resolve_profile(profile, planner, name)
    chosen = check_profile(profile_name, planner, name)
    if isinstance(spad, bool):
        if kind_of(name).reads_evidence and not spad:
            raise ValueError(f"the {name} predictor reads the SPAD evidence: build it with spad=True")
        spad_processing = make_processing(name, sensor, nlos_cfg, models, chosen.nlos_skips) if spad else None
    elif isinstance(spad, SpadProcessing):
        spad_processing = spad
    else:
        raise ValueError(f"spad must be True, False or a SpadProcessing, got {type(spad).__name__}")
    profile_cfg = chosen.explorer_config(clock)  # also checks the clock
    if isinstance(predictor, str):
        predictor = make_predictor(predictor, grid, models, chosen, cores=cores)
    return Explorer(frame, planner, predictor, spad_processing=spad_processing, cfg=cfg or profile_cfg, seed=seed,
                    cores=cores)
