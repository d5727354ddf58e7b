"""The layout's rules that a test can hold: no import cycle anywhere in ``python/percver``.

The graph is read from the source (the AST, not a running interpreter), so an import inside a
function counts as much as one at the top: a lazy import hides a cycle from ``import percver``
but not from a reader. Importing ``a.b.c`` also runs ``a/__init__.py`` and ``a/b/__init__.py``,
so it is an edge to those packages too; an edge from a module to its own ancestor packages is
left out (every module of a package runs its ``__init__`` first, that is no design choice).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "percver"


def module_names(package: Path) -> dict:
    """Module name -> file for every ``.py`` file of the package (``__init__.py`` names the package)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = [package.name, *path.relative_to(package).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imported(node: ast.AST, module: str, is_package: bool) -> list:
    """Absolute names an import statement (or ``importlib.import_module("...")``) loads."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = module.split(".")
            base = base[: len(base) - node.level + (1 if is_package else 0)]
            stem = ".".join(base + ([node.module] if node.module else []))
        else:
            stem = node.module
        return [stem] + [f"{stem}.{alias.name}" for alias in node.names]
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "import_module"
        and node.args
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    ):
        return [node.args[0].value]
    return []


def import_graph(package: Path) -> dict:
    """module -> {imported module of the same package: line of the first such import}."""
    modules = module_names(package)
    graph = {}
    for name, path in modules.items():
        edges: dict = {}
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            for target in _imported(node, name, path.name == "__init__.py"):
                parts = target.split(".")
                # ``from a.b import c`` names a module or an attribute; importing runs every parent package.
                for k in range(1, len(parts) + 1):
                    prefix = ".".join(parts[:k])
                    if prefix in modules and prefix != name and not name.startswith(prefix + "."):
                        edges.setdefault(prefix, node.lineno)
        graph[name] = edges
    return graph


def strongly_connected(graph: dict) -> list:
    """Tarjan's strongly connected components with more than one module (or a module importing itself)."""
    index, low, on_stack, stack, components = {}, {}, set(), [], []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def a_cycle(graph: dict, component: list) -> list:
    """One cycle through the component's first module, as the modules in order (first repeated last)."""
    start, members = component[0], set(component)
    paths = {start: [start]}
    todo = [start]
    while todo:
        v = todo.pop(0)
        for w in sorted(graph[v]):
            if w == start:
                return paths[v] + [start]
            if w in members and w not in paths:
                paths[w] = paths[v] + [w]
                todo.append(w)
    raise AssertionError(f"no cycle through {start} in {component}")


def describe(graph: dict, cycle: list, files: dict) -> str:
    root = PACKAGE.parent
    steps = []
    for a, b in zip(cycle, cycle[1:]):
        where = files[a]
        where = where.relative_to(root) if where.is_relative_to(root) else where.name
        steps.append(f"{a} imports {b} ({where}:{graph[a][b]})")
    return "\n  ".join(steps)


def cycles_report(package: Path) -> str:
    graph, files = import_graph(package), module_names(package)
    return "\n".join(f"import cycle:\n  {describe(graph, a_cycle(graph, c), files)}" for c in strongly_connected(graph))


def test_no_import_cycle_in_percver():
    report = cycles_report(PACKAGE)
    assert not report, f"{report}\nmove the shared piece to a module both can import, or invert the dependency"


def _package(tmp_path: Path, files: dict) -> Path:
    for name, text in files.items():
        path = tmp_path / "pkg" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path / "pkg"


def test_a_planted_cycle_through_a_lazy_import_is_found(tmp_path):
    package = _package(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "from pkg.b import f\n",
            "b.py": "def f():\n    from pkg import c\n",
            "c.py": "import pkg.a\n",
            "d.py": "from . import a\n",
        },
    )
    graph = import_graph(package)
    assert graph["pkg.d"] == {"pkg.a": 1}  # relative imports resolve; nothing imports d
    assert strongly_connected(graph) == [["pkg.a", "pkg.b", "pkg.c"]]
    report = cycles_report(package)
    assert "pkg.a imports pkg.b (a.py:1)" in report and "pkg.b imports pkg.c (b.py:2)" in report
    assert "pkg.c imports pkg.a (c.py:1)" in report


def test_importing_a_submodule_runs_its_package(tmp_path):
    # sub/__init__ imports x, x imports sub.y: a cycle through the package's __init__ (x -> sub).
    package = _package(
        tmp_path,
        {
            "__init__.py": "",
            "x.py": "from pkg.sub.y import g\n",
            "sub/__init__.py": "import importlib\nX = importlib.import_module('pkg.x')\n",
            "sub/y.py": "from pkg.sub import z\n",
            "sub/z.py": "",
        },
    )
    graph = import_graph(package)
    assert strongly_connected(graph) == [["pkg.sub", "pkg.x"]]
    assert "pkg.sub" not in graph["pkg.sub.y"]  # a module's own ancestors are no edge


def test_an_acyclic_package_passes(tmp_path):
    package = _package(tmp_path, {"__init__.py": "from pkg import a, b\n", "a.py": "import pkg.b\n", "b.py": "import pkg\n"})
    assert strongly_connected(import_graph(package)) == []
    assert cycles_report(package) == ""
