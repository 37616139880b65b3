"""Import paths that moved, kept working for one release.

The onboard modules were grouped by concept (``onboard/mapping``, ``onboard/planning``, ``onboard/prediction``,
``onboard/nlos``) and the simulator's noise models gathered in ``sim/noise``. Code written against the old paths
(``from superex_deploy.onboard.motion import MotionConfig``) still imports: a finder placed first on
:data:`sys.meta_path` answers an old name with the module at its new path (the same module object, so classes and
state are shared) and emits one :class:`DeprecationWarning` naming the new path. The old paths go in the release
after next; :data:`MOVED` is the list.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from typing import Optional

__all__ = ["MOVED", "new_name", "install"]

MOVED: dict[str, str] = {
    "superex_deploy.onboard.mapper": "superex_deploy.onboard.mapping.mapper",
    "superex_deploy.onboard.scan_matching": "superex_deploy.onboard.mapping.scan_matching",
    "superex_deploy.onboard.motion": "superex_deploy.onboard.planning.motion",
    "superex_deploy.onboard.frontiers": "superex_deploy.onboard.planning.frontiers",
    "superex_deploy.onboard.goal_choice": "superex_deploy.onboard.planning.goal_choice",
    "superex_deploy.onboard.visibility": "superex_deploy.onboard.planning.visibility",
    "superex_deploy.onboard.viewpoint_gains": "superex_deploy.onboard.planning.viewpoint_gains",
    "superex_deploy.onboard.expected_visibility": "superex_deploy.onboard.planning.expected_visibility",
    "superex_deploy.onboard.planners.config_checks": "superex_deploy.onboard.checks",
    "superex_deploy.onboard.planners": "superex_deploy.onboard.planning.planners",
    "superex_deploy.onboard.predictors": "superex_deploy.onboard.prediction.registry",
    "superex_deploy.onboard.prediction_schedule": "superex_deploy.onboard.prediction.schedule",
    "superex_deploy.onboard.prediction_reuse": "superex_deploy.onboard.prediction.reuse",
    "superex_deploy.onboard.inference": "superex_deploy.onboard.prediction.inference",
    "superex_deploy.onboard.spad_processing": "superex_deploy.onboard.nlos.processing",
    "superex_deploy.sim.localization": "superex_deploy.sim.noise.pose",
    "superex_deploy.sim.lidar_noise": "superex_deploy.sim.noise.lidar",
    "superex_deploy.commands._options": "superex_deploy.commands.options",
    "superex_deploy.benchmarking": "superex_deploy.evaluation.tasks",
    "superex_deploy.sim.gym_env": "superex_deploy.gym_env",
}
"""Old dotted module path -> new one. A moved package's submodules moved with it
(``superex_deploy.onboard.planners.superex`` -> ``superex_deploy.onboard.planning.planners.superex``).
``superex_deploy.onboard.prediction`` is now the prediction package; it re-exports the two baseline predictors that
module held."""


def new_name(old: str) -> Optional[str]:
    """The new dotted path of the module ``old`` (the longest moved prefix wins), or None if it did not move."""
    parts = old.split(".")
    for k in range(len(parts), 0, -1):
        prefix = ".".join(parts[:k])
        if prefix in MOVED:
            return ".".join([MOVED[prefix]] + parts[k:])
    return None


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers an old module path with the module at its new path (see the module's docstring)."""

    def __init__(self) -> None:
        self._own_specs: dict = {}

    def find_spec(self, fullname, path=None, target=None):
        target_name = new_name(fullname)
        if target_name is None:
            return None
        target_spec = importlib.util.find_spec(target_name)
        if target_spec is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, self,
                                              is_package=target_spec.submodule_search_locations is not None)

    def create_module(self, spec):
        target_name = new_name(spec.name)
        warnings.warn(f"{spec.name} moved to {target_name}; the old path works until the release after next",
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(target_name)
        self._own_specs[spec.name] = module.__spec__
        return module

    def exec_module(self, module) -> None:
        # The import system has just set __spec__ to the old name's spec: give the module back its own.
        module.__spec__ = self._own_specs.pop(module.__spec__.name, module.__spec__)


def install() -> None:
    """Put the finder first on :data:`sys.meta_path` (once): before the path finder, which would otherwise load a
    moved package's submodule a second time under its old name."""
    if not any(isinstance(finder, _MovedFinder) for finder in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())
