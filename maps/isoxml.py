"""ISO 11783-10 (ISOXML) TASKDATA prescription grids: read grid types 1 and 2, write type 2.

The ``GRD`` element of a ``TSK`` (attributes per ISO 11783-10):

====  ==========================  =========================================================
A     GridMinimumNorthPosition    latitude of the grid's south edge, WGS84 degrees
B     GridMinimumEastPosition     longitude of the grid's west edge, WGS84 degrees
C     GridCellNorthSize           cell height, degrees
D     GridCellEastSize            cell width, degrees
E     GridMaximumColumn           number of columns
F     GridMaximumRow              number of rows
G     Filename                    binary file name without extension (``GRD00001`` -> .BIN)
H     Filelength                  binary file length in bytes (optional; some writers get it wrong)
I     GridType                    1: one byte per cell naming a TZN; 2: int32 LE per PDV per cell
J     TreatmentZoneCode           type 2: the TZN whose PDV list says what each cell's values are
====  ==========================  =========================================================

Cells run east along a row; rows run north from the south-west corner, so the file's first row is the
grid's south row (vrsim's row 0 is north: the rows are flipped on reading and writing). The rate is
the process data value of DDI 6 (setpoint mass per area application rate) in mg/m^2; 1 mg/m^2 = 0.01
kg/ha; a grid without DDI 6 is read by DDI 1 (setpoint volume per area, 0.01 mm^3/m^2), in L/ha.
"""

from __future__ import annotations

import io
import os
import posixpath
import warnings
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
from affine import Affine

from vrsim.common import MapError, __version__, files
from vrsim.maps import ddi as DDI
from vrsim.maps.crs import WGS84
from vrsim.maps.ddi import KG_HA_PER_MG_M2, NAMES, ddi_list
from vrsim.maps.grid import DEFAULT_MAX_CELLS, Grid, check_size
from vrsim.maps.units import map_unit
from vrsim.maps.warn import MapWarning


