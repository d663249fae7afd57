"""The built-in controller kinds; importing this package registers them (`controller.registry`)."""

from vrsim.controller.kinds import aog_pi, ff_pi, fuzzy_pid, ideal, pid, python, smith  # noqa: F401
