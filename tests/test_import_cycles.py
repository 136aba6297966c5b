"""Dependencies run one way: no import cycle between the package's modules, nor between its subpackages
(``datasets``, ``eval``, ``mapping``, ...; each top-level module is a node of its own), counting imports at
module level and inside functions alike (an import moved into a function hides a cycle from Python, not from
the design). ``if TYPE_CHECKING:`` blocks do not count: they never run."""

from __future__ import annotations

import ast
from pathlib import Path

import ogscene3d

ROOT = Path(ogscene3d.__file__).resolve().parent
KERNELS = ROOT.parent.parent / "kernels"


def _module_files() -> dict[str, Path]:
    files = {}
    for base, prefix in ((ROOT, "ogscene3d"), (KERNELS, "ogscene3d.kernels")):
        for path in base.rglob("*.py"):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            files[".".join([prefix, *parts])] = path
    return files


def _reexports(tree: ast.Module) -> dict[str, str]:
    """name -> relative module, of the names a package ``__init__`` re-exports (through ``lazy_exports``,
    or imported as ``from .module import name``)."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
            out.update({a.name: f".{node.module}" for a in node.names})
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "lazy_exports":
            table = node.args[1]
            assert isinstance(table, ast.Dict)
            for key, names in zip(table.keys, table.values):
                for name in ast.literal_eval(names):
                    out[name] = ast.literal_eval(key)
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST):
    """Every Import / ImportFrom under ``tree`` (in functions too), except inside ``if TYPE_CHECKING:``."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            yield from (n for child in node.orelse for n in _imports_of(child))
            continue
        yield from _imports_of(node)


def _imports_of(node: ast.AST):
    if isinstance(node, ast.Import | ast.ImportFrom):
        yield node
    else:
        yield from _imports(node)


def import_graph() -> dict[str, set[str]]:
    """module -> the package modules it imports (a name re-exported by a package counts as an import of
    the module that defines it)."""
    files = _module_files()
    trees = {m: ast.parse(p.read_text(), str(p)) for m, p in files.items()}
    lazy = {m: _reexports(t) for m, t in trees.items() if files[m].name == "__init__.py"}

    def resolve(package: str, name: str) -> str | None:
        if f"{package}.{name}" in files:
            return f"{package}.{name}"
        if name in lazy.get(package, {}):
            rel = lazy[package][name]
            target = package + rel if rel != "." else package
            return resolve_module(target)
        return resolve_module(package)

    def resolve_module(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {m: set() for m in files}
    for mod, tree in trees.items():
        is_pkg = files[mod].name == "__init__.py"
        for node in _imports(tree):
            if isinstance(node, ast.Import):
                targets = [resolve_module(a.name) for a in node.names if a.name.startswith("ogscene3d")]
            else:
                if node.level:
                    base = mod if is_pkg else mod.rpartition(".")[0]
                    for _ in range(node.level - 1):
                        base = base.rpartition(".")[0]
                    package = f"{base}.{node.module}" if node.module else base
                elif node.module and node.module.startswith("ogscene3d"):
                    package = node.module
                else:
                    continue
                targets = [resolve(package, a.name) for a in node.names]
            graph[mod].update(t for t in targets if t and t != mod)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_walker_sees_function_level_imports_and_skips_type_checking():
    tree = ast.parse(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import a\ndef f():\n    import b\n"
    )
    assert [n.names[0].name for n in _imports(tree)] == ["TYPE_CHECKING", "b"]
    assert cycles({"x": {"y"}, "y": {"z"}, "z": {"x"}, "w": {"x"}}) == [["x", "y", "z"]]


def test_no_import_cycle_between_modules():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def package_of(module: str) -> str:
    """The node ``module`` belongs to in the graph between packages: its subpackage of ``ogscene3d``
    (``ogscene3d.mapping.source`` -> ``ogscene3d.mapping``), or itself for a top-level module."""
    return ".".join(module.split(".")[:2])


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """``graph`` (module -> modules) collapsed onto :func:`package_of` (imports inside a package dropped)."""
    out: dict[str, set[str]] = {}
    for mod, targets in graph.items():
        src = package_of(mod)
        out.setdefault(src, set()).update(package_of(t) for t in targets if package_of(t) != src)
    for targets in list(out.values()):
        for t in targets:
            out.setdefault(t, set())
    return out


def _package_edges(graph: dict[str, set[str]], packages: list[str]) -> list[str]:
    """The module imports that make up a cycle between ``packages``, as ``a -> b`` lines."""
    members = set(packages)
    return sorted(
        f"{mod} -> {t}"
        for mod, targets in graph.items()
        for t in targets
        if package_of(mod) in members and package_of(t) in members and package_of(t) != package_of(mod)
    )


def test_the_package_graph_collapses_modules_onto_subpackages():
    graph = {
        "ogscene3d.eval.views": {"ogscene3d.mapping.source", "ogscene3d.eval.readers"},
        "ogscene3d.eval.readers": set(),
        "ogscene3d.mapping.ablation": {"ogscene3d.eval.run_eval"},
        "ogscene3d.mapping.source": {"ogscene3d.config"},
        "ogscene3d.eval.run_eval": set(),
        "ogscene3d.config": set(),
    }
    assert not cycles(graph)  # no cycle between modules ...
    packages = package_graph(graph)
    assert packages["ogscene3d.config"] == set()
    assert cycles(packages) == [["ogscene3d.eval", "ogscene3d.mapping"]]  # ... but one between packages
    assert _package_edges(graph, ["ogscene3d.eval", "ogscene3d.mapping"]) == [
        "ogscene3d.eval.views -> ogscene3d.mapping.source",
        "ogscene3d.mapping.ablation -> ogscene3d.eval.run_eval",
    ]


def test_no_import_cycle_between_subpackages():
    graph = import_graph()
    found = cycles(package_graph(graph))
    assert not found, "import cycles between packages: " + "; ".join(
        " <-> ".join(c) + " (" + ", ".join(_package_edges(graph, c)) + ")" for c in found
    )
