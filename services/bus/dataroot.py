"""What a service reads for a scenario that came over the bus: files under the data root only.

``vrsim serve --data-root DIR`` (default: the folder ``serve`` runs in). Every file a scenario
received over the bus names (``[field] file``, ``[map] file``, and what a reader opens along with
them: a shapefile's ``.dbf``, an ISOXML folder's files) must resolve, symlinks and ``..`` followed,
under DIR and outside the private state folder; side files beside a symlinked file are checked where
a reader opens them (beside the link), and a raster whose side files would lead GDAL elsewhere (a VRT
``.ovr``, an ``.aux.xml`` naming an overview file) is refused (`common.files.check_within`). Anything
else is refused before it is opened, with a message that names the path as given and says nothing of
whether it exists. The readers then open each file only as what it claims to be (a ``.tif`` with the
GTiff driver, no VRT, no side files, no network; docs/security.md). `vrsim run` and the other local
commands read local files as they always did, with those same readers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from common import ScenarioError, files
from services.bus.config import ServiceConfig


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
        from services.sim import scenario

        sc = scenario.parse(text, source, base_dir)
        for what, path in scenario.files_named(sc):
            files.check_within(path, self.root, ScenarioError, self.private, label=f"{source}: {what} {path}")
        return sc
