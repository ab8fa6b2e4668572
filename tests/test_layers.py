"""The package's import graph: layers import only downwards, and no module imports itself through others.

Walks every module of ``fwdlook_cli`` with :mod:`ast` (no import is executed), including imports inside
functions, and checks two facts:

* every import of a fwdlook module is allowed by :data:`ALLOWED` (a layer may import itself and the
  layers listed for it: ``dsp``, ``io`` and ``scenario`` never import ``forward``, ``isar``, ``report``
  or the commands, and the two radar systems never import each other);
* the module graph has no cycle, direct or through other modules.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "fwdlook_cli"

# layer -> the layers it may import (besides itself)
ALLOWED = {
    "base": set(),                                   # errors.py: the one exception type
    "dsp": {"base"},
    "io": {"base", "dsp"},
    "scenario": {"base", "dsp"},
    "runner": {"base", "io"},
    "forward": {"base", "dsp", "io", "scenario", "runner"},
    "isar": {"base", "dsp", "io", "scenario", "runner"},
    "testing": {"base", "scenario"},
    "report": {"base", "dsp", "io", "scenario", "runner", "forward", "isar"},
    "cli": {"base", "dsp", "io", "scenario", "runner", "forward", "isar", "report"},
}
TOP_LEVEL = {"errors": "base", "limits": "base", "runner": "runner", "testing": "testing", "cli": "cli", "options": "cli",
             "console": "cli", "api": "cli", "cube_source": "cli"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1:
        return "cli"                                 # the package itself: __version__ and the lazy API facade
    if parts[1] in ALLOWED:
        return parts[1]
    return TOP_LEVEL[parts[1]]


def imports_of(path: Path, modules: set[str]) -> set[str]:
    """fwdlook modules imported by ``path`` (``from . import x`` counts as module ``x`` when it is one)."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                root = ".".join(base + ([node.module] if node.module else []))
            else:
                root = node.module or ""
            names = [root] + [f"{root}.{a.name}" for a in node.names]
        else:
            continue
        for name in names:
            if name in modules:
                found.add(name)
    found.discard(me)
    return found


def import_graph() -> dict[str, set[str]]:
    paths = sorted(PKG.rglob("*.py"))
    modules = {module_name(p) for p in paths}
    return {module_name(p): imports_of(p, modules) for p in paths}


def test_every_module_has_a_layer():
    for module in import_graph():
        assert layer_of(module) in ALLOWED, module


def test_layers_import_only_downwards():
    bad = []
    for module, deps in import_graph().items():
        mine = layer_of(module)
        for dep in deps:
            theirs = layer_of(dep)
            if dep == "fwdlook_cli":
                continue                              # __version__
            if theirs != mine and theirs not in ALLOWED[mine]:
                bad.append(f"{module} ({mine}) imports {dep} ({theirs})")
    assert not bad, "\n".join(bad)


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules, or None (iterative depth-first search)."""
    colour = {m: 0 for m in graph}                   # 0 new, 1 on the stack, 2 done
    for start in graph:
        if colour[start]:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        colour[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
                continue
            if nxt not in graph:
                continue
            if colour[nxt] == 1:
                return path[path.index(nxt):] + [nxt]
            if colour[nxt] == 0:
                colour[nxt] = 1
                stack.append((nxt, iter(sorted(graph[nxt]))))
                path.append(nxt)
    return None


def test_no_import_cycle():
    graph = {m: {d for d in deps if d != "fwdlook_cli"} for m, deps in import_graph().items()}
    cycle = find_cycle(graph)
    assert cycle is None, " -> ".join(cycle)


def test_cycle_finder_finds_a_planted_cycle():
    """The checker itself can fail: a three-module circle and a self-free chain."""
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


@pytest.mark.parametrize("module, dep, ok", [
    ("fwdlook_cli.dsp.keystone", "fwdlook_cli.forward.chain", False),
    ("fwdlook_cli.forward.chain", "fwdlook_cli.dsp.keystone", True),
    ("fwdlook_cli.forward.chain", "fwdlook_cli.isar.stages", False),
    ("fwdlook_cli.scenario.loader", "fwdlook_cli.report.plots", False),
])
def test_layer_rule_itself(module, dep, ok):
    mine, theirs = layer_of(module), layer_of(dep)
    assert (theirs == mine or theirs in ALLOWED[mine]) is ok


def test_no_module_much_over_500_lines():
    long = {module_name(p): n for p in PKG.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 550}
    assert not long, long


def test_repository_paths_of_moved_modules_exist():
    """Modules that find the repository's scenarios from their own file resolve to the real folders
    (a module moved one package deeper must climb one level more)."""
    from fwdlook_cli.report import bench, experiments, fig8, isar_tables, scene_bench

    root = PKG.parent
    assert experiments.REPO == root and fig8.REPO == root
    for path in (experiments.SCENARIOS, experiments.CONFIGS, bench.SCENARIOS, isar_tables._scenario_dir()):
        assert path.is_dir(), path
    assert scene_bench.SCENARIO.is_file()
