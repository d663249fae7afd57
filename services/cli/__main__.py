"""``python -m services.cli``: the `vrsim` command (how `vrsim serve all` starts its children)."""

import sys

from services.cli.main import main

sys.exit(main())
