"""A function of the data this process holds, run in a forked child on another core while this process
goes on: the child inherits the arguments (nothing is pickled on the way in, only the result on the
way back). For a second of numpy beside another second of numpy; Linux, where vrsim runs SUMO.
"""

from __future__ import annotations

import multiprocessing


class Forked:
    """``Forked(fn, *args)`` starts ``fn(*args)`` in a forked child; `result` waits for its value (or
    raises its exception), `fileno` says when it would not wait; `cancel` ends it unfinished. Use as a
    context manager to cancel on leaving."""

    def __init__(self, fn, *args):
        ctx = multiprocessing.get_context("fork")
        self.name = getattr(fn, "__qualname__", repr(fn))
        self._recv, send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_call, args=(send, fn, args), name=f"forked {self.name}", daemon=True)
        self._proc.start()
        send.close()

    def fileno(self) -> int:
        """A descriptor that turns readable once `result` would not wait (for `select`)."""
        return self._recv.fileno()

    def result(self):
        """The function's value, once the child has it; its exception is raised here."""
        try:
            status, value = self._recv.recv()
        except EOFError:
            self._proc.join()
            raise RuntimeError(f"the forked {self.name} ended without a result "
                               f"(exit code {self._proc.exitcode})") from None
        finally:
            self._recv.close()
        self._proc.join()
        if status == "error":
            raise value
        return value

    def cancel(self) -> None:
        """End the child if it still runs, and reap it."""
        if self._proc.is_alive():
            self._proc.kill()
        self._proc.join()

    def __enter__(self) -> Forked:
        return self

    def __exit__(self, *exc) -> None:
        self.cancel()


def _call(send, fn, args) -> None:
    try:
        reply = ("ok", fn(*args))
    except BaseException as exc:  # noqa: BLE001 - raised in the parent by `result`
        reply = ("error", exc)
    send.send(reply)
    send.close()
