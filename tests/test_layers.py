"""The package's layers import only downwards, and no module imports itself round a circle.

Every module of ``surrol_data`` is parsed with :mod:`ast`; every ``import`` / ``from ... import`` it holds, at any
depth (module level, inside functions, under ``if TYPE_CHECKING:``), is an edge of the module graph. The layers
and the rules are those of ``docs/architecture.md``:

====== ==========================================================
layer  packages and modules of ``surrol_data``
====== ==========================================================
0      ``surrol_data`` itself (``__init__``), ``extras``, ``slurm``
1      ``envs``
2      ``render``, ``datasets`` (neither imports the other)
3      ``collect``, ``viz`` (viz does not import collect)
4      ``evaluation``, ``algos`` (evaluation does not import algos)
5      the apps: ``cli``, ``demo``, ``gui``, ``study``, ``train_app``, ``web``
====== ==========================================================

A module may import from its own layer and the ones below, never from a higher one; the pairs named above are
refused too; and the module graph has no cycle. Imports by name at run time (``importlib.import_module``, the
env registry's ``"module:Class"`` strings, entry points) are not imports here: the renderers reach ``envs``
through its registry and the ``surrol_data.renderers`` entry point, which is the point.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "surrol_data"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

LAYERS = {
    PACKAGE: 0, "extras": 0, "slurm": 0,
    "envs": 1,
    "render": 2, "datasets": 2,
    "collect": 3, "viz": 3,
    "evaluation": 4, "algos": 4,
    "cli": 5, "demo": 5, "gui": 5, "study": 5, "train_app": 5, "web": 5,
}
# (importer, imported): refused although the layers alone would allow it (or named for a clearer message).
FORBIDDEN = {
    ("datasets", "render"): "the dataset format does not depend on a renderer",
    ("render", "datasets"): "renderers draw envs; they do not read or write datasets",
    ("datasets", "collect"): "the dataset format (recorder, journal, repair included) sits below the collectors",
    ("envs", "render"): "renderers plug into envs through envs.camera's registry, envs never import them",
    ("evaluation", "algos"): "evaluation takes any policy callable; loading a checkpoint is algos' job "
                             "(surrol_data.algos.policies.load_policy)",
    ("viz", "collect"): "viz draws trajectories; the collectors may use it, not the other way round",
}


@dataclass(frozen=True)
class Import:
    importer: str      # dotted module name
    imported: str      # dotted module name (the longest module prefix of what the statement names)
    path: Path
    line: int

    def where(self) -> str:
        return f"{self.path.relative_to(ROOT.parent)}:{self.line}: {self.importer} imports {self.imported}"


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package ``__init__``)."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts.pop()
        out[".".join(parts)] = (path, is_package)
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The module ``name`` names: itself, or its longest prefix that is a module (``pkg.mod.attr`` -> ``pkg.mod``)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports() -> list[Import]:
    found = []
    for module, (path, is_package) in MODULES.items():
        package = module if is_package else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                # `from pkg import sub` imports the submodule sub; `from mod import name` imports mod.
                names = [f"{source}.{a.name}" if f"{source}.{a.name}" in MODULES else source for a in node.names]
            for name in names:
                if name != PACKAGE and not name.startswith(PACKAGE + "."):
                    continue
                target = _resolve(name)
                if target is not None and target != module:
                    found.append(Import(module, target, path, node.lineno))
    return sorted(set(found), key=lambda i: (i.importer, i.line, i.imported))  # one per statement and module


IMPORTS = _imports()


def _part(module: str) -> str:
    """The layer unit of a module: ``surrol_data`` itself, or the top-level package or module it belongs to."""
    parts = module.split(".")
    return PACKAGE if len(parts) == 1 else parts[1]


def test_the_graph_is_read():
    """The parser sees lazy imports inside functions (a checker that missed them would pass anything)."""
    assert len(MODULES) > 100
    assert any(i.importer == f"{PACKAGE}.cli" and i.imported == f"{PACKAGE}.demo" for i in IMPORTS)


def test_every_part_of_the_package_has_a_layer():
    missing = sorted({_part(m) for m in MODULES} - set(LAYERS))
    assert not missing, (f"{missing} belong to no layer: give each one a layer in tests/test_layers.py "
                         "and docs/architecture.md")


def test_imports_go_downwards_only():
    wrong = []
    for imp in IMPORTS:
        a, b = _part(imp.importer), _part(imp.imported)
        if a == b:
            continue
        if (a, b) in FORBIDDEN:
            wrong.append(f"{imp.where()} ({a} must not import {b}: {FORBIDDEN[a, b]})")
        elif LAYERS.get(b, 99) > LAYERS.get(a, -1):
            wrong.append(f"{imp.where()} (layer {LAYERS.get(a)} {a} imports layer {LAYERS.get(b)} {b}, a higher one)")
    assert not wrong, "imports against the layers (docs/architecture.md):\n  " + "\n  ".join(wrong)


def test_no_import_cycles():
    graph: dict[str, dict[str, Import]] = {m: {} for m in MODULES}
    for imp in IMPORTS:
        graph[imp.importer].setdefault(imp.imported, imp)
    # Tarjan's strongly connected components, iteratively; a component of two or more modules holds a cycle.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph[child])))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
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
    messages = []
    for component in components:
        cycle = _shortest_cycle(graph, component)
        messages.append(f"{' -> '.join([*cycle, cycle[0]])} ({len(component)} modules import each other round "
                        "circles here; this is the shortest):\n    "
                        + "\n    ".join(graph[a][b].where() for a, b in zip(cycle, [*cycle[1:], cycle[0]])))
    assert not messages, "import cycles:\n  " + "\n  ".join(messages)


def _shortest_cycle(graph: dict[str, dict[str, Import]], component: list[str]) -> list[str]:
    """The modules of a shortest cycle through the first module of ``component`` (breadth-first inside it)."""
    members, start = set(component), component[0]
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for child in graph[node]:
                if child == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return path[::-1]
                if child in members and child not in parent:
                    parent[child] = node
                    following.append(child)
        frontier = following
    return component   # not reached: every strongly connected component of two or more holds a cycle
