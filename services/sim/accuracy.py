"""The accuracy regression library: scenarios whose recorded figures CI holds.

``tests/accuracy/scenarios/*.toml`` are ordinary scenario files; ``tests/accuracy/expected.json``
holds, per scenario, each accuracy metric of ``vrsim run --json`` with a tolerance::

    {"uniform": {"mae_kg_ha": {"value": 1.23, "tol": 0.5}, ...}, ...}

A metric has *moved* when ``|measured - value| > tol`` (or exactly one of them is null). Timings
(wall time, real-time factor) are not held: they measure the machine, not the model.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from vrsim.common import ScenarioError, is_number
from vrsim.services.sim.metrics import METRICS

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LIBRARY_DIR = os.path.join(ROOT, "tests", "accuracy")
SCENARIO_DIR = os.path.join(LIBRARY_DIR, "scenarios")
EXPECTED = os.path.join(LIBRARY_DIR, "expected.json")
CHANGELOG = os.path.join(LIBRARY_DIR, "CHANGELOG.md")

# What `vrsim accuracy` and the accuracy tests use: the runner, the comparison and the library's files.
__all__ = ["Check", "scenario_names", "run_scenario", "run_library", "load_expected", "compare", "table",
           "update", "TOLERANCES", "LIBRARY_DIR", "SCENARIO_DIR", "EXPECTED", "CHANGELOG"]

# Held metrics and their tolerance (absolute floor, share of the value), from the metrics table.
TOLERANCES = {m.key: m.tolerance for m in METRICS if m.tolerance is not None}


@dataclass
class Check:
    scenario: str
    metric: str
    expected: float | None
    measured: float | None
    tol: float
    moved: bool


def scenario_names() -> list[str]:
    """The library's scenarios; refuses an installed vrsim, which ships no library."""
    if not os.path.isdir(SCENARIO_DIR):
        raise ScenarioError(f"vrsim accuracy needs a source checkout: the accuracy library is not at "
                            f"{LIBRARY_DIR} (an installed vrsim ships no tests; run it in a clone of the "
                            "repository)")
    return sorted(f[:-5] for f in os.listdir(SCENARIO_DIR) if f.endswith(".toml"))


def run_scenario(name: str) -> dict:
    """Run one library scenario through the real CLI (its own process: one SUMO per process)."""
    path = os.path.join(SCENARIO_DIR, name + ".toml")
    vrsim = os.path.join(os.path.dirname(sys.executable), "vrsim")
    with tempfile.TemporaryDirectory(prefix=f"vrsim-acc-{name}-") as out:
        proc = subprocess.run([vrsim, "run", path, "--json", "--quiet", "--out", out],
                              capture_output=True, text=True)
    if proc.returncode != 0:
        raise ScenarioError(f"{path}: vrsim run exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    return json.loads(proc.stdout)


def run_library(names: list[str] | None = None, workers: int | None = None) -> dict[str, dict]:
    """Run scenarios in parallel across the machine's cores; {name: summary}."""
    names = names or scenario_names()
    workers = workers or os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return dict(zip(names, pool.map(run_scenario, names), strict=True))


def load_expected() -> dict:
    if not os.path.isfile(EXPECTED):
        return {}
    with open(EXPECTED) as fh:
        return json.load(fh)


def _tolerance(metric: str, value: float | None) -> float:
    floor, share = TOLERANCES[metric]
    return floor + share * abs(value) if value is not None else floor


def _num(value):
    """A figure as compared: a finite number, or None (null, NaN: the figure does not exist)."""
    return value if is_number(value) else None


def compare(name: str, summary: dict, expected: dict) -> list[Check]:
    checks = []
    for metric in TOLERANCES:
        want = expected.get(name, {}).get(metric)
        got = _num(summary.get(metric))
        if want is None:
            checks.append(Check(name, metric, None, got, 0.0, True))
            continue
        value, tol = _num(want["value"]), want["tol"]
        if value is None or got is None:
            moved = (value is None) != (got is None)
        else:
            moved = abs(got - value) > tol
        checks.append(Check(name, metric, value, got, tol, moved))
    return checks


def table(checks: list[Check], only_moved: bool = False) -> str:
    def fmt(v):
        return "null" if v is None else f"{v:.4g}"

    rows = [f"{'scenario':<28} {'metric':<28} {'expected':>10} {'measured':>10} {'tol':>8}  status"]
    for c in checks:
        if only_moved and not c.moved:
            continue
        status = "MOVED" if c.moved else "ok"
        rows.append(f"{c.scenario:<28} {c.metric:<28} {fmt(c.expected):>10} {fmt(c.measured):>10} "
                    f"{c.tol:>8.3g}  {status}")
    return "\n".join(rows)


def _expected_from(results: dict[str, dict]) -> dict:
    out = {}
    for name, summary in sorted(results.items()):
        out[name] = {}
        for metric in TOLERANCES:
            value = _num(summary.get(metric))
            out[name][metric] = {"value": value, "tol": round(_tolerance(metric, value), 6)}
    return out


def update(results: dict[str, dict], reason: str) -> None:
    """Rewrite the figures of the scenarios in `results` (others are kept) and append the reason and
    the changed figures to the changelog."""
    if not reason.strip():
        raise ScenarioError("--update needs --reason TEXT saying why the figures change")
    old = load_expected()
    new = {**old, **_expected_from(results)}
    lines = [f"\n## {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}: {reason.strip()}\n"]
    for name in sorted(set(old) | set(new)):
        for metric in TOLERANCES:
            before = old.get(name, {}).get(metric, {}).get("value")
            after = new.get(name, {}).get(metric, {}).get("value")
            if before != after:
                lines.append(f"- {name} {metric}: {before} -> {after}\n")
    if len(lines) == 1:
        lines.append("- no figure changed\n")
    with open(EXPECTED, "w") as fh:
        json.dump(new, fh, indent=1, sort_keys=True)
        fh.write("\n")
    header = "" if os.path.isfile(CHANGELOG) else "# Accuracy library changelog\n"
    with open(CHANGELOG, "a") as fh:
        fh.write(header + "".join(lines))
