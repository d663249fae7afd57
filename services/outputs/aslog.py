"""The run's as-applied log in farm formats: taskdata/ (ISO 11783-10 TASKDATA with one TimeLog) and
as_applied_points.gpkg (or .zip, a zipped shapefile): one record per ``[output] log_rate_hz``."""

from __future__ import annotations

import os

from vrsim.maps import write_points, write_taskdata
from vrsim.maps.taskdata import TLG_NAME, prepare_folder
from vrsim.services.sim.run import RunResult

POINT_FILES = {"gpkg": "as_applied_points.gpkg", "shp": "as_applied_points.zip"}


def write_as_applied(result: RunResult, out_dir: str) -> dict[str, str]:
    """Write taskdata/ and the points file (``[output] points``) into `out_dir`; {name: path}.

    A run into the same folder again replaces the earlier run's taskdata/, as it does every other
    file; a taskdata/ that holds anything else is refused (`maps.write_taskdata` never overwrites).
    """
    log = result.kept.point_log   # the run's as-applied log (see `services.sim.aslog`)
    implement = result.world.scenario.implement
    folder = _prepare_as_applied(out_dir)
    paths = {"taskdata": write_taskdata(log, folder,
                                        [implement.section_width_m] * implement.sections,
                                        task=result.world.scenario.name, device="vrsim implement")}
    name = POINT_FILES.get(result.world.scenario.output.points)
    if name:
        paths[name] = os.path.join(out_dir, name)
        write_points(log, paths[name])
    return paths


def check_as_applied(out_dir: str) -> None:
    """Refuse (`common.MapError`) a taskdata/ in `out_dir` that holds another TASKDATA than an earlier
    run's log, before anything is written; changes nothing."""
    folder = os.path.join(out_dir, "taskdata")
    if os.path.isdir(folder) and set(os.listdir(folder)) != _OWN:
        prepare_folder(folder)  # refuses it; or, holding no TASKDATA.XML, leaves it as it is


def _prepare_as_applied(out_dir: str) -> str:
    """The run's taskdata/ folder in `out_dir`, emptied of an earlier run's log and created; refused
    (`common.MapError`) if it holds anything else (`maps.taskdata.prepare_folder`)."""
    folder = os.path.join(out_dir, "taskdata")
    _remove_earlier_run(folder)
    prepare_folder(folder)
    return folder


_OWN = {"TASKDATA.XML", f"{TLG_NAME}.xml", f"{TLG_NAME}.bin"}  # the files of a run's log


def _remove_earlier_run(folder: str) -> None:
    if os.path.isdir(folder) and set(os.listdir(folder)) == _OWN:
        for name in _OWN:
            os.remove(os.path.join(folder, name))
