"""A second process that draws a run's pictures while the first writes the other files.

`vrsim run` starts it (`PlotWorker.start`) before it simulates, so its matplotlib import (a third of a
second or more) overlaps the simulation on another core; after the run it draws map.png and
sections.png (timeseries.png too, unless it was drawn as the run went) while the run's process writes
the GeoTIFFs, the track files and the TimeLog. A process, not a thread: drawing holds the GIL.

The worker is ``python -m vrsim.services.outputs.plot_worker``: jobs (drawing function's name, picture, path
or None) arrive pickled on its stdin, each behind its length (8 bytes, little-endian), and one reply
per job goes back pickled on its stdout, in order (a job without a path is drawn in memory: its reply
holds the PNG's bytes). A job may come while the run still goes on (timeseries.png's minute is known
early: `services.outputs.early`); like any, it is drawn once the low-priority imports are done, that
is once the cores have had time to spare. (Drawn at a low priority too, on a busy machine it was
drawn last, 0.26 s after the run's other pictures.) Each job is drawn in a child forked from the
worker (fork copies no import: matplotlib is loaded once), so the pictures are drawn side by side on
the cores the run's process leaves (`common.forked.Forked`), and a drawing that crashes its process is
an error reply, not a lost worker.
Both ends are vrsim's own processes (pickle is no format for anything else). The worker imports numpy,
matplotlib and vrsim's drawing code in a thread at a low priority (a Linux thread has its own nice
value), so the import takes what the run's processes leave of the cores; the children it forks draw
at the caller's priority, as the run's own work, which they are once the run is over. (Drawing a
small picture before the forks, so that what a first drawing loads is loaded once, saves the
children 0.04 s of CPU and costs the worker 0.3 s: it is not done; only what a first save imports, the
Agg canvas and PIL's formats, 5 ms, is.) It is started as a plain subprocess, not through
multiprocessing, whose spawn would re-import the caller's main module (its children are forked: they
re-import nothing).
"""

from __future__ import annotations

import os
import pickle
import queue
import select
import struct
import subprocess
import sys
import threading

# What a job may ask for, from services.outputs.plots.
DRAWINGS = ("draw_maps", "draw_sections", "draw_timeseries")
_LENGTH = struct.Struct("<Q")  # each job's length, before it


