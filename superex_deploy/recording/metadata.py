"""What a recording says about its run, written and read back: :func:`recording_metadata` writes every configuration
the explorer ran by its own ``to_json`` (the planner's, the explorer's, the SPAD sensor's and NLOS processing's, the
profile's), and :func:`explorer_arguments` rebuilds the explorer from them by the strict ``from_json``
(:mod:`superex_deploy.configs`): a field this version does not have, or one of the wrong type, is refused by name,
never dropped or guessed.

The metadata of recording format :data:`~superex_deploy.recording.schemas.FORMAT_VERSION` (JSON values, one key each
in the ``superex.episode`` record; :data:`~superex_deploy.recording.schemas.METADATA_TYPES` gives their types):

===================  ===============================================================================================
key                  value
===================  ===============================================================================================
``frame``            the explorer's first map frame (written by the recorder)
``map``              the floor's or the bag's name (for the reader; a replay does not read it)
``planner``          the planner's name (:data:`~superex_deploy.onboard.planning.planners.PLANNERS`)
``planner_options``  the options its user gave (for the reader; ``planner_config`` holds what ran)
``planner_config``   its whole configuration (``cfg.to_json()``; ``{}`` for a planner without one)
``predictor``        the predictor's name (:data:`~superex_deploy.pipeline.PREDICTORS`)
``seed``             the seed handed to the planner
``spad``             whether the explorer processed SPAD frames
``sensor``, ``nlos``  the SPAD sensor model and NLOS processing (``to_json``), None without SPAD
``explorer``         the explorer's whole configuration (``ExplorerConfig.to_json()``)
``profile``          the profile's name (:data:`~superex_deploy.pipeline.PROFILES`)
``profile_settings`` its values (``RealtimeProfile.to_json()``): a replay refuses a profile defined otherwise now
``models``           the folder of exported models, or None (the repository's)
===================  ===============================================================================================

A recording of an earlier format is refused when read (:func:`~superex_deploy.recording.read_recording`);
``superex convert-recording`` (:mod:`superex_deploy.recording.convert`) rewrites it into this one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

__all__ = ["REPLAYED_KEYS", "planner_settings", "sensing_settings", "recording_metadata", "explorer_arguments"]

REPLAYED_KEYS = ("planner", "planner_config", "predictor", "seed", "spad", "sensor", "nlos", "explorer", "profile",
                 "profile_settings")
"""The metadata keys :func:`explorer_arguments` reads; a recording that lacks one is refused, naming it."""


def planner_settings(planner) -> dict:
    """Every field of ``planner``'s configuration (its ``cfg``) as JSON values (``cfg.to_json()``); ``{}`` for a
    planner that takes no configuration."""
    cfg = getattr(planner, "cfg", None)
    return {} if cfg is None else cfg.to_json()


def sensing_settings(sensor, nlos_cfg) -> dict:
    """``{"sensor": ..., "nlos": ...}``: the SPAD sensor model (:class:`~superex_deploy.spad_types.SpadConfig`) and
    the NLOS processing (:class:`~superex_deploy.onboard.nlos.NlosConfig`) as JSON values, None each for a run
    without SPAD (``sensor`` None)."""
    if sensor is None:
        return {"sensor": None, "nlos": None}
    return {"sensor": sensor.to_json(), "nlos": nlos_cfg.to_json()}


def recording_metadata(*, map_name: str, planner_name: str, planner, planner_options: Optional[dict],
                       predictor: str, seed: int, sensor, nlos_cfg, explorer_cfg, profile: str,
                       models=None) -> dict:
    """The metadata of a recording of this format (see the module docstring; the recorder adds ``frame`` and
    ``format_version``): ``planner`` is the Planner instance that runs (``planner_name`` its name,
    ``planner_options`` the options given), ``sensor`` and ``nlos_cfg`` the SPAD processing's (None: no SPAD),
    ``explorer_cfg`` the explorer's :class:`~superex_deploy.onboard.config.ExplorerConfig`, ``profile`` a name of
    :data:`~superex_deploy.pipeline.PROFILES`, ``models`` the models' folder or None."""
    from superex_deploy.pipeline import PROFILES

    return {"map": map_name, "planner": planner_name, "planner_options": dict(planner_options or {}),
            "planner_config": planner_settings(planner), "predictor": predictor, "seed": int(seed),
            "spad": sensor is not None, "models": None if models is None else str(Path(models).resolve()),
            **sensing_settings(sensor, nlos_cfg), "explorer": explorer_cfg.to_json(), "profile": profile,
            "profile_settings": PROFILES[profile].to_json()}


