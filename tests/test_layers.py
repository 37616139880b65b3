"""The package layout's promises, read from the source: every import (module level or inside a function, under
``TYPE_CHECKING`` or not) points to the same layer or a lower one, no two modules import each other through any
chain, and ``superex_deploy`` never imports torch, neither in its source nor at run time."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("superex_deploy", "superex_train")

LAYERS = (
    # (name, module prefixes): a module belongs to the layer of its longest matching prefix (``a.b`` matches
    # ``a.b`` and ``a.b.*``), so new modules inside a package (onboard/nlos/, sim/spad/, commands/_options.py) join
    # its layer by themselves. A new top-level module of superex_deploy falls back on the base layer: if it imports
    # anything higher, give it its own place here.
    ("base", ("superex_deploy",)),  # geometry, messages, maps, spad_types, parallel, files, ...
    ("onboard", ("superex_deploy.onboard",)),
    ("recording", ("superex_deploy.recording",)),
    ("sim", ("superex_deploy.sim",)),
    ("pipeline", ("superex_deploy.pipeline", "superex_deploy.render", "superex_deploy.benchmarking")),
    ("commands", ("superex_deploy.commands",)),
    ("cli", ("superex_deploy.cli",)),
    ("train", ("superex_train",)),
    ("train commands", ("superex_train.commands",)),
)

def _modules() -> dict[str, Path]:
    """Dotted name -> source file of every module of the packages (a package is its ``__init__.py``)."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _imported_names(module: str, path: Path) -> set[str]:
    """Every dotted name ``module`` imports anywhere in its source: ``import a.b``, ``from a import b`` (both
    ``a`` and ``a.b``, which may be a submodule), relative imports resolved, ``importlib.import_module("a.b")``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            names.add(target)
            names.update(f"{target}.{alias.name}" for alias in node.names)
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            names.add(node.args[0].value)
    return names


def _graph() -> dict[str, set[str]]:
    """Module -> the modules of the packages it imports (a name resolves to its longest known module prefix:
    ``from a.b import function`` is an import of ``a.b``)."""
    modules = _modules()
    graph = {}
    for module, path in modules.items():
        targets = set()
        for name in _imported_names(module, path):
            parts = name.split(".")
            known = next((".".join(parts[:k]) for k in range(len(parts), 0, -1) if ".".join(parts[:k]) in modules),
                         None)
            if known is not None and known != module:
                targets.add(known)
        graph[module] = targets
    return graph


def _layer(module: str) -> int:
    matches = [(len(prefix), index) for index, (_, prefixes) in enumerate(LAYERS) for prefix in prefixes
               if module == prefix or module.startswith(prefix + ".")]
    assert matches, f"{module} belongs to no layer: add it to LAYERS in {__file__}"
    return max(matches)[1]


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def test_the_import_graph_is_read_from_every_module():
    graph = _graph()
    assert {"superex_deploy.onboard.explorer", "superex_deploy.sim.world", "superex_deploy.cli",
            "superex_train.commands.train"} <= set(graph)
    # Function-level, TYPE_CHECKING and relative imports count too.
    assert "superex_deploy.pipeline" in graph["superex_deploy.commands.benchmark"]
    assert "superex_deploy.sim.episode" in graph["superex_deploy.sim.gym_env"]
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_from_a_higher_layer():
    graph = _graph()
    upward = sorted((module, target, LAYERS[_layer(module)][0], LAYERS[_layer(target)][0])
                    for module, targets in graph.items() for target in targets
                    if _layer(target) > _layer(module))
    assert not upward, "imports from a higher layer (module, imported, layer, its layer):\n" + "\n".join(map(str, upward))


def test_no_import_circles():
    circles = _circles(_graph())
    assert not circles, f"import circles: {circles}"


def test_superex_deploy_never_imports_torch_in_its_source():
    offenders = sorted(module for module, path in _modules().items() if module.startswith("superex_deploy")
                       for name in _imported_names(module, path)
                       if name.split(".")[0] in ("torch", "superex_train"))
    assert not offenders, offenders


@pytest.mark.slow
def test_superex_deploy_never_imports_torch_at_run_time():
    """Import every module of superex_deploy in turn in a fresh interpreter (torch installed and importable):
    none loads torch or superex_train."""
    code = ("import importlib, json, pkgutil, sys, superex_deploy\n"
            "names = sorted(m.name for m in pkgutil.walk_packages(superex_deploy.__path__, 'superex_deploy.'))\n"
            "offenders = {}\n"
            "for name in names:\n"
            "    importlib.import_module(name)\n"
            "    loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'superex_train'))\n"
            "    if loaded:\n"
            "        offenders[name] = loaded[:5]\n"
            "        break\n"
            "print(json.dumps({'names': names, 'offenders': offenders}))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert not report["offenders"], report["offenders"]
    assert set(report["names"]) == {m for m in _modules() if m.startswith("superex_deploy.")}
