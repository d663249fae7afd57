"""``python -m services.cli``: the `vrsim` command (how `vrsim serve all` starts its children), the same
entry as the installed script (`main.console`: `vrsim run` exits without the interpreter's teardown)."""

from services.cli.main import console

console()
