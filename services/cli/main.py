"""The `vrsim` command: one subcommand per use, each in its own ``services/cli/<name>.py``.

A command module defines ``HELP`` (one line), ``configure(parser)`` (adds its arguments; keep its
module-level imports light, since ``vrsim --help`` imports every command module) and ``run(args) -> int``.

Exit codes: 0 done, 2 bad input (a `common.VrsimError` or an argparse error: one line on stderr, no
traceback), 1 internal error (a bug; set ``VRSIM_DEBUG=1`` to see the traceback) or a crash inside a
user-defined controller (one line with its file and line; the traceback under ``VRSIM_DEBUG=1``), 3 a
command's own "no" on fine input, which its module returns (`vrsim run --check`: the machine cannot
apply the map, `services.cli.run.EXIT_CANNOT`; `vrsim sweep`: runs lost; `vrsim fit`: no convergence).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

# One BLAS thread per process, set before numpy loads (children inherit it; a user's own setting
# wins): vrsim's products are small (a plant's 4 x 4, a batch of loops' 16 x 17 each), and OpenBLAS's
# threads spin between calls on the cores that `vrsim run`'s other processes (SUMO's, the pictures')
# need: with them the whole command took 0.5 s longer and a tenth more CPU time.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from vrsim.common import VrsimError, __version__  # noqa: E402

# Order is the order `vrsim --help` lists them in.
COMMANDS = ("run", "compare", "sweep", "tune", "evaluate", "replay", "report", "controller", "machine",
            "paper", "map", "serve", "query", "aog", "accuracy", "calibrate", "fit")


def _available_commands(names=COMMANDS):
    """Yield (name, module) for each command module of `names` that exists."""
    for name in names:
        try:
            module = importlib.import_module(f"vrsim.services.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"vrsim.services.cli.{name}":
                continue
            raise
        yield name, module


def _build_parser(names=COMMANDS) -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The parser of `names`' commands (all of them by default: what ``vrsim --help`` lists)."""
    parser = argparse.ArgumentParser(
        prog="vrsim",
        description="Simulator for map-based variable-rate fertilizer application.",
    )
    parser.add_argument("--version", action="version", version=f"vrsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    commands = {}
    for name, module in _available_commands(names):
        cmd = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.configure(cmd)
        cmd.set_defaults(_run=module.run, command=name, _exit_at_once=getattr(module, "EXIT_AT_ONCE", False))
        commands[name] = cmd
    return parser, commands


def _parse(argv: list[str]) -> argparse.Namespace:
    """Parse the command line; exits 2 with a usage message on a bad command or option.

    A command's options and positionals may interleave (``vrsim query KEY --body F NAME=VALUE``):
    what the first pass leaves over is parsed again by the command's own parser, intermixed (a command
    with actions, ``vrsim map info``, plainly: argparse cannot intermix subcommands, and an unknown
    option there is a usage error too, exit 2).
    """
    # A known command first: only its module is imported (a tenth of a second for all of them).
    parser, commands = _build_parser((argv[0],) if argv and argv[0] in COMMANDS else COMMANDS)
    args, rest = parser.parse_known_args(argv)
    if rest:
        own = argv[argv.index(args.command) + 1:]
        command = commands[args.command]
        with_actions = any(isinstance(a, argparse._SubParsersAction) for a in command._actions)
        args = command.parse_args(own) if with_actions else command.parse_intermixed_args(own)
    return args


def console() -> None:
    """The `vrsim` executable (and ``python -m vrsim.services.cli``): `main`, then the exit."""
    sys.exit(main(leave=True))


def main(argv: list[str] | None = None, *, leave: bool = False) -> int:
    """Run the command line `argv` (default: this process's); returns the exit code.

    With `leave` (the executable's, `console`), a command whose module sets ``EXIT_AT_ONCE`` (everything
    it wrote is closed when it returns) ends the process here, without the interpreter's teardown of
    the libraries it loaded (GDAL, Arrow, PROJ: a fifth of a second of `vrsim run`)."""
    args = _parse(sys.argv[1:] if argv is None else argv)
    code = _run_command(args)
    if leave and args._exit_at_once:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except BrokenPipeError:  # `vrsim run --json | head -1`: the reader has what it wanted
                pass
        os._exit(code)
    return code


def _run_command(args: argparse.Namespace) -> int:
    """Run a parsed command; `common.VrsimError` and bugs become exit codes and one line on stderr."""
    try:
        return int(args._run(args) or 0)
    except VrsimError as exc:
        print(f"vrsim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vrsim {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception as exc:  # noqa: BLE001 - the last line of defence: a bug, not bad input
        if _user_code_error(exc):
            if os.environ.get("VRSIM_DEBUG"):
                print(exc.user_traceback, file=sys.stderr, end="")
            print(f"vrsim {args.command}: error in a user-defined controller: {exc} "
                  "(VRSIM_DEBUG=1 shows the traceback)", file=sys.stderr)
            return 1
        if os.environ.get("VRSIM_DEBUG"):
            traceback.print_exc()
        print(f"vrsim {args.command}: internal error: {type(exc).__name__}: {exc} "
              "(this is a bug; VRSIM_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


def _user_code_error(exc: BaseException) -> bool:
    """A crash inside a user's controller class (`controller.UserCodeError`: exit 1 with its file and
    line). Looked up only if that module was loaded, so ``vrsim --help`` stays light."""
    module = sys.modules.get("vrsim.controller.kinds.python")
    return module is not None and isinstance(exc, module.UserCodeError)


if __name__ == "__main__":
    console()