class TaskdataFolder:
    """The TASKDATA's files, from a folder or a zip archive; names matched case-insensitively."""

    def __init__(self, path: str):
        self.path = path
        is_dir = os.path.isdir(path)
        if not is_dir:
            files.check_file(path, error=MapError)  # before is_zipfile opens it: a FIFO would block
        if not is_dir and zipfile.is_zipfile(path):
            self._zip = files.open_zip(path, MapError)
            names = [n for n in self._zip.namelist() if not n.endswith("/")]
            xmls = [n for n in names if posixpath.basename(n).upper() == "TASKDATA.XML"]
            if not xmls:
                self.close()
                raise MapError(f"{path}: the zip archive holds no TASKDATA.XML")
            self.xml_name = min(xmls, key=len)  # the shallowest one
            self._dir = posixpath.dirname(self.xml_name)
            self._names = {posixpath.basename(n).upper(): n for n in names
                           if posixpath.dirname(n) == self._dir}
        else:
            self._zip = None
            self.xml_name = path
            if is_dir:
                found = [os.path.join(d, n) for d in (path, os.path.join(path, "TASKDATA"))
                         if os.path.isdir(d) for n in os.listdir(d) if n.upper() == "TASKDATA.XML"]
                if not found:
                    raise MapError(f"{path}: the folder holds no TASKDATA.XML")
                self.xml_name = found[0]
            self._dir = os.path.dirname(os.path.abspath(self.xml_name))
            self._names = {n.upper(): os.path.join(self._dir, n) for n in os.listdir(self._dir)}

    def __enter__(self) -> TaskdataFolder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the zip archive (a folder holds nothing open)."""
        if self._zip is not None:
            self._zip.close()

    def read_xml(self) -> bytes:
        return self._read(self.xml_name, files.cap_for("xml"))

    def size(self, name: str) -> int | None:
        member = self._names.get(name.upper())
        if member is None:
            return None
        return self._zip.getinfo(member).file_size if self._zip else os.path.getsize(member)

    def read(self, name: str, limit: int) -> bytes:
        return self._read(self._names[name.upper()], limit)

    def _read(self, member: str, limit: int) -> bytes:
        """A member of the archive or a file of the folder, regular and within ``limit`` bytes."""
        if self._zip:
            return files.read_member(self._zip, member, self.path, MapError, limit)
        return files.read_bytes(member, error=MapError, limit=limit)


def typed_attr(el, key: str, kind, where: str, required: bool = True):
    """The XML attribute `key` of element `el` as `kind` (a type, or "hex": a hexadecimal DDI).

    Missing: None, or a `MapError` naming `where`, the element and the key if `required`; a value
    that does not convert is a `MapError` too (the TASKDATA reader's and the TimeLog reader's messages).
    """
    raw = el.get(key)
    if raw is None:
        if required:
            raise MapError(f"{where}: {el.tag} has no attribute {key}")
        return None
    try:
        return int(raw, 16) if kind == "hex" else kind(raw)
    except ValueError:
        raise MapError(f"{where}: {el.tag} attribute {key}={files.shown(raw)} is not a valid "
                       f"{'hexadecimal DDI' if kind == 'hex' else kind.__name__}") from None


def _zone_values(tzn, where: str) -> list[tuple[int, int, str | None]]:
    """(DDI, value, product id) of each PDV of a TZN, in file order."""
    return [(typed_attr(p, "A", "hex", where), typed_attr(p, "B", int, where), p.get("C"))
            for p in tzn.findall("PDV")]


def read_isoxml(path: str, max_cells: int | None = DEFAULT_MAX_CELLS, product: str | None = None,
                unit: str | None = None) -> Grid:
    """Read the prescription grid of a TASKDATA (folder, TASKDATA.XML or .zip) into a `Grid` (WGS84).

    `product` (a PDT's id ``PDT2`` or its name) chooses among the rates of a grid with several
    products; without it such a grid is refused, listing them (`MapError`): none is chosen silently.
    The grid's DDI states the unit (DDI 0006, mass per area: read in kg/ha; else DDI 0001, volume per
    area: in L/ha); a `unit` given must agree with it.
    """
    with TaskdataFolder(path) as folder:
        grid = _read_taskdata(folder, path, max_cells, product)
    map_unit(path, grid.unit, unit, "its DDI")
    return grid


# The rate DDIs a grid is read by, in this order: (the unit of its values, vrsim's unit, factor to it).
_GRID_RATES = {DDI.SETPOINT_MASS_PER_AREA: ("mg/m^2", "kg/ha", DDI.KG_HA_PER_MG_M2),
               DDI.SETPOINT_VOLUME_PER_AREA: ("0.01 mm^3/m^2", "L/ha", DDI.L_HA_PER_VOLUME_COUNT)}


def _rate_ddi(ddis, where: str, what: str) -> int:
    """The DDI a grid's rates are read by: 0006 if `what` holds it, else 0001; refused with neither."""
    found = next((d for d in _GRID_RATES if d in ddis), None)
    if found is None:
        raise MapError(f"{where}: {what} DDI {ddi_list(sorted(ddis)) or 'none'}; vrsim needs DDI 0006 "
                       f"({NAMES[6]}) or 0001 ({NAMES[1]})")
    return found


def parse_xml(data: bytes, where: str, name: str, root_tag: str):
    """Parse an ISOXML file's bytes safely (`common.files.parse_xml`) and check its root.

    `where` is the TASKDATA path and `name` the file within it, for messages.
    """
    root = files.parse_xml(data, f"{where}: {name}", MapError)
    if root.tag != root_tag:
        raise MapError(f"{where}: {name}: root element is {files.shown(root.tag)}, not <{root_tag}>")
    return root