def explorer_arguments(metadata: dict, frame, models=None) -> dict:
    """The keyword arguments of :func:`superex_deploy.pipeline.build_explorer` that rebuild the explorer a
    recording's metadata (this format's, see the module docstring) describes on ``frame`` (the recording's first
    map frame, included as ``frame``): its planner (a Planner instance), predictor name, profile, SPAD sensor model
    and processing, ``models`` (default: the recording's), seed and explorer configuration.
    ``build_explorer(**explorer_arguments(metadata, frame))``.

    Raises:
        ValueError: metadata that lacks a key of :data:`REPLAYED_KEYS` (named), the oracle predictor (it reads the
            truth), a profile this version defines otherwise, a bad seed, or a configuration its class refuses
            (a field it does not have or a bad value, named).
    """
    from superex_deploy import pipeline
    from superex_deploy.onboard import ExplorerConfig
    from superex_deploy.onboard.nlos import NlosConfig
    from superex_deploy.onboard.planning.planners import PLANNERS, make_planner, planner_config
    from superex_deploy.onboard.prediction.registry import kind_of
    from superex_deploy.spad_types import SpadConfig

    missing = [key for key in REPLAYED_KEYS if key not in metadata]
    if missing:
        raise ValueError(f"the recording's metadata lacks {', '.join(repr(key) for key in missing)}")
    predictor_name, profile_name, seed = metadata["predictor"], metadata["profile"], metadata["seed"]
    if kind_of(predictor_name).reads_truth:
        raise ValueError(f"the recording used the {predictor_name} predictor, which reads the ground truth: it cannot "
                         f"be replayed")
    if profile_name not in pipeline.PROFILES:
        raise ValueError(f"the recording used the profile {profile_name!r}, which this version does not have "
                         f"({', '.join(pipeline.PROFILES)})")
    profile = pipeline.PROFILES[profile_name]
    if metadata["profile_settings"] != profile.to_json():
        raise ValueError(f"the recording's profile {profile_name!r} was defined differently when it was recorded "
                         f"({metadata['profile_settings']}) than in this version ({profile.to_json()}): "
                         "a replay would not rebuild its explorer")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"the recording's seed must be an integer >= 0, got {seed!r}")
    try:
        config_class = planner_config(metadata["planner"])
        if config_class is None:
            planner = make_planner(metadata["planner"], **metadata["planner_config"])
        else:
            planner = PLANNERS[metadata["planner"]](config_class.from_json(metadata["planner_config"]))
    except (TypeError, ValueError) as error:
        raise ValueError(f"the recording's planner cannot be rebuilt: {error}") from None
    try:
        cfg = ExplorerConfig.from_json(metadata["explorer"])
        spad = metadata["spad"] is True
        sensor = SpadConfig.from_json(metadata["sensor"]) if spad else None
        nlos_cfg = NlosConfig.from_json(metadata["nlos"]) if spad else None
    except (TypeError, ValueError) as error:
        raise ValueError(f"the recording's configuration cannot be rebuilt: {error}") from None
    return dict(frame=frame, planner=planner, predictor=predictor_name, profile=profile_name, spad=spad,
                models=models or metadata.get("models"), seed=seed, cfg=cfg, sensor=sensor, nlos_cfg=nlos_cfg)
