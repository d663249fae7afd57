"""Each module's public surface is what other modules use: a leading underscore marks the rest.

Read from the source with `ast`, like `test_import_direction.py` (every import, lazy ones too):

- (a) No private name crosses a module boundary: neither ``from x import _y`` nor ``x._y`` on a
  module ``x`` in vrsim's packages. Attributes of objects (``obj._y``) are out of reach of a
  parser, which does not know types; dunders (``__version__``) are public.
- (b) A module-level function or class without an underscore in `common`, `maps`, `vehicle`,
  `controller` or `services` is used by another of those modules or listed in its module's
  ``__all__`` (the API a user imports: `services.sim.__all__`, `maps.__all__`, ...).

A *use* by another module is ``from x import y``; ``x.y`` on an imported module ``x``
(``services.sim.run.drive``); an entry of a package's lazy table ``_LAZY = {"name": "module"}`` (the
re-exports its module ``__getattr__`` resolves on first use); a module-level decorator or call of
another module that receives the definition (``@register("pid", PidParams, ...)`` hands both to
`controller.registry`); a class named in the signature of a function or the fields of a class other
modules use (its users hold one); a command of pyproject.toml's ``[project.scripts]``. Modules found
by name at run time (`services.cli.main` imports ``services.cli.<command>``, `vrsim serve`
``services.bus.<service>``, the plot worker draws by function name) are used through their
protocol's names (`PROTOCOLS`).

Tests, benchmarks and the example scripts do not count as uses, and (a) does not apply to them: a
unit test is its module's own and may call its private helpers; a name public only for a test would
still be the module's internals, and a user's API is what ``__all__`` says.
"""

import ast
import functools
import os
import re
import subprocess
import sys
import tomllib

from tests.unit.test_import_direction import repo_name

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PACKAGES = ("common", "maps", "vehicle", "controller", "services")

# Entry points called by a module found at run time by its name: {module pattern: names}.
PROTOCOLS = {
    r"services\.cli\.\w+": {"configure", "run"},  # services.cli.main: HELP, configure(parser), run(args)
    r"services\.bus\.\w+": {"main"},  # vrsim serve NAME: services.bus.NAME.main(config, stop)
    # The plot worker draws a job by its function's name (`services.outputs.plot_worker.DRAWINGS`).
    r"services\.outputs\.plots": {"draw_maps", "draw_sections", "draw_timeseries"},
}

# Exceptions to both rules, (module, name): why. None today; the test below flags an entry no longer
# needed, so the list cannot keep a stale one.
ALLOWED: dict[tuple[str, str], str] = {}


@functools.cache
def _parse(root: str, packages=PACKAGES) -> dict[str, ast.Module]:
    """{module name: its syntax tree} of every .py file under `packages`."""
    out = {}
    for package in packages:
        for folder, _, files in os.walk(os.path.join(root, package)):
            for name in sorted(files):
                if name.endswith(".py"):
                    path = os.path.join(folder, name)
                    rel = os.path.relpath(path, root)[:-3].replace(os.sep, ".")
                    module = rel[:-len(".__init__")] if rel.endswith(".__init__") else rel
                    out[module] = ast.parse(open(path, encoding="utf-8").read(), path)
    return out


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _uses(tree: ast.Module, known: set[str]) -> set[tuple[str, str]]:
    """(module, name) of every name of another module of `known` that `tree` imports or reads."""
    bound = {}  # local name -> the module it is bound to
    uses = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname:
                    bound[alias.asname] = repo_name(alias.name)
                else:
                    bound[alias.name.split(".")[0]] = alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.module:
            module = repo_name(node.module)
            for alias in node.names:
                full = f"{module}.{alias.name}" if module else alias.name
                if full in known:
                    bound[alias.asname or alias.name] = full
                else:
                    uses.add((module, alias.name))
        elif (isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict)
              and any(isinstance(t, ast.Name) and t.id == "_LAZY" for t in node.targets)):
            uses.update((repo_name(v.value), k.value)
                        for k, v in zip(node.value.keys, node.value.values, strict=True)
                        if isinstance(k, ast.Constant) and isinstance(v, ast.Constant))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            chain = []
            base = node
            while isinstance(base, ast.Attribute):
                chain.insert(0, base.attr)
                base = base.value
            if isinstance(base, ast.Name) and base.id in bound:
                parts = repo_name(".".join([bound[base.id], *chain])).split(".")
                # The longest prefix that is a module; the next part is the name used.
                for i in range(len(parts) - 1, 0, -1):
                    if ".".join(parts[:i]) in known:
                        uses.add((".".join(parts[:i]), parts[i]))
                        break
    return {(m, n) for m, n in uses if m in known}