def _read_taskdata(folder: TaskdataFolder, path: str, max_cells: int | None, product: str | None) -> Grid:
    where = path
    root = parse_xml(folder.read_xml(), where, "TASKDATA.XML", "ISO11783_TaskData")
    tasks = [t for t in root.iter("TSK") if t.find("GRD") is not None]
    if not tasks:
        raise MapError(f"{where}: no task (TSK) has a grid (GRD): nothing to read as a prescription map")
    if len(tasks) > 1:
        warnings.warn(f"{where}: {len(tasks)} tasks have grids; reading the first, {tasks[0].get('A')}",
                      MapWarning, stacklevel=3)
    task = tasks[0]
    grd = task.find("GRD")
    south, west = typed_attr(grd, "A", float, where), typed_attr(grd, "B", float, where)
    dlat, dlon = typed_attr(grd, "C", float, where), typed_attr(grd, "D", float, where)
    cols, rows = typed_attr(grd, "E", int, where), typed_attr(grd, "F", int, where)
    name, declared = grd.get("G"), typed_attr(grd, "H", int, where, required=False)
    gtype, zone_code = typed_attr(grd, "I", int, where), typed_attr(grd, "J", int, where, required=False)
    if not (-90.0 <= south <= 90.0 and -180.0 <= west <= 180.0):
        raise MapError(f"{where}: GRD A={south!r}, B={west!r} is not a WGS84 latitude/longitude")
    for key, value in (("C", dlat), ("D", dlon)):
        if not (0.0 < value <= 1.0):
            raise MapError(f"{where}: GRD {key}={value!r}: a cell size must be in (0, 1] degree")
    if not (south + rows * dlat <= 90.0 + 1e-9):
        raise MapError(f"{where}: GRD reaches north of the pole ({rows} rows of {dlat} degree from {south})")
    check_size(rows, cols, max_cells, f"{where}: GRD E={cols}, F={rows}")
    if gtype not in (1, 2):
        raise MapError(f"{where}: GRD I={gtype}: grid type must be 1 or 2")
    if not name:
        raise MapError(f"{where}: GRD has no file name (attribute G)")
    if folder.size(name + ".BIN") is None:
        raise MapError(f"{where}: the grid's binary file {name}.BIN (GRD G={name!r}) is missing beside "
                       "TASKDATA.XML")
    zones = {typed_attr(z, "A", int, where): _zone_values(z, where) for z in task.findall("TZN")}

    if gtype == 2:
        if zone_code is None or zone_code not in zones:
            raise MapError(f"{where}: grid type 2 needs GRD J naming a defined treatment zone; "
                           f"J={zone_code}, zones defined: {sorted(zones)}")
        layers = zones[zone_code]
        ddis = [d for d, _, _ in layers]
        rate_ddi = _rate_ddi(ddis, where, f"treatment zone {zone_code} holds")
        rate_layers = [i for i, d in enumerate(ddis) if d == rate_ddi]
        product_ref = _choose_product(root, [layers[i][2] for i in rate_layers], product, where)
        layer = next(i for i in rate_layers if layers[i][2] == product_ref)
        cell_bytes = 4 * len(layers)
    else:
        rate_ddi = _rate_ddi({d for values in zones.values() for d, _, _ in values}, where,
                             "the treatment zones hold")
        cell_bytes = 1
    iso_unit, unit, factor = _GRID_RATES[rate_ddi]
    data = _read_binary(folder, name, rows * cols * cell_bytes, declared, where,
                        f"{cols} columns x {rows} rows x {cell_bytes} byte{'s' * (cell_bytes > 1)} per cell")
    if gtype == 2:
        raw = np.frombuffer(data, dtype="<i4").reshape(rows, cols, len(layers))[..., layer]
        if (raw < 0).any():
            r, c = np.argwhere(raw < 0)[0]
            raise MapError(f"{where}: negative rate {files.shown(int(raw[r, c]))} {iso_unit} in {name} at "
                           f"row {r} (from south), column {c}")
        rates = raw.astype(np.float64) * factor
    else:
        codes = np.frombuffer(data, dtype=np.uint8).reshape(rows, cols)
        refs = [ref for values in zones.values() for d, _, ref in values if d == rate_ddi]
        product_ref = _choose_product(root, refs, product, where) if refs else None
        rates = _type1_rates(codes, zones, product_ref, where, rate_ddi)
    transform = Affine(dlon, 0.0, west, 0.0, -dlat, south + rows * dlat)
    return Grid(rates[::-1], transform, WGS84, product=_product_name(root, product_ref), source=path,
                format="isoxml", unit=unit)


