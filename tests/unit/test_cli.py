import subprocess

from tests.conftest import VRSIM


def _vrsim(*args):
    return subprocess.run([VRSIM, *args], capture_output=True, text=True, timeout=120)


def test_help_lists_subcommands():
    p = _vrsim("--help")
    assert p.returncode == 0
    assert "COMMAND" in p.stdout


def test_version():
    p = _vrsim("--version")
    assert p.returncode == 0 and p.stdout.startswith("vrsim ")


def test_unknown_subcommand_exits_2_without_traceback():
    p = _vrsim("no-such-command")
    assert p.returncode == 2
    assert "Traceback" not in p.stderr + p.stdout
    assert "invalid choice" in p.stderr


def test_bad_option_exits_2():
    p = _vrsim("--no-such-option")
    assert p.returncode == 2
    assert "Traceback" not in p.stderr


def test_options_and_parameters_may_interleave():
    from vrsim.services.cli.main import _parse

    args = _parse(["query", "scenario/start", "--body", "f.toml", "source=f.toml", "base_dir=/x"])
    assert args.command == "query" and args.body == "f.toml"
    assert args.params == ["source=f.toml", "base_dir=/x"]
    args = _parse(["run", "--json", "s.toml", "--quiet"])
    assert args.scenario == "s.toml" and args.json and args.quiet
