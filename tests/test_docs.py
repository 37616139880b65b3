"""The documentation: the site builds without a warning, the API reference covers every public module, the package
code names no tracker issue, and the README stays a short landing page whose two commands are the ones CI runs."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 200


def _bash_blocks(markdown: str) -> list[str]:
    """The contents of the fenced ```bash blocks, in order, stripped."""
    return [block.strip() for block in re.findall(r"^```bash\n(.*?)^```", markdown, flags=re.MULTILINE | re.DOTALL)]


@pytest.mark.slow
def test_site_builds_strictly(tmp_path):
    """`mkdocs build --strict` fails on any warning: broken links or anchors, pages outside the navigation,
    docstrings the API reference cannot render."""
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)]
    quiet = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # mkdocs-material's banner about its successor
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env=quiet)
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout}\n{result.stderr}"
    # Packages that re-export their names (``__all__``) must still show them: one name per page is enough to
    # notice a page left with the package docstring alone.
    for page, name in [("onboard", "superex_deploy.onboard.explorer.Explorer"),
                       ("planning", "superex_deploy.onboard.planning.planners.make_planner"),
                       ("nlos", "superex_deploy.onboard.nlos.process_scan"),
                       ("inference", "superex_deploy.onboard.prediction.inference.LamaEnsemble"),
                       ("spad", "superex_deploy.sim.spad.simulate_scan"),
                       ("sim", "superex_deploy.gym_env.ExplorationEnv")]:
        html = (tmp_path / "api" / page / "index.html").read_text(encoding="utf-8")
        assert f'id="{name}"' in html, f"the API reference page api/{page} does not document {name}"


def test_readme_is_a_landing_page_with_the_two_commands():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= README_MAX_LINES, "README.md is the landing page; move details into docs/"
    blocks = _bash_blocks(readme)
    assert len(blocks) >= 2, "README.md must open with two bash blocks: the main job, then the tests"
    main_job, tests = blocks[0], blocks[1]
    assert "\n" not in main_job and "\n" not in tests, "each of the two commands is one line"
    assert main_job.startswith("python3 -m venv .venv && .venv/bin/pip install") and "superex explore" in main_job
    assert tests.startswith("python3 -m venv .venv && ") and "-m pytest" in tests and ".[train,test,docs]" in tests

    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    commands = [line for line in ci_lines if line and not line.startswith("#")
                and not line.startswith(("set ", "cd "))]
    assert commands == [tests], f".ci/run must run exactly the README's test command, got {commands}"


# A tracker reference: "#" and a number, not inside a word or an HTML entity ("&#39;"), and not a colour ("#1f77b4").
_TRACKER_REFERENCE = re.compile(r"(?<![\w&])#[0-9]+\b")
PACKAGE_CODE = ("superex_deploy", "superex_train")


def test_package_code_names_no_tracker_issue():
    """Docstrings and comments say what, in which units and why; the history of a choice (which issue asked for
    it) belongs to the docs and the benchmark pages, where the reader of the code can follow a link."""
    assert _TRACKER_REFERENCE.search("chosen for issue #16") and not _TRACKER_REFERENCE.search("'#1f77b4', &#39;")
    found = []
    for package in PACKAGE_CODE:
        for path in sorted((ROOT / package).rglob("*.py")):
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
                if _TRACKER_REFERENCE.search(line):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "tracker issue references in package code (move the history to docs/):\n" + "\n".join(found)


def _public_modules(package: str) -> list[str]:
    """Dotted names of the package's modules (a package is its ``__init__.py``) whose every component is public
    (no leading ``_``): read from the files, nothing imported."""
    modules = []
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        if not any(part.startswith("_") for part in parts):
            modules.append(".".join(parts))
    return modules


def _documented_identifiers() -> set[str]:
    """The identifiers of every mkdocstrings block (``::: name``) of the API reference's pages."""
    names = set()
    for page in sorted((ROOT / "docs" / "api").rglob("*.md")):
        names.update(re.findall(r"^:::\s*([\w.]+)\s*$", page.read_text(encoding="utf-8"), flags=re.MULTILINE))
    return names


def test_api_reference_covers_every_public_module():
    """Every public module of ``superex_deploy`` (a new one included: the walk is over the files) has a ``:::``
    block on a page of docs/api/, and every page there is in the site's navigation (``mkdocs build --strict``,
    above, fails on a block that does not resolve)."""
    modules = _public_modules("superex_deploy")
    assert "superex_deploy.onboard.explorer" in modules and "superex_deploy._moved" not in modules
    documented = _documented_identifiers()
    missing = [module for module in modules if module not in documented]
    assert not missing, ("public modules with no `::: module` block in docs/api/ (add one to the page of their "
                         "package):\n" + "\n".join(missing))
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for page in sorted((ROOT / "docs" / "api").rglob("*.md")):
        name = page.relative_to(ROOT / "docs").as_posix()
        assert name in nav, f"docs/{name} is not in mkdocs.yml's nav"
