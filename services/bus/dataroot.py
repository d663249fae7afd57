"""What a service reads for a scenario that came over the bus: files under the data root only.

``vrsim serve --data-root DIR`` (default: the folder ``serve`` runs in). Every file a scenario
received over the bus names (``[field] file``, ``[map] file``, a spinner's catch-tray profile
``[implement] pattern``, a fuzzy PID's ``[controller] params.rules_file``, and what a reader opens
along with them: a shapefile's ``.dbf``, an ISOXML folder's files) must resolve, symlinks and ``..``
followed, under DIR and outside the private state folder; side files beside a symlinked file are checked where
a reader opens them (beside the link), and a raster whose side files would lead GDAL elsewhere (a VRT
``.ovr``, an ``.aux.xml`` naming an overview file) is refused (`common.files.check_within`). Anything
else is refused before it is opened, with a message that names the path as given and says nothing of
whether it exists. The readers then open each file only as what it claims to be (a ``.tif`` with the
GTiff driver, no VRT, no side files, no network; docs/security.md). `vrsim run` and the other local
commands read local files as they always did, with those same readers.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass

from vrsim.common import ScenarioError, VrsimError, files
from vrsim.common.toml_text import loads_toml
from vrsim.services.bus.config import ServiceConfig


@dataclass(frozen=True)
class DataRoot:
    """The folder a service's scenarios from the bus may read under, and the private folders in it."""

    root: str
    private: tuple[str, ...] = ()

    @classmethod
    def of(cls, config: ServiceConfig) -> DataRoot:
        """``config.data_root``, with the state folder of the credentials kept out of it."""
        return cls(os.path.realpath(config.data_root), (os.path.realpath(config.zenoh.state_dir),))

    def scenario(self, text: str, source: str, base_dir: str):
        """`services.sim.scenario.parse`, then every file it names checked against the data root.

        Raises
        ------
        ScenarioError
            A bad scenario, or a file outside the data root (naming the file, the table and the key).
        """
        from vrsim.services.sim import scenario

        for what, path in _read_while_parsing(text, base_dir):  # checked before `parse` opens them
            self._check(path, f"{source}: {what} {path}")
        sc = scenario.parse(text, source, base_dir)
        for what, path in scenario.files_named(sc):
            self._check(path, f"{source}: {what} {path}")
        rules = sc.controller.params.get("rules_file") if sc.controller.kind == "fuzzy_pid" else None
        if isinstance(rules, str):  # read by the controller service when it builds the loop
            label = f"{source}: [controller] params.rules_file {rules}"
            self._check(os.path.abspath(rules), label)
            try:
                files.check_file(rules, "toml", ScenarioError)  # a FIFO would hang the reader's open()
            except VrsimError as exc:
                raise ScenarioError(f"{source}: [controller] params.rules_file {exc}") from None
        return sc

    def _check(self, path: str, label: str) -> None:
        files.check_within(path, self.root, ScenarioError, self.private, label=label)


def _read_while_parsing(text: str, base_dir: str) -> list[tuple[str, str]]:
    """(``[table] key``, path) of the files `services.sim.scenario.parse` itself reads: a spinner's
    catch-tray profile CSV (``[implement] pattern``, resolved as `vehicle.spinner.SpinnerSpec.resolved`
    resolves it). A text that does not read as TOML names none here: `parse` says what is wrong."""
    from vrsim.vehicle.spinner import PATTERN_SHAPES

    if "pattern" not in text or len(text) > files.cap_for("toml"):
        return []
    try:
        doc = loads_toml(text, "scenario", ScenarioError)
    except (VrsimError, tomllib.TOMLDecodeError, RecursionError):
        return []
    implement = doc.get("implement")
    pattern = implement.get("pattern") if isinstance(implement, dict) else None
    if not isinstance(pattern, str) or pattern in PATTERN_SHAPES:
        return []
    return [("[implement] pattern", os.path.abspath(os.path.join(base_dir, os.path.expanduser(pattern))))]
