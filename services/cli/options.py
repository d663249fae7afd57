"""Options that several `vrsim` commands share (not a command itself)."""

from __future__ import annotations

from vrsim.common import VrsimError, files


def warnings_as_lines(command: str) -> None:
    """Warnings (a map or a field used with a repair) as one stderr line each, ``vrsim COMMAND:
    warning: ...``, not Python's two-line format."""
    import sys
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"vrsim {command}: warning: {message}", file=sys.stderr)

    warnings.showwarning = show


def add_input_cap(parser) -> None:
    """``--max-input-mb MB``: raise the byte cap of every input format (`common.files.BYTE_CAPS`)."""
    parser.add_argument("--max-input-mb", type=float, default=None, metavar="MB",
                        help="read input files up to this size in any format (default caps: 1 MB for "
                             "TOML, 64 MB for GeoJSON/CSV/XML, 256 MB for shapefile parts, 1 GB for "
                             "GeoTIFF and zip)")


def apply_input_cap(args) -> None:
    """Raise every format's byte cap to at least ``args.max_input_mb`` (a lower one stays as it is)."""
    mb = getattr(args, "max_input_mb", None)
    if mb is None:
        return
    if not 0 < mb < 1e6:
        raise VrsimError(f"--max-input-mb {mb:g}: must be a number of megabytes in (0, 1e6)")
    floor = int(mb * files.MiB)
    files.set_byte_caps(**{kind: max(cap, floor) for kind, cap in files.BYTE_CAPS.items()})


def add_overrides(parser, help_text: str = "override a scenario key, as for vrsim run (repeatable)") -> None:
    """``--set KEY=VALUE`` (repeatable): scenario keys changed on the command line (`load_scenario`)."""
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                        help=help_text)
    parser.add_argument("--machine", metavar="FILE",
                        help="a machine file (machine_fit.toml from vrsim fit: the twin of your machine) "
                             "whose tables replace the scenario's keys they name (before --set)")


def load_scenario(args):
    """``args.scenario`` (a file or a built-in name) loaded with `overrides_of`, checked as a file's
    values are."""
    from vrsim.services.sim import scenario

    return scenario.load(args.scenario, overrides_of(args))


def overrides_of(args) -> list:
    """``--machine``'s keys, then the ``--set`` overrides, as (dotted key, value) pairs."""
    from vrsim.services.sim.overrides import parse_assignment

    machine = _machine_file(args.machine) if getattr(args, "machine", None) else []
    return [*machine, *(parse_assignment(text) for text in getattr(args, "overrides", ()))]


def _machine_file(path: str) -> list:
    """A machine file's keys as overrides, checked on the built-in default scenario first, so that a
    key or value it gets wrong is reported against the machine file, not against the scenario."""
    from vrsim.common import ScenarioError
    from vrsim.services.sim.overrides import machine_overrides
    from vrsim.services.sim.scenario import load

    overrides = machine_overrides(path)
    try:
        load(None, overrides)
    except ScenarioError as exc:
        message = str(exc).removeprefix("builtin:default: ")
        raise ScenarioError(f"{path}: {message}") from None
    return overrides
