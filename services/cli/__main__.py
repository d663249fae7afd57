"""``python -m vrsim.services.cli``: the `vrsim` command (how `vrsim serve all` starts its children), the same
entry as the installed script (`main.console`, with `leave`: `vrsim run` exits without the
interpreter's teardown)."""

import sys

from vrsim.services.cli.main import main

sys.exit(main(leave=True))
