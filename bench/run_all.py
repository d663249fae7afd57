"""`make bench`: runs every bench/bench_*.py, prints its figures and writes them all to
bench/results.json ({"figure_name": number, ...}).

Each benchmark runs in its own process (libsumo allows one simulation per process, and a fresh
process keeps one benchmark's memory from another's peak-memory figure). A benchmark module defines
``run() -> dict[str, float]``.
"""

from __future__ import annotations

import glob
import importlib
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
RESULTS = os.path.join(HERE, "results.json")


def run_one(name: str) -> dict:
    module = importlib.import_module(f"bench.{name}")
    return module.run()


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "--one":
        figures = run_one(argv[1])
        print("BENCH-JSON " + json.dumps(figures))
        return 0
    names = argv or sorted(os.path.basename(p)[:-3] for p in glob.glob(os.path.join(HERE, "bench_*.py")))
    results = {}
    if os.path.isfile(RESULTS):
        with open(RESULTS) as fh:
            results = json.load(fh)
    failed = []
    for name in names:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "bench.run_all", "--one", name], cwd=ROOT,
                              capture_output=True, text=True)
        sys.stdout.write(proc.stdout.replace("BENCH-JSON ", f"{name} figures: "))
        line = [ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH-JSON ")]
        if proc.returncode != 0 or not line:
            failed.append(name)
            sys.stderr.write(proc.stderr[-3000:])
            continue
        results.update(json.loads(line[-1][len("BENCH-JSON "):]))
        print(f"{name}: {time.perf_counter() - t0:.1f} s")
    with open(RESULTS + ".tmp", "w") as fh:   # whole or not at all: written aside, then renamed
        json.dump(dict(sorted(results.items())), fh, indent=2)
        fh.write("\n")
    os.replace(RESULTS + ".tmp", RESULTS)
    print(f"\nwrote {RESULTS}:")
    for key, value in sorted(results.items()):
        print(f"  {key:<40} {value:,.4g}")
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
