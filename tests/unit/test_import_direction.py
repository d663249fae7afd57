"""Imports point one way: cli -> bus/batch/outputs/sim -> maps/vehicle/controller -> common.

Module names here are the repository's (``maps.grid``, from the folders); the code imports them by their
installed names (``vrsim.maps.grid``: pyproject.toml's package-dir), which `repo_name` maps back.

Read from the source with `ast` (every import, also those inside functions), so a lazy import that
goes the wrong way fails here, not in a user's run.
"""

import ast
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOMAIN = ("maps", "vehicle", "controller")
ROOMS = ("sim", "outputs", "bus", "batch", "cli")
# Modules of services.bus that are shared helpers, not services.
BUS_HELPERS = ("services.bus", "services.bus.config", "services.bus.serving", "services.bus.client",
               "services.bus.messages", "services.bus.security", "services.bus.dataroot",
               "services.bus.reads", "services.bus.records")


def repo_name(name: str) -> str:
    """An imported module's name as the repository's folders spell it (``vrsim.maps.grid`` -> ``maps.grid``;
    ``vrsim`` itself, the namespace, -> ""); any other name as it is."""
    return "" if name == "vrsim" else name.removeprefix("vrsim.")


def modules(package: str, root: str = ROOT) -> dict[str, set[str]]:
    """{module name: the absolute module names it imports} for every .py file under `package`."""
    out = {}
    for folder, _, files in os.walk(os.path.join(root, *package.split("."))):
        for name in files:
            if not name.endswith(".py"):
                continue
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, root)[:-3].replace(os.sep, ".")
            module = rel[:-len(".__init__")] if rel.endswith(".__init__") else rel
            tree = ast.parse(open(path, encoding="utf-8").read(), path)
            imported = set()
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    imported.update(repo_name(alias.name) for alias in node.names)
                elif isinstance(node, ast.ImportFrom):
                    assert node.level == 0, f"{path}: relative import; use absolute ones"
                    base = repo_name(node.module)
                    imported.update({base} - {""})
                    imported.update(f"{base}.{alias.name}" if base else alias.name for alias in node.names)
            out[module] = imported
    return out


def _under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _violations(package: str, forbidden, root: str = ROOT) -> list[str]:
    return sorted(f"{mod} imports {imp}" for mod, imps in modules(package, root).items() for imp in imps
                  if any(_under(imp, f) for f in forbidden))


def test_common_imports_nothing_of_vrsim():
    assert _violations("common", (*DOMAIN, "services")) == []


@pytest.mark.parametrize("package", DOMAIN)
def test_domain_packages_never_import_services_or_each_other(package):
    others = [p for p in DOMAIN if p != package]
    assert _violations(package, ("services", *others)) == []


def test_sim_imports_no_other_room():
    assert _violations("services.sim", ("services.outputs", "services.bus", "services.batch",
                                        "services.cli")) == []


def test_outputs_import_neither_bus_nor_batch_nor_cli():
    assert _violations("services.outputs", ("services.bus", "services.batch", "services.cli")) == []


def test_aog_imports_neither_bus_nor_batch_nor_cli():
    """`vrsim serve aog-rc`'s room (services.aog) builds on sim and outputs only."""
    assert _violations("services.aog", ("services.bus", "services.batch", "services.cli")) == []


def test_aog_app_client_imports_nothing_of_the_module_side():
    """The app's side is written from the app's sources apart from vrsim's codec (docs/aog_rc.md)."""
    imports = modules("services.aog")["services.aog.app_client"]
    assert sorted(i for i in imports if i.startswith("services")) == []


def test_batch_imports_only_sim():
    assert _violations("services.batch", ("services.outputs", "services.bus", "services.cli")) == []


@pytest.mark.parametrize("package", ["common", *DOMAIN, *(f"services.{room}" for room in ROOMS
                                                          if room != "batch")])
def test_only_batch_imports_dask(package):
    assert _violations(package, ("dask", "distributed")) == []


def test_bus_never_imports_cli():
    assert _violations("services.bus", ("services.cli",)) == []


def test_no_bus_service_imports_another_service():
    found = modules("services.bus")
    # A service is a module or a subpackage (services.bus.web.*) of services.bus; its own modules
    # may import each other.
    service_of = {m: ".".join(m.split(".")[:3]) for m in found if m not in BUS_HELPERS}
    services = set(service_of.values())
    assert {"services.bus.map", "services.bus.vehicle", "services.bus.controller", "services.bus.monitor",
            "services.bus.scenario", "services.bus.web"} <= services
    bad = sorted(f"{mod} imports {imp}" for mod, own in service_of.items() for imp in found[mod]
                 if any(_under(imp, other) for other in services if other != own))
    assert bad == []


def test_the_rule_catches_a_wrong_import(tmp_path):
    """The checker itself: a lazy import from a domain package into services is reported."""
    pkg = tmp_path / "maps"
    pkg.mkdir()
    (pkg / "bad.py").write_text("def f():\n    from vrsim.services.sim import run\n")
    assert _violations("maps", ("services",), str(tmp_path)) == ["maps.bad imports services.sim",
                                                                 "maps.bad imports services.sim.run"]


ROOMS_TOP = ("common", "maps", "vehicle", "controller", "services")


def bare_imports(top: str, root: str = ROOT) -> list[str]:
    """Every import under the folder `top` of one of vrsim's rooms by its folder's name (``import maps``)
    rather than its installed one (``from vrsim import maps``)."""
    bad = []
    for folder, _, files in os.walk(os.path.join(root, top)):
        for name in sorted(f for f in files if f.endswith(".py")):
            path = os.path.join(folder, name)
            for node in ast.walk(ast.parse(open(path, encoding="utf-8").read(), path)):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                         [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
                bad += [f"{os.path.relpath(path, root)}:{node.lineno}: {n}" for n in names
                        if n.split(".")[0] in ROOMS_TOP]
    return bad


@pytest.mark.parametrize("top", [*ROOMS_TOP, "tests", "bench", "scenarios"])
def test_every_import_names_the_installed_namespace(top):
    """Run from the checkout, ``import maps`` would still find the folder, and load a second copy of
    each module beside vrsim.maps' (two registries, two classes of one name): only vrsim.* is imported."""
    assert bare_imports(top) == []


def test_the_bare_import_rule_catches_one(tmp_path):
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "a.py").write_text("import os\nfrom vrsim.maps import grid\ndef f():\n"
                                            "    import services.sim.run as r\n    from maps import grid\n")
    assert bare_imports("maps", str(tmp_path)) == ["maps/a.py:4: services.sim.run", "maps/a.py:5: maps"]
