"""The second process of a streamed run (`services.sim.streamed`): it plans the scenario's path, drives
it in SUMO and sends what SUMO reports, part by part, while the first process controls what has been
driven so far.

``python -m services.sim.drive_worker``: the scenario and the ticks per part arrive pickled on stdin;
on stdout go ``("part", time_s, s_m, speed_m_s)`` for each part (`vehicle.SumoDriver.run_parts`),
then ``("done", path_length_m, sumo_s)``; or ``("error", kind, message)`` for a scenario that cannot be
driven (``kind`` names the `common.VrsimError` subclass). Both ends are vrsim's own processes (pickle is
no format for anything else). It imports what planning and SUMO need, not the controller or metrics.
"""

from __future__ import annotations

import os
import pickle
import sys
import time


def serve(stdin, stdout) -> None:
    """Drive the scenario that arrives on `stdin`, writing the messages above to `stdout`."""
    from common import VrsimError
    from services.sim.world import driving, plan_path

    def send(message) -> None:
        pickle.dump(message, stdout, protocol=pickle.HIGHEST_PROTOCOL)
        stdout.flush()

    scenario, ticks = pickle.load(stdin)
    try:
        _, path = plan_path(scenario)
        clock = time.perf_counter()
        with driving(scenario, path) as driver:
            for part in driver.run_parts(ticks):
                send(("part", *part))
        send(("done", path.length_m, time.perf_counter() - clock))
    except VrsimError as exc:
        send(("error", type(exc).__name__, str(exc)))


if __name__ == "__main__":
    try:
        serve(sys.stdin.buffer, sys.stdout.buffer)
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole group; the caller is gone
        pass
    os._exit(0)  # every message is flushed and SUMO closed: skip the interpreter's teardown