def _read_binary(folder: TaskdataFolder, name: str, expected: int, declared, where: str, shape: str) -> bytes:
    fname = name + ".BIN"
    size = folder.size(fname)
    if size != expected:
        raise MapError(f"{where}: {fname} has {size:,} bytes but the declared grid ({shape}) needs "
                       f"{expected:,}: {'truncated' if size < expected else 'oversized'} or mis-declared")
    if declared is not None and declared != size:
        warnings.warn(f"{where}: GRD H (Filelength) says {declared:,} bytes but {fname} has {size:,}, as "
                      "its grid needs; reading it", MapWarning, stacklevel=4)
    return folder.read(fname, expected)


def _type1_rates(codes: np.ndarray, zones: dict, product_ref: str | None, where: str,
                 rate_ddi: int) -> np.ndarray:
    """Rates of `product_ref` from per-cell treatment-zone codes: a 256-entry table, NaN for zones
    without its rate DDI (`_GRID_RATES`)."""
    iso_unit, _, factor = _GRID_RATES[rate_ddi]
    table = np.full(256, np.nan)
    for code, values in zones.items():
        for ddi, value, product in values:
            if ddi == rate_ddi and product == product_ref and 0 <= code <= 255:
                if value < 0:
                    raise MapError(f"{where}: treatment zone {code} has a negative rate "
                                   f"{files.shown(value)} {iso_unit}")
                table[code] = value * factor
    used = np.unique(codes)
    undefined = [int(c) for c in used if np.isnan(table[c])]
    if undefined:
        warnings.warn(f"{where}: grid cells name treatment zones {undefined} that have no DDI {rate_ddi:04X} "
                      "rate in TASKDATA.XML; those cells are nodata", MapWarning, stacklevel=4)
    return table[codes]


def _choose_product(root, refs: list, product: str | None, where: str) -> str | None:
    """The product reference (PDV C) among `refs` (in file order) that `product` names, by id (``PDT2``)
    or name (case-insensitive); without `product`, the only one. MapError listing them otherwise."""
    products = list(dict.fromkeys(refs))
    listed = ", ".join(f"{ref} {_product_name(root, ref)!r}" if ref else "(no product)" for ref in products)
    if product is None:
        if len(products) > 1:
            raise MapError(f"{where}: the grid holds the rates of {len(products)} products: {listed}; "
                           "choose one with --product NAME|PDTn")
        return products[0]
    wanted = product.strip().lower()
    for ref in products:
        if ref and wanted in (ref.lower(), _product_name(root, ref).lower()):
            return ref
    raise MapError(f"{where}: no product {product!r} in the grid; products: {listed}")


def _product_name(root, ref: str | None) -> str:
    if ref:
        for pdt in root.iter("PDT"):
            if pdt.get("A") == ref:
                return pdt.get("B") or ""
    return ""


def write_isoxml(grid: Grid, path: str) -> None:
    """Write a grid as TASKDATA with a type-2 grid of DDI 6 (mg/m^2, int32).

    `path` ending in ``.zip`` gives an archive ``TASKDATA/TASKDATA.XML`` + ``TASKDATA/GRD00001.BIN``;
    otherwise `path` is the TASKDATA folder (created if missing) or the ``TASKDATA.XML`` in it. A
    folder that already holds a TASKDATA.XML is refused (its export would break); grid files of
    other exports in it are left alone: the grid takes the first free ``GRDnnnnn`` name. A grid not
    in WGS84 is first reprojected (`Grid.reproject`, same cell size in metres). Type 2 has no nodata
    value: nodata cells are written as 0 (apply nothing), with a warning. Rates are rounded to
    0.01 kg/ha. Only rates in kg/ha are written: a map of differences (an error map) or of another
    unit is refused.
    """
    if grid.quantity != "rate" or grid.unit != "kg/ha":
        what = "differences of rates" if grid.quantity != "rate" else "rates"
        raise MapError(f"{path}: an ISOXML prescription holds rates in kg/ha; {grid.source or 'the grid'} "
                       f"holds {what} in {grid.unit}")
    folder = None if path.lower().endswith(".zip") else _taskdata_folder(path)
    if not (grid.crs.is_geographic and grid.crs == WGS84):
        grid = grid.reproject(WGS84)
    rates = grid.rates_kg_ha
    nodata = np.isnan(rates)
    if nodata.any():
        warnings.warn(f"{path}: ISOXML grid type 2 has no nodata value: {int(nodata.sum())} nodata cells are "
                      "written as rate 0", MapWarning, stacklevel=2)
    mg = np.rint(np.where(nodata, 0.0, rates) / KG_HA_PER_MG_M2)
    if mg.max() > np.iinfo(np.int32).max:
        raise MapError(f"{path}: rate {np.nanmax(rates)} kg/ha does not fit an ISOXML int32 in mg/m^2")
    binary = mg[::-1].astype("<i4").tobytes()
    if folder is None:
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
            z.writestr("TASKDATA/TASKDATA.XML", _taskdata_xml(grid, len(binary), "GRD00001"))
            z.writestr("TASKDATA/GRD00001.BIN", binary)
        return
    os.makedirs(folder, exist_ok=True)
    name = _free_grid_name(folder)
    # Exclusive creation: never replace a file, even one that appeared since the checks.
    for fname, data in ((name + ".BIN", binary), ("TASKDATA.XML", _taskdata_xml(grid, len(binary), name))):
        try:
            with open(os.path.join(folder, fname), "xb") as f:
                f.write(data)
        except FileExistsError:
            raise MapError(f"{path}: {fname} already exists in {folder}; vrsim does not overwrite") from None


