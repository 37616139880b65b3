"""Every script in scripts/ still runs: it imports without running (its ``main`` is guarded) and answers ``--help``."""

import ast
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))


def _needs_torch(path: Path) -> bool:
    """Whether the script imports torch or the training package (the ``train`` extra)."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
        if any(name.split(".")[0] in ("torch", "superex_train") for name in names):
            return True
    return False


def _run(args: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)


def test_the_scripts_are_found():
    assert len(SCRIPTS) >= 8 and ROOT / "scripts" / "bench_explore.py" in SCRIPTS


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: path.stem)
def test_a_script_imports_without_running_and_answers_help(script):
    if _needs_torch(script) and importlib.util.find_spec("torch") is None:
        pytest.skip("needs the train extra (torch)")
    # Imported as a module, with arguments its parser would refuse: an unguarded main() would exit with 2.
    code = ("import runpy, sys\n"
            f"sys.argv = [{str(script)!r}, '--not-an-option-of-any-script']\n"
            f"runpy.run_path({str(script)!r}, run_name='imported_by_a_test')\n"
            "print('imported')\n")
    imported = _run(["-c", code])
    assert imported.returncode == 0 and imported.stdout.strip().endswith("imported"), imported.stderr[-2000:]
    helped = _run([str(script), "--help"])
    assert helped.returncode == 0, helped.stderr[-2000:]
    assert helped.stdout.startswith("usage:"), helped.stdout[:500]


def _path_edits_and_script_imports(source: str) -> list[str]:
    """What a script does to reach other code outside the package: ``sys.path`` used anywhere, or an import of a
    sibling script (a module named like a file in scripts/)."""
    siblings = {path.stem for path in SCRIPTS}
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr == "path" and getattr(node.value, "id", None) == "sys":
            found.append(f"sys.path at line {node.lineno}")
        names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
        found += [f"imports the script {name} at line {node.lineno}" for name in names if name in siblings]
    return found


def test_the_check_finds_path_edits_and_script_imports():
    source = "import sys\nsys.path.insert(0, 'x')\nfrom ceiling_study import scenarios\n"
    assert sorted(_path_edits_and_script_imports(source)) == ["imports the script ceiling_study at line 3",
                                                              "sys.path at line 2"]
    assert _path_edits_and_script_imports("import sys\nprint(sys.argv)\nfrom superex_deploy import evaluation\n") == []


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: path.stem)
def test_a_script_neither_edits_sys_path_nor_imports_another_script(script):
    """Shared code lives in the package (superex_deploy.evaluation), not in a script others reach through
    sys.path."""
    assert not _path_edits_and_script_imports(script.read_text(encoding="utf-8"))
