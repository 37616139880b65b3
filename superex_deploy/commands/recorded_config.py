"""The configurations a run records in full, and the defaults that changed, for what an earlier version recorded
without them.

A recording of ``superex explore --record`` holds the planner's whole configuration (``planner_config``: every
field of its config dataclass, :func:`planner_settings`), and a ``superex benchmark`` folder's ``settings.json``
those of its planners (``planner_configs``) and of its SPAD sensing (``sensing``, :func:`sensing_settings`), so
that a replay or a resumed run builds what the recorded run ran, whatever the defaults are when it is read.

A recording made before ``planner_config`` holds only the options its user gave (``planner_options``); a benchmark
folder made before ``planner_configs`` and ``sensing`` holds neither. Such a run used the defaults of its version:
this version's, but for the fields of :data:`PREVIOUS_DEFAULTS`, which hold the values they had then (the defaults
of the versions before 0.2); :func:`previous_planner_options` and :func:`previous_sensing` fill them in. A
recording's sensor model and NLOS configuration need no such filling: ``metadata["sensor"]`` and
``metadata["nlos"]`` hold every field since the first recording. The paper suite's rows
(``superex benchmark --suite paper``) record their planner's and sensing's configurations in their settings too.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from typing import Optional

__all__ = ["PREVIOUS_DEFAULTS", "ADDED_EXPLORER_FIELDS", "recorded_explorer_fields", "planner_settings", "previous_planner_options", "default_planner_settings",
           "previous_sensing", "sensing_settings", "default_sensing_settings"]

PREVIOUS_DEFAULTS: dict = {
    "planners": {"superex": {"gain": "path"}},
    "sensor": {"n_secondary": 64},
    "nlos": {"sector_margin_deg": 35.0},
}
"""The defaults before 0.2 of every field whose default changed since: per planner name, its config's
fields (:class:`~superex_deploy.onboard.planning.planners.SuperexConfig`); the sensor's
(:class:`~superex_deploy.spad_types.SpadConfig`) and the NLOS processing's
(:class:`~superex_deploy.onboard.nlos.NlosConfig`). What a run recorded before its full configuration was recorded
used; a later change of a default adds its field here (with the value it had before)."""


ADDED_EXPLORER_FIELDS: dict = {"finish_frontier_m": 0.0, "goal_policy": {"drop_resolved_m": None,
                                                                         "confirm_visit_m": None}}
"""Fields of :class:`~superex_deploy.onboard.config.ExplorerConfig` (and of its ``goal_policy``) added after 0.2.0, at
the values that behave as the explorer did before them: a recording made then holds the whole configuration it ran
but these (its ``finish_after_s`` counted goals of any size, and a goal was kept until reached)."""


def recorded_explorer_fields(fields: dict) -> dict:
    """A recording's ``explorer`` configuration (JSON values) with the fields added since it was made
    (:data:`ADDED_EXPLORER_FIELDS`) filled in: what rebuilds the explorer it ran."""
    fields = dict(fields)
    for name, value in ADDED_EXPLORER_FIELDS.items():
        if isinstance(value, dict):
            if name not in fields:
                fields[name] = dict(value)
            elif isinstance(fields[name], dict):
                fields[name] = {**value, **fields[name]}
        else:
            fields.setdefault(name, value)
    return fields


def planner_settings(planner) -> dict:
    """Every field of ``planner``'s configuration (its ``cfg`` dataclass) as JSON values, nested configurations as
    objects; ``{}`` for a planner that takes no configuration. ``make_planner(name, **settings)`` rebuilds it once
    the nested objects are dataclasses again (:func:`~superex_deploy.onboard.checks.nested_configs`)."""
    cfg = getattr(planner, "cfg", None)
    return {} if cfg is None else asdict(cfg)


def previous_planner_options(name: str, options: dict) -> dict:
    """The options of a planner ``name`` recorded before its whole configuration was recorded (``options``: those
    its user gave), with the fields whose default changed since at their previous default
    (:data:`PREVIOUS_DEFAULTS`): what rebuilds the planner that run used."""
    return {**PREVIOUS_DEFAULTS["planners"].get(name, {}), **options}


def default_planner_settings(name: str, options: Optional[dict] = None, previous: bool = False) -> dict:
    """:func:`planner_settings` of planner ``name`` built with ``options`` (the user's; None: none) and this
    version's defaults otherwise; ``previous``: the defaults of the versions before 0.2
    (:func:`previous_planner_options`), what a run ran before it recorded its planner's configuration."""
    from superex_deploy.onboard.planning.planners import make_planner

    options = dict(options or {})
    return planner_settings(make_planner(name, **(previous_planner_options(name, options) if previous else options)))


def sensing_settings(sensing) -> Optional[dict]:
    """``{"sensor": ..., "nlos": ...}``: every field of a :class:`~superex_deploy.sim.sensing.SpadSensing`'s sensor
    model and NLOS configuration as JSON values (as a recording holds them); None for no sensing."""
    if sensing is None:
        return None
    return {"sensor": asdict(sensing.spad), "nlos": asdict(sensing.nlos_cfg)}


def previous_sensing(sensing):
    """A :class:`~superex_deploy.sim.sensing.SpadSensing` like ``sensing`` whose sensor and NLOS fields that
    changed default hold their previous default (:data:`PREVIOUS_DEFAULTS`): the sensing of the versions before 0.2."""
    return replace(sensing, spad=replace(sensing.spad, **PREVIOUS_DEFAULTS["sensor"]),
                   nlos_cfg=replace(sensing.nlos_cfg, **PREVIOUS_DEFAULTS["nlos"]))


def default_sensing_settings(spad_noise: str = "off", previous: bool = False) -> dict:
    """:func:`sensing_settings` of the default sensing a simulated episode runs
    (:func:`~superex_deploy.pipeline.make_sensing`) with the photon budget of ``spad_noise``; ``previous``: that of
    the versions before 0.2 (:func:`previous_sensing`), what a benchmark ran before its settings recorded it."""
    from superex_deploy.sim.noise.model import SimNoise
    from superex_deploy.sim.sensing import SpadSensing

    sensing = previous_sensing(SpadSensing()) if previous else SpadSensing()
    return sensing_settings(SimNoise(spad=spad_noise).sensing(sensing))
