"""The import layers, read from the source with ast: no arrow from the library up to the services,
no cycle between hydrowatch's subpackages, shared types and constants defined once."""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = "hydrowatch.commands"
"""The command line: the one part of the library that starts the services (``hydrowatch plant`` …)."""
KNOWN_CYCLES = [
    {"hydrowatch.sysid", "hydrowatch.sysid.narx", "hydrowatch.sysid.narx_search"},
    {"hydrowatch.condition", "hydrowatch.condition.estimates", "hydrowatch.condition.features",
     "hydrowatch.condition.features_boxes", "hydrowatch.condition.features_evidence", "hydrowatch.condition.model",
     "hydrowatch.condition.stream",
     "hydrowatch.condition.unit", "hydrowatch.condition.unit_checks"},
    {"hydrowatch.gap.analysis", "hydrowatch.gap.report"},
]
"""Module cycles inside one subpackage that predate issue 13 (through package ``__init__`` imports or lazy
imports); they may shrink or vanish, a new one fails :func:`test_no_new_module_cycle`. features_evidence is a split
of features (2026-11-26), in its cycle through the package ``__init__`` as features is; unit_checks a split of unit
(2026-11-28), in the cycle since features asks it whether the pump's capacity is determined (2026-12-02);
features_boxes a split of features (stop 59), in its cycle as features_evidence is."""


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted([*ROOT.glob("hydrowatch/**/*.py"), *ROOT.glob("services/**/*.py")]):
        parts = path.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


@functools.cache
def _tree(path: Path) -> ast.Module:
    """``path`` parsed, once per session (several tests walk every module)."""
    return ast.parse(path.read_text(encoding="utf-8"))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(node: ast.AST) -> Iterator[str]:
    """Absolute module names imported anywhere in ``node`` (lazy imports too), except under ``if TYPE_CHECKING``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.If) and _is_type_checking(child.test):
            yield from (name for n in child.orelse for name in _imports(ast.Module([n], [])))
            continue
        if isinstance(child, ast.Import):
            yield from (a.name for a in child.names)
        elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
            yield child.module
        yield from _imports(child)


def _graph() -> dict[str, set[str]]:
    """Module → the project modules it imports (a ``from package import name`` counts as the package)."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        targets = set()
        for imported in _imports(_tree(path)):
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            if imported and imported != name:
                targets.add(imported)
        graph[name] = targets
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[set[str]] = []

    def visit(v: str) -> None:
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
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _subpackage(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_the_library_does_not_import_the_services() -> None:
    offenders = sorted(f"{m} -> {t}" for m, targets in _graph().items() for t in targets
                       if m.startswith("hydrowatch") and not m.startswith(CLI) and t.startswith("services"))
    assert offenders == []


def test_no_cycle_between_subpackages() -> None:
    graph: dict[str, set[str]] = {}
    for m, targets in _graph().items():
        mine = _subpackage(m)
        graph.setdefault(mine, set()).update(_subpackage(t) for t in targets if _subpackage(t) != mine)
    assert _cycles(graph) == []
    assert "hydrowatch.training" not in graph["hydrowatch.report"]  # the reports read hydrowatch.results


def test_no_new_module_cycle() -> None:
    cycles = _cycles(_graph())
    assert [c for c in cycles if not any(c <= known for known in KNOWN_CYCLES)] == []
    assert not any(m.startswith("hydrowatch.training") for c in cycles for m in c)


def test_the_cycle_finder_finds_a_cycle_and_skips_type_only_imports() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import x.y\nelse:\n    import z\n"
                     "def f():\n    from w import v\n")
    assert sorted(_imports(tree)) == ["typing", "w", "z"]


def _definitions(pattern: type[ast.AST], name: str) -> list[str]:
    found = []
    for module, path in _modules().items():
        for node in ast.walk(_tree(path)):
            if isinstance(node, pattern) and getattr(node, "name", None) == name:
                found.append(module)
            if isinstance(node, ast.Assign) and pattern is ast.Assign and any(
                    isinstance(t, ast.Name) and t.id == name for t in node.targets):
                if not isinstance(node.value, (ast.Name, ast.Attribute)):  # an alias is not a definition
                    found.append(module)
    return found


def test_shared_types_and_constants_are_defined_once_in_neutral_modules() -> None:
    # (sysid.narx_lm has a TrainingResult of its own: the Levenberg-Marquardt optimiser's result)
    assert [m for m in _definitions(ast.ClassDef, "TrainingResult") if m != "hydrowatch.sysid.narx_lm"] == [
        "hydrowatch.results"]
    assert _definitions(ast.ClassDef, "Verdict") == ["hydrowatch.verdict"]
    assert _definitions(ast.ClassDef, "FilteredNoiseCommand") == ["hydrowatch.plant.excitation"]
    assert _definitions(ast.Assign, "M3S_TO_LPM") == ["hydrowatch.channels"]
