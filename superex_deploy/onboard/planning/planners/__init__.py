"""Goal selection for exploration: nearest frontier, IG-Hector, UPEN and MapEx, and the registry of all planners
(one module per planner:
:mod:`.nearest`, :mod:`.hector`, :mod:`.upen`, :mod:`.mapex`, :mod:`.superex`).

These reproduce the line-of-sight planners of the MapEx benchmark (castacks/MapEx, ICRA 2025; its
``scripts/explore.py``, ``sim_utils.py``, ``simple_mask_utils.py`` and ``upen_baseline.py``) in our own code,
one class per method where MapEx selects them with mode strings (``nearest``, ``hectoraug``, ``upen``,
``visvarprob``). Each planner reads a :class:`~superex_deploy.onboard.types.PlanningContext` and returns a goal
cell of finite travel cost; the episode loop drives there and keeps the goal until it is reached or blocked.

Differences common to all planners, and why:

* Distances are the engine's cost-to-go (``ctx.travel_cost``: path length weighted by the wall-proximity cost),
  not MapEx's straight-line distance from the robot to the frontier centre: a frontier behind a wall is not
  near, and an unreachable one (``inf``) is never chosen (MapEx picks by straight line, then drops goals that A*
  cannot reach).
* Ties are broken by travel cost, then by cell, so a choice never depends on the order of the frontiers.

The predicted visibility that MapEx and IG-Hector score lives in :mod:`superex_deploy.onboard.planning.visibility`.
"""

from __future__ import annotations

from dataclasses import replace

from superex_deploy.onboard.planning.planners.hector import HectorConfig, HectorPlanner
from superex_deploy.onboard.planning.planners.mapex import MapexConfig, MapexPlanner
from superex_deploy.onboard.planning.planners.nearest import NearestFrontier
from superex_deploy.onboard.planning.planners.superex import SuperexConfig, SuperexPlanner
from superex_deploy.onboard.planning.planners.upen import RandomTree, UpenConfig, UpenPlanner, grow_rrt
from superex_deploy.onboard.types import Planner
from superex_deploy.onboard.planning.viewpoint_gains import visible_gains
from superex_deploy.onboard.planning.visibility import (VisibilityConfig, connected_unknown_gains, predicted_visibility,
                                               reachable_frontiers, visible_ranges)

__all__ = [
    "VisibilityConfig", "visible_ranges", "predicted_visibility", "visible_gains", "connected_unknown_gains",
    "reachable_frontiers",
    "RandomTree", "grow_rrt",
    "NearestFrontier", "HectorConfig", "HectorPlanner", "UpenConfig", "UpenPlanner", "MapexConfig", "MapexPlanner",
    "SuperexConfig", "SuperexPlanner", "PLANNERS", "register_planner", "make_planner", "planner_config",
]

PLANNERS: dict[str, type[Planner]] = {
    NearestFrontier.name: NearestFrontier,
    HectorPlanner.name: HectorPlanner,
    UpenPlanner.name: UpenPlanner,
    MapexPlanner.name: MapexPlanner,
    SuperexPlanner.name: SuperexPlanner,
}

_CONFIGS = {HectorPlanner: HectorConfig, UpenPlanner: UpenConfig, MapexPlanner: MapexConfig,
            SuperexPlanner: SuperexConfig}


def register_planner(planner_class: type, config_class: type = None) -> type:
    """Register ``planner_class`` under its ``name``: from then on :func:`make_planner`, :func:`planner_config` and
    everything that builds planners by name (the CLI's ``--planner``, the pipelines, the benchmarks run in this
    process) build it, with ``config_class`` (a frozen dataclass the class is constructed with, or None for a
    planner without configuration). Returns ``planner_class``, so it serves as a decorator of a class without
    configuration. A worker process of a parallel benchmark sees the registration only if it imports the module
    that makes it.

    Raises:
        ValueError: a class that is not a :class:`~superex_deploy.onboard.types.Planner` or has no ``name`` (a
            non-empty str), a name already registered, a ``config_class`` that is not a dataclass.
    """
    import dataclasses

    if not isinstance(planner_class, type) or not issubclass(planner_class, Planner):
        raise ValueError(f"a planner must be a subclass of superex_deploy.onboard.types.Planner, got {planner_class!r}")
    name = getattr(planner_class, "name", None)
    if not isinstance(name, str) or not name:
        raise ValueError(f"{planner_class.__name__} needs a class attribute name (a non-empty str), got {name!r}")
    if name in PLANNERS:
        raise ValueError(f"a planner named {name!r} is registered already ({PLANNERS[name].__name__})")
    if config_class is not None and not (isinstance(config_class, type) and dataclasses.is_dataclass(config_class)):
        raise ValueError(f"config_class must be a dataclass or None, got {config_class!r}")
    PLANNERS[name] = planner_class
    if config_class is not None:
        _CONFIGS[planner_class] = config_class
    return planner_class


def planner_config(name: str):
    """The config dataclass of the planner called ``name``, or None for a planner that takes no configuration.

    Raises:
        ValueError: an unknown name.
    """
    if not isinstance(name, str) or name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(sorted(PLANNERS))}")
    return _CONFIGS.get(PLANNERS[name])


def make_planner(name: str, **config_overrides) -> Planner:
    """Create a planner by name (``nearest``, ``hector``, ``upen``, ``mapex``, ``superex``), overriding its config
    fields.

    Every override is checked here, by the config's own checks (type, finiteness, range:
    :mod:`~superex_deploy.onboard.checks`), so that a bad option stops a run before its episode
    starts.

    Raises:
        ValueError: an unknown name (the message lists the valid ones), overrides the config does not take, or a
            bad value (the message names the field and what it takes).
    """
    if not isinstance(name, str) or name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(sorted(PLANNERS))}")
    planner_class = PLANNERS[name]
    config_class = _CONFIGS.get(planner_class)
    if config_class is None:
        if config_overrides:
            raise ValueError(f"planner {name!r} takes no configuration, got {sorted(config_overrides)}")
        return planner_class()
    try:
        config = replace(config_class(), **config_overrides)
    except (TypeError, ValueError) as error:
        raise ValueError(f"bad configuration for planner {name!r}: {error}") from None
    return planner_class(config)
