"""A second process that draws a run's pictures while the first writes the other files.

`vrsim run` starts it (`PlotWorker.start`) before it simulates, so its matplotlib import (a third of a
second or more) overlaps the simulation on another core; after the run it draws map.png and
timeseries.png while the run's process writes the GeoTIFFs, track.csv and the TimeLog. A process, not
a thread: drawing holds the GIL.

The worker is ``python -m services.outputs.plot_worker``: jobs (drawing function's name, picture, path)
arrive pickled on its stdin and one reply per job goes back on its stdout, in order. Both ends are
vrsim's own processes (pickle is no format for anything else). It imports only numpy and matplotlib
(no multiprocessing start-up that re-imports the caller's main module).
"""

from __future__ import annotations

import os
import pickle
import queue
import subprocess
import sys
import threading

# What a job may ask for, from services.outputs.plots.
DRAWINGS = ("draw_maps", "draw_sections", "draw_timeseries")


class PlotWorker:
    """The worker process, seen from the caller: `start`, `submit` jobs, `result` of each in order,
    `close`."""

    def __init__(self):
        self.proc = None
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()   # pickled jobs; None ends them
        self._writer: threading.Thread | None = None

    def start(self) -> PlotWorker:
        self.proc = subprocess.Popen([sys.executable, "-m", "services.outputs.plot_worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        return self

    def submit(self, drawing: str, picture, path: str) -> None:
        """Ask for `drawing` (one of `DRAWINGS`) of `picture` into `path`; returns at once.

        A picture is megabytes and the pipe holds 64 KB: written here, the next job would wait for
        the worker to finish drawing the last. A thread writes the jobs in order instead."""
        if self._writer is None:
            self._writer = threading.Thread(target=self._write_jobs, name="plot-jobs", daemon=True)
            self._writer.start()
        self._jobs.put(pickle.dumps((drawing, picture, path), protocol=pickle.HIGHEST_PROTOCOL))

    def _write_jobs(self) -> None:
        stdin = self.proc.stdin
        try:
            while (job := self._jobs.get()) is not None:
                stdin.write(job)
                stdin.flush()
        except (BrokenPipeError, ValueError):  # the worker is gone: `result` says so
            pass
        finally:
            stdin.close()

    def result(self) -> None:
        """Wait for the next job; what went wrong in the worker is raised here (a RuntimeError: a bug)."""
        try:
            status, detail = pickle.load(self.proc.stdout)
        except EOFError:
            raise RuntimeError(f"the plot worker ended (exit code {self.proc.wait()})") from None
        if status != "ok":
            raise RuntimeError(f"the plot worker: {detail}")

    def close(self) -> None:
        """End the worker (after its pending jobs)."""
        if self.proc is not None:
            if self._writer is None:
                self.proc.stdin.close()
            else:
                self._jobs.put(None)
                self._writer.join()
            self.proc.wait()
            self.proc.stdout.close()
            self.proc = None


def serve(stdin, stdout) -> None:
    """The worker's loop: draw each job, reply ("ok", path) or ("error", text), until stdin closes."""
    import matplotlib.figure  # noqa: F401 - imported before the first job arrives

    from services.outputs import plots

    while True:
        try:
            drawing, picture, path = pickle.load(stdin)
        except EOFError:
            return
        try:
            if drawing not in DRAWINGS:
                raise ValueError(f"unknown drawing {drawing!r}")
            getattr(plots, drawing)(picture, path)
            reply = ("ok", path)
        except Exception as exc:  # noqa: BLE001 - reported to the caller, which raises it
            reply = ("error", f"{drawing} {path}: {type(exc).__name__}: {exc}")
        pickle.dump(reply, stdout)
        stdout.flush()


if __name__ == "__main__":
    # At a low priority: its matplotlib import, during the run, takes what the run's two processes
    # (control here, SUMO in the drive worker) leave of the two cores, not their share.
    os.nice(10)
    try:
        serve(sys.stdin.buffer, sys.stdout.buffer)
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole group; the caller is gone
        pass
    # Every reply is flushed and every picture closed: skip the interpreter's teardown of matplotlib
    # (a fifth of a second the caller would wait for in `close`).
    os._exit(0)
