"""The runnable examples under ``examples/``: each one's ``main()`` runs in this process at a small size and does what
its docstring says (the explorer on messages covers more as it goes, the new planner's goals are frontier regions'
goal cells, the bag's scans are all stepped by ``superex offline``)."""

from __future__ import annotations

import ast
import runpy
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _main(name: str):
    """The example's ``main``, its module run under another name than ``__main__`` (so that it does not run)."""
    return runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name=f"example_{name}")["main"]


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.py")), ids=lambda p: p.name)
def test_every_example_says_what_it_shows_and_how_to_run_it(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstring = ast.get_docstring(tree)
    assert docstring and f"python examples/{path.name}" in docstring, f"{path.name}: a docstring with its command"
    mains = [node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == "main"]
    assert mains and [a.arg for a in mains[0].args.args] == ["argv"], f"{path.name}: main(argv=None)"
    imported = [alias.name if isinstance(node, ast.Import) else node.module
                for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
                for alias in (node.names if isinstance(node, ast.Import) else [None])]
    assert not [m for m in imported if m and (m.startswith("tests") or ("._" in m))], "public API only"


def test_there_are_the_three_examples():
    assert {p.stem for p in EXAMPLES.glob("*.py")} == {"explore_on_messages", "new_planner", "explore_a_bag"}


def test_the_explorer_on_messages_covers_more_as_it_goes(capsys):
    result = _main("explore_on_messages")(["--steps", "40", "--every", "20"])
    coverage = np.asarray(result["coverage"])
    assert len(coverage) == 40 and not result["finished"] and result["status"] == "exploring"
    assert 0 < coverage[0] < coverage[-1] and np.all(np.diff(coverage) >= 0)
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[1] for line in lines[:-1]] == ["20", "40"] and lines[-1].startswith("final: ")


@pytest.fixture
def planners_restored():
    """The planners' registry as it was: the example registers its planner in it, for the whole process."""
    from superex_deploy.onboard.planning.planners import PLANNERS

    saved = dict(PLANNERS)
    yield PLANNERS
    PLANNERS.clear()
    PLANNERS.update(saved)


def test_the_new_planner_is_built_by_name_and_drives_to_frontiers(planners_restored, capsys):
    from superex_deploy.onboard.planning.planners import make_planner

    result = _main("new_planner")(["--steps", "60"])
    assert make_planner("largest").name == "largest"  # registered: built by name like the shipped ones
    goals = result["largest"]["goals"]
    assert len(goals) >= 2 and all(on_frontier for _, on_frontier in goals)
    for run in result.values():
        coverage = np.asarray(run["coverage"])
        assert len(coverage) == 60 and 0 < coverage[0] < coverage[-1]
    out = capsys.readouterr().out
    assert "largest" in out and "nearest" in out and f"{len(goals)} of them a frontier" in out


def test_superex_offline_steps_every_scan_of_the_examples_bag(tmp_path, capsys):
    pytest.importorskip("rosbags")
    summary = _main("explore_a_bag")(["--scans", "12", "--out", str(tmp_path)])
    assert summary["steps"] == summary["expected_scans"] == 12 and summary["complete"]
    assert sum(summary["scans_skipped"].values()) == 0 and summary["pose_source"] == "tf"
    observed = np.load(tmp_path / "offline" / "map.npz")["observed"]
    assert np.count_nonzero(observed == 1) > 100 and np.count_nonzero(observed == 0) > 1000  # walls and floor seen
    assert "exit 0: 12 of 12 scans stepped" in capsys.readouterr().out
