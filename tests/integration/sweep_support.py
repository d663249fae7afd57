"""Tasks for the Dask driver's fault tests; a module of its own so the workers can import them."""

import os


def square_or_die(item):
    """``(x, mode, marker)``: x*x, after killing this worker process first when asked to.

    mode ``"always"`` kills every attempt; ``"once"`` kills the first attempt only (it leaves
    `marker`, a file path, so the retry on another process knows); ``"raise"`` raises, after adding a
    line to `marker` (one per attempt)."""
    x, mode, marker = item
    if mode == "raise":
        with open(marker, "a") as fh:
            fh.write("attempt\n")
        raise ValueError(f"no square of {x} today")
    if mode == "always" or (mode == "once" and not os.path.exists(marker)):
        if marker:
            open(marker, "w").close()
        os._exit(3)  # the worker process dies here, as it would on a segfault or an out-of-memory kill
    return x * x
