"""The SUMO road network of a coverage path: one single-lane edge per segment, built by netconvert.

Each path segment becomes an edge whose shape is the segment's polyline (thinned to points at least
1 m apart: `NETCONVERT_OPTIONS`) and whose ``length`` is the planned length (so SUMO's lane position
is planned arc length); a lead-out edge lets the tractor's front drive on while the implement, behind
it, finishes the last segment. Plain XML nodes and edges are converted by the ``netconvert`` of the
eclipse-sumo package, without internal junction lanes, and the result is cached under a hash of
everything that goes into it.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass

import numpy as np

from vrsim.common.errors import VehicleError

NETCONVERT_OPTIONS = (
    "--no-internal-links", "true",           # the tractor passes straight from lane to lane
    "--offset.disable-normalization", "true",  # keep field CRS coordinates
    "--no-turnarounds", "true",
    "--junctions.limit-turn-speed", "-1",     # edge speeds alone set the speed in turns
    "--geometry.remove", "false",
    # Every step SUMO walks the lane's shape from its start to place the vehicle (its x, y and angle,
    # which vrsim does not read: the driver takes lane positions). Turns are planned every 0.25 m:
    # thinned to 1 m, a tick of the default scenario costs 4.5 % fewer instructions. Lengths, speeds
    # and connections, all that moves the tractor, stay (the drive is the same to the bit).
    "--geometry.min-dist", "1",
    "--no-warnings", "true",
    "--verbose", "false",
)
_FORMAT = "vrsim-net-1"  # bump when the XML written here changes meaning


@dataclass(frozen=True)
class Network:
    """A built network.

    Attributes
    ----------
    net_file : str
        Path of the ``.net.xml``.
    edge_ids : tuple of str
        Route edges in driving order: one per path segment, then the lead-out edge.
    edge_length_m : ndarray
        Planned length of each route edge, m.
    """

    net_file: str
    edge_ids: tuple
    edge_length_m: np.ndarray


def import_sumo_module(name: str):
    """SUMO's Python module `name` (``"sumo"``, ``"libsumo"``), imported without its side effect on
    the process's PROJ settings.

    Imported, both point ``PROJ_LIB`` and ``PROJ_DATA`` at SUMO's own proj.db (an older layout) when
    neither is set; every CRS look-up of rasterio (and of GDAL through pyogrio) in the same process
    after it then fails ("proj.db ... comes from another PROJ installation"), and so do the processes
    it starts, which inherit the variables. vrsim's SUMO networks are in plain metres with no
    projection, so SUMO needs no PROJ data: the variables are put back as they were.
    """
    unset = not os.environ.get("PROJ_LIB") and not os.environ.get("PROJ_DATA")
    module = importlib.import_module(name)
    if unset:
        os.environ.pop("PROJ_LIB", None)
        os.environ.pop("PROJ_DATA", None)
    return module


def find_netconvert() -> str:
    """Path of the ``netconvert`` shipped with eclipse-sumo (or beside the Python executable)."""
    candidates = []
    try:
        sumo = import_sumo_module("sumo")
        candidates.append(os.path.join(sumo.SUMO_HOME, "bin", "netconvert"))
    except ImportError:
        pass
    candidates.append(os.path.join(os.path.dirname(sys.executable), "netconvert"))
    for exe in candidates:
        if os.path.isfile(exe) and os.access(exe, os.X_OK):
            return exe
    found = shutil.which("netconvert")
    if found:
        return found
    raise VehicleError(f"netconvert: not found (looked at {', '.join(candidates)} and PATH); "
                       "install eclipse-sumo")


def default_cache_dir() -> str:
    """``$VRSIM_CACHE/sumo`` if set, else ``~/.cache/vrsim/sumo``."""
    root = os.environ.get("VRSIM_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "vrsim")
    return os.path.join(root, "sumo")


def build_network(segments, speeds_m_s, lead_out_m: float, cache_dir: str | None = None,
                  netconvert: str | None = None) -> Network:
    """Build (or fetch from the cache) the network of a path.

    Parameters
    ----------
    segments : sequence of `vehicle.coverage.Segment`
        The path, consecutive segments joined end to start.
    speeds_m_s : sequence of float
        Speed limit of each segment's edge, m/s.
    lead_out_m : float
        Length of the straight edge appended after the last segment, m.
    cache_dir : str, optional
        Where built networks are kept (default `default_cache_dir`).
    netconvert : str, optional
        The netconvert executable (default `find_netconvert`).

    Raises
    ------
    VehicleError
        netconvert missing or failing, or an unwritable cache directory.
    """
    shapes = [np.asarray(seg.xy, dtype=float) for seg in segments]
    last = shapes[-1]
    direction = (last[-1] - last[-2]) / np.hypot(*(last[-1] - last[-2]))
    shapes.append(np.array([last[-1], last[-1] + lead_out_m * direction]))
    speeds = [float(v) for v in speeds_m_s] + [float(max(speeds_m_s))]
    lengths = np.array([np.hypot(*np.diff(xy, axis=0).T).sum() for xy in shapes])
    nodes_xml, edges_xml = _plain_xml(shapes, speeds, lengths)
    edge_ids = tuple(f"e{i}" for i in range(len(shapes)))

    inputs = [_FORMAT, _sumo_version(), " ".join(NETCONVERT_OPTIONS), nodes_xml, edges_xml]
    key = hashlib.sha256("\n".join(inputs).encode()).hexdigest()[:24]
    cache_dir = cache_dir or default_cache_dir()
    net_file = os.path.join(cache_dir, f"{key}.net.xml")
    if not _complete(net_file):
        _convert(nodes_xml, edges_xml, net_file, netconvert or find_netconvert())
    return Network(net_file, edge_ids, lengths)


def _complete(net_file: str) -> bool:
    """True if ``net_file`` exists and ends its root element. SUMO can crash the whole process on a
    truncated network, so a damaged cache entry is rebuilt rather than loaded."""
    try:
        with open(net_file, "rb") as f:
            f.seek(max(0, os.path.getsize(net_file) - 64))
            return b"</net>" in f.read()
    except OSError:
        return False


def _sumo_version() -> str:
    """The installed eclipse-sumo version (part of the cache key: a new netconvert rebuilds)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-sumo")
    except PackageNotFoundError:
        return "unknown"


