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
    # ``a.b`` and ``a.b.*``), so new modules inside a package (onboard/nlos/, sim/spad/, commands/options.py) join
    # its layer by themselves. A new top-level module of superex_deploy falls back on the base layer: if it imports
    # anything higher, give it its own place here.
    ("base", ("superex_deploy",)),  # geometry, messages, maps, spad_types, parallel, files, ...
    ("onboard", ("superex_deploy.onboard",)),
    # tf2's rules and the rigid transforms they hold, in numpy: the bag reader's and the node's
    ("ros 2 transforms", ("superex_deploy.ros.tf", "superex_deploy.ros.rigid")),
    ("recording", ("superex_deploy.recording",)),
    ("ros 2 wire", ("superex_deploy.ros",)),  # messages over DDS, QoS, transforms, the node's parameters
    ("sim", ("superex_deploy.sim",)),
    ("pipeline", ("superex_deploy.pipeline",)),
    # A recording's configurations, written and rebuilt into the pipeline's explorer, and the converter of old ones.
    ("recording format", ("superex_deploy.recording.metadata", "superex_deploy.recording.convert")),
    ("ros 2 node", ("superex_deploy.ros.core", "superex_deploy.ros.node")),  # builds its explorer by the pipeline
    # The benchmarks' library: scenarios, the episode runner (its explorers by pipeline.build_explorer), metrics,
    # summaries, reports.
    ("evaluation", ("superex_deploy.evaluation",)),
    ("figures", ("superex_deploy.render",)),  # draws the evaluation's curves and intervals
    ("gym env", ("superex_deploy.gym_env",)),  # the world and explorer of an episode (evaluation.episodes)
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
    assert "superex_deploy.evaluation.episodes" in graph["superex_deploy.gym_env"]
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


SOURCES = PACKAGES + ("scripts",)


def _sources() -> dict[str, str]:
    """Dotted name -> source text of every module of the packages and of ``scripts/``."""
    sources = {}
    for top in SOURCES:
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            sources[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path.read_text(encoding="utf-8")
    return sources


def _is_private(name: str) -> bool:
    """``_name`` is private; ``__name__`` (a protocol name, ``__version__``) is not."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_crossings(sources: dict[str, str], packages: tuple = SOURCES) -> list[str]:
    """Every use of a private name outside the module that defines it, as ``"module:line: dotted name"``.

    A use is ``from X import _name``, ``import X._name``, ``from X._name import ...`` or an attribute ``X._name``
    of an imported module or name ``X`` (``import a.b as m; m._f``, ``from a import b; b._f``), anywhere in the
    source, relative imports resolved. Only names of ``packages`` count (``os._exit`` is not ours). A private
    module (``pkg/_options.py``) belongs to its package: the package and its other modules may use it. Any other
    private name belongs to its module alone, so a package's ``__init__`` that imports a submodule's private name
    is a crossing too. ``sources`` maps dotted module names to their text (``__init__`` as the package's name)."""
    is_package = {name: any(other.startswith(name + ".") for other in sources) for name in sources}
    crossings = []

    def check(module: str, line: int, dotted: str) -> None:
        parts = dotted.split(".")
        if parts[0] not in packages:
            return
        for k, part in enumerate(parts):
            if not _is_private(part):
                continue
            name = ".".join(parts[:k + 1])
            owner = ".".join(parts[:k])
            if name in sources and (module == owner or module.startswith(owner + ".")):
                continue  # a private module used inside its package: its own private names are checked next
            if module != owner:
                crossings.append(f"{module}:{line}: {dotted}")
            return

    for module, text in sources.items():
        tree = ast.parse(text, module)
        package = module.split(".") if is_package[module] else module.split(".")[:-1]
        bound = {}  # local name -> the dotted name it was imported as
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    check(module, node.lineno, alias.name)
                    if alias.asname:
                        bound[alias.asname] = alias.name
                    else:
                        bound[alias.name.split(".")[0]] = alias.name.split(".")[0]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[:len(package) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module
                for alias in node.names:
                    if alias.name != "*":
                        check(module, node.lineno, f"{target}.{alias.name}")
                        bound[alias.asname or alias.name] = f"{target}.{alias.name}"
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _is_private(node.attr):
                chain, value = [node.attr], node.value
                while isinstance(value, ast.Attribute):
                    chain.append(value.attr)
                    value = value.value
                if isinstance(value, ast.Name) and value.id in bound:
                    check(module, node.lineno, ".".join([bound[value.id]] + chain[::-1]))
    return sorted(set(crossings))


def test_the_private_name_check_finds_each_kind_of_crossing():
    sources = {
        "p": "from p.kernels import _kernel\nfrom p import _helpers\n__version__ = '1'\n",
        "p._helpers": "def _tool(): pass\n",
        "p.kernels": "def _kernel(): pass\ndef public(): return _kernel()\n",
        "p.user": ("from p.kernels import _kernel, public\nfrom p._helpers import _tool\nfrom . import _helpers\n"
                   "import p.kernels as k\nfrom p import kernels\nimport p.kernels\nfrom p import __version__\n"
                   "k._kernel(); kernels._kernel(); p.kernels._kernel(); k.public(); self._own = 1\n"),
        "p.mine": "def _own(): pass\nclass A:\n    def f(self): return self._x, _own()\n",
        "q": "from p._helpers import public\nimport p._helpers\nimport os\nos._exit\n",
    }
    assert _private_crossings(sources, packages=("p", "q")) == sorted([
        "p:1: p.kernels._kernel",  # a package re-exporting its submodule's private name
        "p.user:1: p.kernels._kernel",
        "p.user:2: p._helpers._tool",  # a private module's private name
        "p.user:8: p.kernels._kernel",  # k._kernel, kernels._kernel and p.kernels._kernel, all on line 8
        "q:1: p._helpers.public",  # a private module outside its package
        "q:2: p._helpers",
    ])


def test_no_private_name_crosses_a_module_boundary():
    """A name another module needs is public API of its module (a numba kernel called from another module's kernel
    included); tests may still reach into the module they test."""
    crossings = _private_crossings(_sources())
    assert not crossings, "private names used outside their module:\n" + "\n".join(crossings)
