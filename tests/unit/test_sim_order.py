"""`services.sim` in one dependency order: no module imports, directly or through others, one that imports it.

Read from the source with `ast`, like `test_import_direction.py`, and every import counts: those inside
functions and under ``TYPE_CHECKING`` too (a back-import there is the same circle, only drawn later).
Relative imports are resolved, and ``from vrsim.services.sim import x`` is the module ``services.sim.x``
(named as the folders spell it, `repo_name`) where there is one (else the package itself, which defines
the name). Importing a submodule runs its package's ``__init__`` first; that is not an edge here (a
package that imports its modules would make every one of them a circle): the package's own imports are
its edges.
"""

import ast
import os
from collections import deque

from tests.unit.test_import_direction import ROOT, repo_name

PACKAGE = "services.sim"


def module_files(package: str = PACKAGE, root: str = ROOT) -> dict[str, str]:
    """{module name: its file} of every .py file under `package`."""
    out = {}
    for folder, _, files in os.walk(os.path.join(root, *package.split("."))):
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                rel = os.path.relpath(path, root)[:-3].replace(os.sep, ".")
                out[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = path
    return out


def _known(name: str, known) -> str | None:
    """The longest prefix of the dotted `name` that is one of the `known` modules, or None."""
    parts = name.split(".")
    while parts:
        if ".".join(parts) in known:
            return ".".join(parts)
        parts.pop()
    return None


def _imported(node: ast.AST, module: str, is_package: bool, known) -> set[str]:
    """The `known` modules one Import/ImportFrom node of `module` imports."""
    if isinstance(node, ast.Import):
        return {m for alias in node.names if (m := _known(repo_name(alias.name), known))}
    base = repo_name(node.module or "") if node.level == 0 else (node.module or "")
    if node.level:  # relative: from the module's package (the package itself for an __init__)
        anchor = module.split(".") if is_package else module.split(".")[:-1]
        anchor = anchor[:len(anchor) - (node.level - 1)]
        base = ".".join([*anchor, *([base] if base else [])])
    out = set()
    for alias in node.names:
        # `from pkg import sub`: the submodule where there is one, else the module defining the name.
        sub = f"{base}.{alias.name}" if base else alias.name
        target = sub if sub in known else _known(base, known)
        if target:
            out.add(target)
    return out


def import_graph(package: str = PACKAGE, root: str = ROOT) -> dict[str, set[str]]:
    """{module: the modules of `package` it imports}, over every import in its source."""
    files = module_files(package, root)
    graph = {}
    for module, path in files.items():
        tree = ast.parse(open(path, encoding="utf-8").read(), path)
        is_package = path.endswith("__init__.py")
        edges = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                edges |= _imported(node, module, is_package, files)
        graph[module] = edges - {module}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other, directly or through others (the strongly connected
    components of more than one module, Tarjan), each sorted."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v):
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
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(groups)


def one_loop(graph: dict[str, set[str]], group: list[str]) -> list[str]:
    """A shortest import loop through the group's first module, inside the group: [a, b, ..., a]."""
    start, members = group[0], set(group)
    came_from = {start: None}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w in sorted(graph[v] & members):
            if w == start:
                path = [v]
                while came_from[path[-1]] is not None:
                    path.append(came_from[path[-1]])
                return [*reversed(path), start]
            if w not in came_from:
                came_from[w] = v
                queue.append(w)
    return group


def _report(graph: dict[str, set[str]]) -> list[str]:
    return [f"{len(group)} modules import each other: {', '.join(group)} "
            f"(e.g. {' -> '.join(one_loop(graph, group))})" for group in circles(graph)]


def test_services_sim_has_no_import_circle():
    graph = import_graph()
    assert {"services.sim.metrics", "services.sim.accounting", "services.sim.machines.base"} <= set(graph)
    assert _report(graph) == []


def test_the_checker_finds_a_circle_of_any_kind_of_import(tmp_path):
    """The checker itself, on a small tree: a lazy import, one under TYPE_CHECKING, a relative one and
    ``from pkg import sub`` close circles; a package's __init__ importing its modules does not."""
    pkg = tmp_path / "services" / "sim"
    (pkg / "kinds").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from vrsim.services.sim.b import g\n")
    (pkg / "b.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n"
                              "    from vrsim.services.sim import c\n")
    (pkg / "c.py").write_text("from . import a\n")
    (pkg / "d.py").write_text("from vrsim.services.sim.kinds.one import X\n")
    (pkg / "kinds" / "__init__.py").write_text("from vrsim.services.sim.kinds import one\n")
    (pkg / "kinds" / "one.py").write_text("from ..d import Y\nX = 1\n")
    graph = import_graph(root=str(tmp_path))
    assert graph["services.sim.c"] == {"services.sim.a"}
    assert graph["services.sim.kinds.one"] == {"services.sim.d"}
    assert circles(graph) == [["services.sim.a", "services.sim.b", "services.sim.c"],
                              ["services.sim.d", "services.sim.kinds.one"]]
    assert _report(graph)[0] == ("3 modules import each other: services.sim.a, services.sim.b, "
                                 "services.sim.c (e.g. services.sim.a -> services.sim.b -> services.sim.c "
                                 "-> services.sim.a)")
    (pkg / "kinds" / "one.py").write_text("X = 1\n")
    assert circles(import_graph(root=str(tmp_path))) == [["services.sim.a", "services.sim.b",
                                                          "services.sim.c"]]