def _plain_xml(shapes, speeds, lengths):
    points = [shapes[0][0]] + [xy[-1] for xy in shapes]
    nodes = "\n".join(f'  <node id="n{i}" x="{p[0]:.4f}" y="{p[1]:.4f}" type="priority"/>'
                      for i, p in enumerate(points))
    edges = []
    for i, (xy, v, length) in enumerate(zip(shapes, speeds, lengths, strict=True)):
        shape = " ".join(f"{x:.4f},{y:.4f}" for x, y in xy)
        edges.append(f'  <edge id="e{i}" from="n{i}" to="n{i + 1}" priority="1" numLanes="1" '
                     f'speed="{v:.4f}" length="{length:.4f}" spreadType="center" shape="{shape}"/>')
    return (f"<nodes>\n{nodes}\n</nodes>\n", "<edges>\n" + "\n".join(edges) + "\n</edges>\n")


def _convert(nodes_xml: str, edges_xml: str, net_file: str, netconvert: str) -> None:
    try:
        os.makedirs(os.path.dirname(net_file), exist_ok=True)
    except OSError as exc:
        raise VehicleError(f"SUMO cache directory {os.path.dirname(net_file)}: {exc.strerror}") from None
    with tempfile.TemporaryDirectory(prefix="vrsim-net-") as tmp:
        nod, edg = os.path.join(tmp, "path.nod.xml"), os.path.join(tmp, "path.edg.xml")
        with open(nod, "w", encoding="utf-8") as f:
            f.write(nodes_xml)
        with open(edg, "w", encoding="utf-8") as f:
            f.write(edges_xml)
        out = os.path.join(tmp, "path.net.xml")
        cmd = [netconvert, "-n", nod, "-e", edg, "-o", out, *NETCONVERT_OPTIONS]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise VehicleError(f"netconvert {netconvert}: could not run: {exc}") from None
        if proc.returncode != 0 or not os.path.isfile(out):
            msg = " ".join((proc.stderr or proc.stdout or "no output").split())[:300]
            raise VehicleError(f"netconvert {netconvert}: failed (exit {proc.returncode}): {msg}")
        # Atomic publish: a concurrent run sees either no file or a complete one.
        tmp_final = f"{net_file}.{os.getpid()}.tmp"
        try:
            shutil.move(out, tmp_final)
            os.replace(tmp_final, net_file)
        except OSError as exc:
            raise VehicleError(f"SUMO cache directory {os.path.dirname(net_file)}: cannot store the "
                               f"network: {exc.strerror}") from None
