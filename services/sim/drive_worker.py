"""The second process of a streamed run (`services.sim.streamed`): it drives the path the first
process planned in SUMO and sends what SUMO reports, part by part, while the first process controls
what has been driven so far.

``python -m vrsim.services.sim.drive_worker`` imports SUMO and the vehicle room first (nothing of the
scenario's parser, the controllers or the maps), then reads a `services.sim.drive_job.DriveJob` and
the ticks per part, pickled, on stdin; on stdout go ``("part", time_s, s_m, speed_m_s)`` for each part
(`vehicle.SumoDriver.run_parts`), then ``("done", sumo_s)`` (the drive's wall time, less the time its
parts took to hand over: waiting for room in a full pipe is the run's time, not SUMO's); or
``("error", kind, message)`` for a path that cannot be driven (``kind`` names the `common.VrsimError`
subclass). Both ends are vrsim's own processes (pickle is no format for anything else). `DriveWorker`
is the first process's end. This module imports nothing heavy itself, so that `vrsim run` can start
the worker before its own imports.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import time

# What SUMO drives before it sends (about 0.04 s of SUMO): the last part's control is what is left
# to do once SUMO ends. Any size gives the same run (`services.sim.streamed`).
PART_TICKS = 4000
# The parts SUMO may send ahead of this process (about ten): without them SUMO waits on each part's
# write while this process accounts a slow one (a pass's end), and this one then waits on SUMO (in
# `vrsim run huge`, 1.2 s of waiting on SUMO against 0.06 s with them). Linux lets a process ask for
# up to /proc/sys/fs/pipe-max-size (1 MiB by default) unprivileged; elsewhere the pipe stays as it is.
PIPE_BYTES = 1 << 20


class DriveWorker:
    """The drive's process, seen from the run: `DriveWorker()` starts it (it imports while the caller
    loads the scenario), `drive` gives it the scenario, `parts` reads what it drove, `close` ends it.
    """

    def __init__(self):
        self.started_unix, self.started_perf_s = time.time(), time.perf_counter()
        # -P: vrsim's own modules, not a `services` package in the folder the command runs in
        self.proc = subprocess.Popen([sys.executable, "-P", "-m", "vrsim.services.sim.drive_worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        _enlarge(self.proc.stdout, PIPE_BYTES)
        self.planned = self.plan_s = self.sumo_s = self._sending = None

    def drive(self, scenario, ticks_per_part: int = PART_TICKS) -> None:
        """Plan `scenario`'s path here (`services.sim.world.plan_path`: its errors are raised here) and
        start driving it, sending every `ticks_per_part` ticks; ``planned`` holds (field, path), ``plan_s``
        the time planning took."""
        from vrsim.services.sim.drive_job import DriveJob
        from vrsim.services.sim.world import plan_path

        clock = time.perf_counter()
        self.planned = plan_path(scenario)
        self.plan_s = time.perf_counter() - clock
        job = pickle.dumps((DriveJob.of(scenario, self.planned[1]), ticks_per_part),
                           protocol=pickle.HIGHEST_PROTOCOL)
        # The job is more than the pipe holds (0.3 MB for the default field, 1 MB for huge's), and the
        # worker reads it once libsumo is imported: a thread writes it, and this process goes on.
        self._sending = threading.Thread(target=_send, args=(self.proc.stdin, job), name="drive-job",
                                         daemon=True)
        self._sending.start()

    def parts(self):
        """Yield ``(time_s, s_m, speed_m_s)`` of each part as SUMO drives it; then set `sumo_s` (the
        drive's wall time in the worker, less the time its parts waited for room in the pipe). Raises the
        worker's `common.VrsimError`, or RuntimeError if it ended without a word (a bug or a kill)."""
        from vrsim.common import errors

        while True:
            try:
                kind, *body = pickle.load(self.proc.stdout)
            except (EOFError, pickle.UnpicklingError):  # gone, perhaps in the middle of a message
                raise RuntimeError("the drive worker (SUMO's process) ended before the drive did "
                                   f"(exit code {self.proc.wait()})") from None
            if kind == "part":
                yield tuple(body)
            elif kind == "done":
                (self.sumo_s,) = body
                return
            else:
                name, message = body
                cls = getattr(errors, name, None)
                if not (isinstance(cls, type) and issubclass(cls, errors.VrsimError)):
                    cls = errors.ScenarioError
                raise cls(message)

    def close(self) -> None:
        """End the worker (killed if it is still driving: the run has failed, or never began) and
        reap it."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        if self._sending is not None:   # ends once the job is written, or at the dead worker's pipe
            self._sending.join()
        for pipe in (self.proc.stdin, self.proc.stdout):
            pipe.close()


def _send(pipe, job: bytes) -> None:
    """Write `job` into `pipe` and close it; a worker gone meanwhile is left to `parts` to say."""
    try:
        pipe.write(job)
        pipe.close()
    except BrokenPipeError:   # the worker is gone (killed by `close`, or dead)
        pass


def _enlarge(pipe, size_bytes: int) -> None:
    """Ask for a `size_bytes` buffer on `pipe` (Linux); a smaller limit or another system leaves it."""
    try:
        import fcntl

        fcntl.fcntl(pipe.fileno(), fcntl.F_SETPIPE_SZ, size_bytes)
    except (ImportError, AttributeError, OSError):   # not Linux, or above the system's limit
        pass


def _serve(stdin, stdout) -> None:
    """Drive the `DriveJob` that arrives on `stdin`, writing the messages above to `stdout`."""
    from vrsim.vehicle.driver import import_libsumo

    import_libsumo()  # the heaviest import, done while the caller loads the scenario
    from vrsim.common import VrsimError
    from vrsim.services.sim import drive_job  # noqa: F401 - the job's classes, before it arrives

    def send(message) -> None:
        pickle.dump(message, stdout, protocol=pickle.HIGHEST_PROTOCOL)
        stdout.flush()

    try:
        job, ticks = pickle.load(stdin)
    except EOFError:  # the caller gave up before the drive (a bad scenario, --check)
        return
    try:
        clock, handing_s = time.perf_counter(), 0.0
        with job.driving() as driver:
            for part in driver.run_parts(ticks):
                handed = time.perf_counter()
                send(("part", *part))
                handing_s += time.perf_counter() - handed
        # SUMO's own time: less handing the parts over (pickled in microseconds; the rest is waiting
        # for room in a full pipe, the run's time, not SUMO's)
        send(("done", time.perf_counter() - clock - handing_s))
    except VrsimError as exc:
        send(("error", type(exc).__name__, str(exc)))


if __name__ == "__main__":
    try:
        _serve(sys.stdin.buffer, sys.stdout.buffer)
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole group; the caller is gone
        pass
    os._exit(0)  # every message is flushed and SUMO closed: skip the interpreter's teardown