def _taskdata_folder(path: str) -> str:
    """The folder an ISOXML TASKDATA is written to: `path` itself, or the folder of its TASKDATA.XML.

    Refuses other ``.xml`` names (the standard names the file TASKDATA.XML) and a folder that
    already holds a TASKDATA.XML.
    """
    name = os.path.basename(os.path.normpath(path))
    if name.upper() == "TASKDATA.XML":
        folder = os.path.dirname(os.path.abspath(path))
    elif name.lower().endswith(".xml"):
        raise MapError(f"{path}: ISOXML is written as a TASKDATA folder: give the folder (e.g. out/TASKDATA) "
                       f"or out/TASKDATA/TASKDATA.XML, the standard's file name, not {name}")
    else:
        folder = os.path.abspath(path)
    if os.path.isdir(folder) and any(n.upper() == "TASKDATA.XML" for n in os.listdir(folder)):
        raise MapError(f"{path}: {folder} already holds a TASKDATA.XML; vrsim does not overwrite an ISOXML "
                       "export (its grid files belong to it): choose another folder")
    return folder


def _free_grid_name(folder: str) -> str:
    """The first ``GRDnnnnn`` without a .BIN in `folder` (any letter case)."""
    taken = {n.upper() for n in os.listdir(folder)}
    return next(f"GRD{i:05d}" for i in range(1, 100_000) if f"GRD{i:05d}.BIN" not in taken)


def _taskdata_xml(grid: Grid, length: int, name: str) -> bytes:
    root = ET.Element("ISO11783_TaskData", VersionMajor="4", VersionMinor="2",
                      ManagementSoftwareManufacturer="vrsim", ManagementSoftwareVersion=__version__,
                      DataTransferOrigin="1")
    task = ET.SubElement(root, "TSK", A="TSK1", B="vrsim prescription", G="1")
    zone = ET.SubElement(task, "TZN", A="1", B="prescription")
    pdv = {"A": "0006", "B": "0", "E": "VPN1"}
    if grid.product:
        pdv["C"] = "PDT1"
    ET.SubElement(zone, "PDV", pdv)
    west, south, _, _ = grid.bounds
    dx, dy = grid.cell_size
    ET.SubElement(task, "GRD", A=repr(south), B=repr(west), C=repr(dy), D=repr(dx), E=str(grid.cols),
                  F=str(grid.rows), G=name, H=str(length), I="2", J="1")
    if grid.product:
        ET.SubElement(root, "PDT", A="PDT1", B=grid.product)
    ET.SubElement(root, "VPN", A="VPN1", B="0", C="0.01", D="2", E="kg/ha")
    ET.indent(root)
    out = io.BytesIO()
    ET.ElementTree(root).write(out, encoding="utf-8", xml_declaration=True)
    return out.getvalue()
