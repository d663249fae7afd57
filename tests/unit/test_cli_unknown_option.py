"""Every subcommand, and every action of `map`, `controller` and `serve`, refuses one unknown option
with exit 2 and one error line after its usage, never a traceback."""

import argparse
import subprocess

import pytest

from tests.conftest import VRSIM
from vrsim.services.cli.main import COMMANDS, _build_parser, _parse


def _value(action: argparse.Action) -> list[str]:
    """A value argparse accepts for `action` (its first choice, else a number: it passes any type=)."""
    if action.nargs == 0:
        return []
    value = str(next(iter(action.choices))) if action.choices else "1"
    return [value] * (1 if action.nargs in (None, "?", "*", "+", argparse.REMAINDER) else action.nargs)


def _required(parser: argparse.ArgumentParser) -> list[str]:
    """The least command line `parser` takes: its required options and positionals, each with a value."""
    words = []
    for action in parser._actions:
        if action.option_strings and action.required:
            words += [action.option_strings[0], *_value(action)]
        elif not action.option_strings and not isinstance(action, argparse._SubParsersAction):
            words += _value(action)
    return words


def _command_lines() -> list[list[str]]:
    """One line per subcommand and per action of a subcommand with actions (`map info`, ...), and per
    choice of an ACTION/SERVICE positional (`controller analyze`, `serve all`, ...)."""
    _, commands = _build_parser(COMMANDS)
    lines = []
    for name, parser in commands.items():
        actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if actions:
            for action_name, sub in actions[0].choices.items():
                lines.append([name, action_name, *_required(sub)])
            continue
        choice = next((a for a in parser._actions if not a.option_strings and a.choices), None)
        for value in choice.choices if choice else [None]:
            line = [name, *_required(parser)]
            if value is not None:
                line[line.index(str(next(iter(choice.choices))))] = value
            lines.append(line)
    return lines


LINES = _command_lines()


def test_every_subcommand_and_action_is_listed():
    names = {line[0] for line in LINES}
    assert names == set(COMMANDS)
    assert {line[1] for line in LINES if line[0] == "map"} == {"info", "sample", "convert", "plot",
                                                                     "boundary"}
    assert len([line for line in LINES if line[0] == "serve"]) > 3


@pytest.mark.parametrize("line", LINES, ids=[" ".join(line[:2]) for line in LINES])
def test_an_unknown_option_is_a_usage_error(line, capsys):
    with pytest.raises(SystemExit) as exit_:
        _parse([*line, "--bogus"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    errors = [text for text in err.splitlines() if ": error: " in text]
    assert errors == [f"vrsim {line[0]}: error: unrecognized arguments: --bogus"], err
    assert err.startswith("usage: vrsim ")


@pytest.mark.parametrize("line", [["map", "info", "f.tif"], ["map", "convert", "f.tif", "out.geojson"],
                                  ["controller", "analyze"], ["run"]])
def test_the_executable_says_so_without_a_traceback(line):
    p = subprocess.run([VRSIM, *line, "--bogus"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines()[-1] == f"vrsim {line[0]}: error: unrecognized arguments: --bogus"
