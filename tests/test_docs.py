"""The documentation: the site builds without a warning, and the README stays a short landing page whose two
commands are the ones CI runs."""

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
                       ("onboard", "superex_deploy.onboard.planning.planners.make_planner"),
                       ("nlos", "superex_deploy.onboard.nlos.process_scan"),
                       ("inference", "superex_deploy.onboard.prediction.inference.LamaEnsemble"),
                       ("spad", "superex_deploy.sim.spad.simulate_scan"),
                       ("sim", "superex_deploy.sim.gym_env.ExplorationEnv")]:
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
