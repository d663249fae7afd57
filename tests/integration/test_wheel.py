"""vrsim as a user installs it: a wheel built from the tracked sources, installed (not editable) into
a fresh virtual environment, run from a folder that is not the checkout.

The fresh environment gets vrsim's dependencies from the project's .venv through a path entry (not
a site directory, so the editable install of .venv is not seen) and vrsim itself only from the
wheel; the test checks that the code that ran is the installed copy.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile

import pytest

from tests.conftest import ROOT

SOURCES = ("pyproject.toml", "README.md", "common", "maps", "vehicle", "controller", "services")


# A user's environment: a PYTHONPATH naming the checkout (as when the tests run from a worktree) would
# put the checkout before the installed copy, and `vrsim accuracy` would run the whole library.
USER_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def sh(*args, cwd=None, timeout=300):
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=USER_ENV)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    for name in SOURCES:  # a copy: building writes build/ and *.egg-info beside the sources
        path = os.path.join(ROOT, name)
        if os.path.isdir(path):
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(path, src / name)
    p = sh(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
           "--disable-pip-version-check", "-w", str(base / "dist"), str(src))
    assert p.returncode == 0, p.stdout + p.stderr
    (wheel,) = (base / "dist").glob("vrsim-*.whl")
    venv = base / "venv"
    p = sh(sys.executable, "-m", "venv", "--without-pip", str(venv))
    assert p.returncode == 0, p.stderr
    python = venv / "bin" / "python"
    site = sh(str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").stdout.strip()
    with open(os.path.join(site, "vrsim-deps.pth"), "w") as fh:
        fh.write(sysconfig.get_paths()["purelib"] + "\n")  # the dependencies, as a plain path
    p = sh(sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
           "--disable-pip-version-check", str(wheel))
    assert p.returncode == 0, p.stdout + p.stderr
    work = base / "elsewhere"
    work.mkdir()
    return {"wheel": wheel, "venv": venv, "python": python, "site": site, "work": work}


def test_the_wheel_ships_the_builtin_scenarios_and_no_tests(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    assert {"vrsim/services/sim/scenarios/default.toml", "vrsim/services/sim/scenarios/large.toml",
            "vrsim/controller/data/fuzzy_pid_rules.toml",
            "vrsim/services/bus/web_static/index.html"} <= set(names)
    assert not [n for n in names if n.startswith(("tests/", "vrsim/tests/"))]


def test_the_wheel_adds_one_top_level_package_vrsim(installed):
    """Installed, the rooms are vrsim.common, vrsim.maps, ...: nothing named `common` or `services` lands in
    a user's environment beside their own packages."""
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    assert {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")} == {"vrsim"}
    assert not [n for n in names if n.startswith("vrsim/__init__")]  # a namespace package
    assert sorted(os.listdir(installed["site"])) == ["vrsim", "vrsim-0.1.0.dist-info", "vrsim-deps.pth"]


def test_installed_vrsim_runs_the_builtin_default_from_any_folder(installed):
    code = "import vrsim.common as c, vrsim.controller as k, vrsim.services.sim.scenario as s\n" \
           "from vrsim import maps, vehicle\n" \
           "print(maps.__file__, s.__file__, vehicle.__file__, c.__file__, k.__file__)"
    where = sh(str(installed["python"]), "-c", code, cwd=installed["work"])
    files = where.stdout.split()
    assert len(files) == 5 and all(f.startswith(installed["site"]) for f in files), where  # not the checkout
    vrsim = str(installed["venv"] / "bin" / "vrsim")
    p = sh(vrsim, "run", "--json", "--quiet", "--out", "out", cwd=installed["work"])
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["scenario"] == "default" and summary["ticks"] > 100_000
    assert (installed["work"] / "out" / "summary.json").is_file()


def test_installed_vrsim_accuracy_exits_2_asking_for_a_checkout(installed):
    vrsim = str(installed["venv"] / "bin" / "vrsim")
    p = sh(vrsim, "accuracy", cwd=installed["work"])
    assert p.returncode == 2, p.stdout + p.stderr
    assert "needs a source checkout" in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