def _handed_over(tree: ast.Module, known: set[str]) -> set[str]:
    """The names of the definitions a module-level decorator or call of another vrsim module receives.

    ``@register("pid", PidParams, ...)`` on ``class PidController`` hands the class and its parameters
    to `controller.registry`, which uses them from then on: that is a use by another module.
    """
    own = set()  # names `tree` imports from vrsim's modules
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and (
                repo_name(node.module) in known or node.module == "vrsim"):
            own.update(alias.asname or alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            own.update((alias.asname or alias.name).split(".")[0] for alias in node.names
                       if repo_name(alias.name) in known)

    def foreign(call) -> bool:
        func = call.func if isinstance(call, ast.Call) else call
        while isinstance(func, ast.Attribute):
            func = func.value
        return isinstance(func, ast.Name) and func.id in own

    def names(call) -> set[str]:
        if not isinstance(call, ast.Call):
            return set()
        return {a.id for a in (*call.args, *(k.value for k in call.keywords)) if isinstance(a, ast.Name)}

    given = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            for deco in node.decorator_list:
                if foreign(deco):
                    given |= {node.name, *names(deco)}
        elif isinstance(node, ast.Expr) and isinstance(node.value, ast.Call) and foreign(node.value):
            given |= names(node.value)
    return given


def _entry_points(root: str) -> set[tuple[str, str]]:
    """(module, name) of the commands pyproject.toml installs (``vrsim = "vrsim.services.cli.main:console"``:
    ``("services.cli.main", "console")``)."""
    path = os.path.join(root, "pyproject.toml")
    if not os.path.exists(path):
        return set()
    with open(path, "rb") as fh:
        scripts = tomllib.load(fh).get("project", {}).get("scripts", {})
    return {(repo_name(module), name) for module, name in (t.split(":") for t in scripts.values())}


def _in_signatures(trees: dict[str, ast.Module], used: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """`used` and the classes named in the signatures of its functions and the fields of its classes.

    ``load_state(folder) -> SecurityState``: whoever calls it holds one, so the type is public too;
    so are `Scenario`'s tables, the classes of its fields.
    """
    out = set(used)
    while True:  # a field's class has fields too
        found = set(out)
        for mod, tree in trees.items():
            for node in tree.body:
                if (mod, getattr(node, "name", None)) not in out:
                    continue
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    args = node.args
                    notes = [a.annotation for a in (*args.posonlyargs, *args.args, *args.kwonlyargs)]
                    notes.append(node.returns)
                elif isinstance(node, ast.ClassDef):
                    notes = [s.annotation for s in node.body if isinstance(s, ast.AnnAssign)]
                else:
                    continue
                found.update((mod, n.id) for note in notes if note is not None
                             for n in ast.walk(note) if isinstance(n, ast.Name))
        if found == out:
            return out
        out = found


def _all(tree: ast.Module) -> set[str]:
    """The names of a module's ``__all__``: strings and ``*TABLE`` (the keys of a module-level dict)."""
    tables = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            name, value = node.targets[0].id, node.value
            if isinstance(value, ast.Dict):
                tables[name] = {k.value for k in value.keys if isinstance(k, ast.Constant)}
            elif name == "__all__":
                starred = [e.value.id for e in value.elts
                           if isinstance(e, ast.Starred) and isinstance(e.value, ast.Name)]
                return ({e.value for e in value.elts if isinstance(e, ast.Constant)}
                        | {k for table in starred for k in tables.get(table, ())})
    return set()


@functools.cache
def _crossings(root: str) -> frozenset[tuple[str, str, str]]:
    """(module, module it takes a name from, name) of every use across modules under `root`."""
    trees = _parse(root)
    return frozenset((mod, target, name) for mod, tree in trees.items()
                     for target, name in _uses(tree, set(trees)) if target != mod)


def private_crossings(root: str = ROOT, allowed=ALLOWED) -> list[str]:
    """(a): every private name a module takes from another one, but those of `allowed`."""
    return sorted(f"{mod} uses {target}.{name}" for mod, target, name in _crossings(root)
                  if _private(name) and (target, name) not in allowed)


def unused_public(root: str = ROOT, allowed=ALLOWED) -> list[str]:
    """(b): every public module-level function or class that no other module uses, nor `__all__` lists,
    but those of `allowed`."""
    trees = _parse(root)
    used = {(target, name) for _, target, name in _crossings(root)} | _entry_points(root)
    used = _in_signatures(trees, used)
    bad = []
    for mod, tree in trees.items():
        exported = _all(tree) | _handed_over(tree, set(trees)) | {
            n for pattern, names in PROTOCOLS.items() if re.fullmatch(pattern, mod) for n in names}
        for node in tree.body:
            if (isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                    and not node.name.startswith("_") and node.name not in exported
                    and (mod, node.name) not in used and (mod, node.name) not in allowed):
                bad.append(f"{mod}.{node.name}")
    return sorted(bad)


def test_no_private_name_crosses_modules():
    assert private_crossings() == []


def test_every_public_name_is_used_elsewhere_or_exported():
    assert unused_public() == []


def test_the_allow_list_holds_only_names_that_need_it():
    """An entry the tree no longer needs is stale: the coordinator empties the list after merging."""
    needed = {line.split()[-1] for line in private_crossings(allowed={})} | set(unused_public(allowed={}))
    assert sorted(f"{m}.{n}" for m, n in ALLOWED if f"{m}.{n}" not in needed) == []


def test_the_rules_catch_a_private_import_and_an_unused_name(tmp_path):
    """The checker itself, on a small tree: a private import, a private module attribute, an unused name."""
    pkg = tmp_path / "maps"
    pkg.mkdir()
    (pkg / "__init__.py").write_text('_LAZY = {"lazy": "maps.a"}\n')
    (pkg / "a.py").write_text("def _helper():\n    pass\n\ndef used():\n    pass\n\ndef lone():\n    pass\n\n"
                              "def lazy():\n    pass\n\nclass Listed:\n    pass\n\n__all__ = ['Listed']\n")
    (pkg / "b.py").write_text("from vrsim.maps.a import _helper, used\n")
    (pkg / "c.py").write_text("import vrsim.maps.a\n\ndef _f():\n    return vrsim.maps.a._helper\n")
    assert private_crossings(str(tmp_path)) == ["maps.b uses maps.a._helper", "maps.c uses maps.a._helper"]
    assert unused_public(str(tmp_path)) == ["maps.a.lone"]


def test_the_simulation_api_is_importable_from_the_package():
    """`services.sim`'s names are the functions and classes, also after their modules were imported."""
    code = ("import vrsim.services.sim.run, vrsim.services.sim.compare, vrsim.services.sim.evaluate\n"
            "import vrsim.services.sim.tune\n"
            "from vrsim.services.sim import load, run, with_changes, drive, control_and_account\n"
            "from vrsim.services.sim import compare, tune\n"
            "import vrsim.services.sim as sim\n"
            "assert run.__module__ == 'vrsim.services.sim.run' and callable(run) and sim.run is run\n"
            "assert compare.__module__ == 'vrsim.services.sim.compare'\n"
            "assert tune.__module__ == 'vrsim.services.sim.tune'\n"
            "assert sim.evaluate.__module__ == 'vrsim.services.sim.evaluate' and callable(sim.evaluate)\n"
            "assert [n for n in sim.__all__ if getattr(sim, n) is None] == []\n"
            "assert set(sim.__all__) <= set(dir(sim))\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    from vrsim.services import sim

    assert {"load", "run", "with_changes", "drive", "control_and_account"} <= set(sim.__all__)


def test_importing_a_submodule_loads_no_other_part_of_the_api():
    """`vrsim run` imports `services.sim.scenario` to parse its options: the package adds nothing to it."""
    heavy = ("vrsim.services.sim.run", "vrsim.services.sim.compare", "vrsim.services.sim.sweep",
             "vrsim.services.sim.tune", "vrsim.services.sim.evaluate", "scipy")
    code = f"import sys, vrsim.services.sim.scenario\nprint(*(m for m in {heavy!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.split() == [], (done.stdout, done.stderr)


def _namesakes(tree: ast.Module) -> list[str]:
    """Where `tree` takes one of `services.sim`'s functions named like its module for the module:
    ``import services.sim.run as m`` (binds the function), or ``from services.sim import run``
    then ``run.drive``."""
    from vrsim.services import sim as sim_package

    sim = os.path.join(ROOT, "services", "sim")
    clash = {n for n in sim_package.__all__ if os.path.exists(os.path.join(sim, f"{n}.py"))}
    bound, bad = set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            bad += [f"import {a.name} as {a.asname}" for a in node.names
                    if a.asname and repo_name(a.name).startswith("services.sim.")
                    and repo_name(a.name).split(".")[2] in clash]
        elif isinstance(node, ast.ImportFrom) and node.module and repo_name(node.module) == "services.sim":
            bound |= {a.asname or a.name for a in node.names if a.name in clash}
    bad += [f"{n.value.id}.{n.attr}" for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id in bound]
    return bad


def test_no_module_is_taken_for_its_namesake_function():
    """`services.sim.run` is the function: its module is imported by its full name (``from
    services.sim.run import drive``); so are `compare`, `evaluate` and `tune`'s."""
    wrong = "from vrsim.services.sim import run as r\nr.drive(s)\nimport vrsim.services.sim.tune as t\n"
    assert _namesakes(ast.parse(wrong)) == ["import vrsim.services.sim.tune as t", "r.drive"]
    found = {}
    for top in (*PACKAGES, "tests", "bench", "scenarios"):
        for folder, _, files in os.walk(os.path.join(ROOT, top)):
            for name in files:
                if name.endswith(".py"):
                    path = os.path.join(folder, name)
                    bad = _namesakes(ast.parse(open(path, encoding="utf-8").read(), path))
                    if bad:
                        found[os.path.relpath(path, ROOT)] = bad
    assert found == {}
