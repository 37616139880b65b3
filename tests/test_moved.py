"""The import paths that moved when onboard/ was grouped by concept keep working for one release
(:mod:`superex_deploy._moved`): each old path is the new module itself, with one DeprecationWarning naming the new
path, and nothing in the project still imports an old path."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from superex_deploy._moved import MOVED, new_name

ROOT = Path(__file__).resolve().parents[1]


def test_new_name_maps_modules_and_their_submodules():
    assert new_name("superex_deploy.onboard.motion") == "superex_deploy.onboard.planning.motion"
    assert new_name("superex_deploy.onboard.planners.superex") == "superex_deploy.onboard.planning.planners.superex"
    # the longest moved prefix wins: config_checks left the planners package
    assert new_name("superex_deploy.onboard.planners.config_checks") == "superex_deploy.onboard.checks"
    assert new_name("superex_deploy.onboard.inference.lama") == "superex_deploy.onboard.prediction.inference.lama"
    assert new_name("superex_deploy.onboard.explorer") is None
    assert new_name("superex_deploy.onboard.motionless") is None


@pytest.mark.parametrize("old", sorted(MOVED))
def test_every_old_path_is_the_new_module_and_warns(old):
    # A fresh interpreter: in this one the old names may already be in sys.modules.
    code = (
        "import importlib, warnings\n"
        f"new = importlib.import_module({MOVED[old]!r})\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        "messages = [str(w.message) for w in caught if w.category is DeprecationWarning]\n"
        f"assert any(m.startswith({old!r} + ' moved to ' + {MOVED[old]!r}) for m in messages), messages\n"
        "assert old is new, (old, new)\n"
        f"assert new.__spec__.name == {MOVED[old]!r}, new.__spec__.name\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr


def test_a_moved_packages_submodule_is_not_loaded_twice():
    import warnings

    new = importlib.import_module("superex_deploy.onboard.planning.planners.nearest")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from superex_deploy.onboard.planners.nearest import NearestFrontier
    assert NearestFrontier is new.NearestFrontier


def test_the_old_prediction_module_names_still_import():
    from superex_deploy.onboard.prediction import EvidenceAsPrediction, ObservedAsPrediction
    from superex_deploy.onboard.prediction.baselines import EvidenceAsPrediction as E, ObservedAsPrediction as O

    assert (EvidenceAsPrediction, ObservedAsPrediction) == (E, O)


def test_nothing_in_the_project_imports_an_old_path():
    offenders = []
    for folder in ("superex_deploy", "superex_train", "scripts", "tests"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.name in ("_moved.py", "test_moved.py"):
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = []
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
                offenders += [f"{path.relative_to(ROOT)}:{node.lineno} {name}" for name in names
                              if new_name(name) is not None]
    assert not offenders, offenders
