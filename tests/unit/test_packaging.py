"""pyproject.toml's package list is the tree's: every folder of a room with an ``__init__.py`` is
installed, as ``vrsim.<its dotted path>``, from that folder (test_wheel.py installs one and runs it)."""

import os
import tomllib

from tests.unit.test_import_direction import ROOMS_TOP, ROOT


def _config() -> dict:
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as fh:
        return tomllib.load(fh)["tool"]["setuptools"]


def _package_folders() -> set[str]:
    found = set()
    for room in ROOMS_TOP:
        for folder, dirs, files in os.walk(os.path.join(ROOT, room)):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            if "__init__.py" in files:
                found.add(os.path.relpath(folder, ROOT).replace(os.sep, "."))
    return found


def test_every_package_folder_is_installed_under_vrsim():
    assert sorted(_config()["packages"]) == sorted(f"vrsim.{p}" for p in _package_folders())


def test_each_room_is_installed_from_its_own_folder():
    assert _config()["package-dir"] == {f"vrsim.{room}": room for room in ROOMS_TOP}