class PlotWorker:
    """The worker process, seen from the caller: `start`, `submit` jobs, `result` of each in order,
    `close`."""

    def __init__(self):
        self.proc = None
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()   # pickled jobs; None ends them
        self._writer: threading.Thread | None = None
        self._replies: queue.SimpleQueue = queue.SimpleQueue()   # unpickled replies; None: the worker ended
        self._reader: threading.Thread | None = None

    def start(self) -> PlotWorker:
        # -P: vrsim's own modules, not a `services` package in the folder the command runs in
        self.proc = subprocess.Popen([sys.executable, "-P", "-m", "vrsim.services.outputs.plot_worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        # Replies are read as they come, not when `result` asks: a PNG's bytes fill the pipe, and a
        # worker blocked writing one reads no job (map.png's waited 0.5 s for the caller's first
        # `result`, after the run's other files, in `vrsim run huge`).
        self._reader = threading.Thread(target=self._read_replies, name="plot-replies", daemon=True)
        self._reader.start()
        return self

    def submit(self, drawing: str, picture, path: str | None) -> None:
        """Ask for `drawing` (one of `DRAWINGS`) of `picture` into `path` (None: into memory, the PNG's
        bytes are the job's `result`); returns at once.

        A picture is megabytes and the pipe holds 64 KB: written here, the next job would wait for
        the worker to finish drawing the last. A thread writes the jobs in order instead."""
        if self._writer is None:
            self._writer = threading.Thread(target=self._write_jobs, name="plot-jobs", daemon=True)
            self._writer.start()
        job = pickle.dumps((drawing, picture, path), protocol=pickle.HIGHEST_PROTOCOL)
        self._jobs.put(_LENGTH.pack(len(job)) + job)

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

    def result(self) -> str | bytes:
        """Wait for the next job: its path, or the PNG's bytes of a job without one; what went wrong in
        the worker is raised here (a RuntimeError: a bug)."""
        reply = self._replies.get()
        if reply is None:
            self._replies.put(None)   # every later `result` too
            raise RuntimeError(f"the plot worker ended (exit code {self.proc.wait()})")
        status, detail = reply
        if status != "ok":
            raise RuntimeError(f"the plot worker: {detail}")
        return detail

    def _read_replies(self) -> None:
        stdout = self.proc.stdout
        try:
            while True:
                self._replies.put(pickle.load(stdout))
        except (EOFError, pickle.UnpicklingError, ValueError):   # it ended (perhaps mid-reply), or closed
            self._replies.put(None)

    def close(self) -> None:
        """End the worker after its pending jobs (whose replies nobody waits for any more: the reader
        drops them)."""
        if self.proc is not None:
            if self._writer is None:
                self.proc.stdin.close()
            else:
                self._jobs.put(None)
                self._writer.join()
            self._reader.join()
            self.proc.wait()
            self.proc.stdout.close()
            self.proc = None


def _serve(stdin_fd: int, stdout) -> None:
    """The worker's loop until stdin closes and every job is answered: each job is drawn in a forked
    child (`common.forked.Forked` of `_drawn`); the replies, ("ok", path) or ("error", text), go out in
    the jobs' order."""
    from vrsim.common.forked import Forked

    ready_to_draw = threading.Thread(target=_import_matplotlib, name="plot-imports")
    ready_to_draw.start()
    pending, children = bytearray(), []   # bytes of jobs not yet whole; [(Forked, label)] in the jobs' order
    reading, jobs = True, 0
    while reading or children:
        ready, _, _ = select.select([child for child, _ in children[:1]] + ([stdin_fd] if reading else []),
                                    [], [])
        if stdin_fd in ready:
            data = os.read(stdin_fd, 1 << 20)
            reading = bool(data)
            pending += data
            for job in _whole_jobs(pending):
                ready_to_draw.join()   # no thread at the fork, and matplotlib loaded for the children
                jobs += 1
                children.append((Forked(_drawn, job), f"job {jobs}"))
        if children and children[0][0] in ready:  # the oldest job's reply goes first
            child, label = children.pop(0)
            try:
                reply = child.result()
            except RuntimeError as exc:  # its process ended without one
                reply = ("error", f"{label}: {exc}")
            pickle.dump(reply, stdout)
            stdout.flush()


def _whole_jobs(pending: bytearray):
    """Take each whole job (its length, then its pickled bytes) off the front of `pending`."""
    while len(pending) >= _LENGTH.size:
        end = _LENGTH.size + _LENGTH.unpack_from(pending)[0]
        if len(pending) < end:
            return
        job = bytes(pending[_LENGTH.size:end])
        del pending[:end]
        yield job


def _import_matplotlib() -> None:
    """Import matplotlib and the drawing code, in this thread at a low priority."""
    os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
    import matplotlib.backends.backend_agg  # noqa: F401 - savefig's canvas, else imported by each child
    import matplotlib.figure  # noqa: F401 - what every drawing needs
    from PIL import Image

    from vrsim.services.outputs import plots  # noqa: F401

    Image.preinit()  # the image formats PIL loads at its first save, once here rather than in each child


def _drawn(job: bytes) -> tuple[str, str | bytes]:
    """Draw one pickled job; its reply. In a child that exits once it has drawn: its garbage goes with
    it, and no collection pass runs (about 5 ms of map.png's 0.2 s)."""
    import gc
    import io

    gc.disable()

    from vrsim.services.outputs import plots

    drawing, picture, path = pickle.loads(job)
    try:
        if drawing not in DRAWINGS:
            raise ValueError(f"unknown drawing {drawing!r}")
        if path is not None:
            getattr(plots, drawing)(picture, path)
            return ("ok", path)
        png = io.BytesIO()
        getattr(plots, drawing)(picture, png)
        return ("ok", png.getvalue())
    except Exception as exc:  # noqa: BLE001 - reported to the caller, which raises it
        return ("error", f"{drawing} {path or 'in memory'}: {type(exc).__name__}: {exc}")


if __name__ == "__main__":
    try:
        _serve(sys.stdin.fileno(), sys.stdout.buffer)
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole group; the caller is gone
        pass
    # Every reply is flushed and every picture closed: skip the interpreter's teardown of matplotlib
    # (a fifth of a second the caller would wait for in `close`).
    os._exit(0)
