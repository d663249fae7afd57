"""The statistics of a sweep's report: configurations (the seeds of one design point are its
replicates), their means with 95 % confidence intervals, the best ones and the Pareto front."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vrsim.services.sim.metrics import METRICS

# Which way is better ("min", "max" or "zero"), for the accuracy figures the report ranks: the
# METRICS table's sense.
METRIC_SENSE = {m.key: m.sense for m in METRICS if m.sense is not None}



@dataclass
class Configuration:
    """The ok runs of one scenario at one point of the design (its seeds are the replicates)."""

    scenario: str
    axes: tuple[tuple[str, Any], ...]
    rows: list[dict] = dataclasses.field(default_factory=list)

    def values(self, metric: str) -> np.ndarray:
        got = [r.get(metric) for r in self.rows]
        return np.array([v for v in got if v is not None and math.isfinite(v)], dtype=float)

    def label(self) -> str:
        return ", ".join([self.scenario, *(f"{k}={v}" for k, v in self.axes)])


def configurations(rows: Sequence[dict], axis_keys: Sequence[str]) -> list[Configuration]:
    """The ok rows grouped by scenario and axis values, in first-seen order."""
    groups: dict[tuple, Configuration] = {}
    for row in rows:
        if row.get("status") != "ok":
            continue
        axes = tuple((k, row.get(k)) for k in axis_keys)
        groups.setdefault((row["scenario"], axes), Configuration(row["scenario"], axes)).rows.append(row)
    return list(groups.values())


def mean_ci95(values: np.ndarray) -> tuple[float, float]:
    """Mean and the half-width of its 95 % confidence interval (Student's t over the replicates;
    NaN half-width for fewer than two, NaN mean for none)."""
    from scipy import stats

    n = len(values)
    if n == 0:
        return math.nan, math.nan
    mean = float(np.mean(values))
    if n < 2:
        return mean, math.nan
    return mean, float(stats.t.ppf(0.975, n - 1) * np.std(values, ddof=1) / math.sqrt(n))


def _badness(metric: str, value: np.ndarray | float):
    """Smaller is better: the metric's value turned by its `METRIC_SENSE`."""
    sense = METRIC_SENSE[metric]
    return -value if sense == "max" else (np.abs(value) if sense == "zero" else value)


def best(configs: Sequence[Configuration], metric: str, k: int = 3):
    """The `k` best configurations by their mean `metric`: [(configuration, mean, ci95 half-width)]."""
    scored = [(c, *mean_ci95(c.values(metric))) for c in configs]
    scored = [s for s in scored if math.isfinite(s[1])]
    return sorted(scored, key=lambda s: _badness(metric, s[1]))[:k]


def pareto_front(x: np.ndarray, y: np.ndarray, metric_x: str, metric_y: str) -> np.ndarray:
    """Boolean mask of the points no other point beats on both metrics (at least as good on both and
    better on one), each metric turned by its sense; NaN points are never on the front."""
    bx, by = _badness(metric_x, np.asarray(x, float)), _badness(metric_y, np.asarray(y, float))
    ok = np.isfinite(bx) & np.isfinite(by)
    no_worse = (bx[None, :] <= bx[:, None]) & (by[None, :] <= by[:, None]) & ok[None, :]
    better = (bx[None, :] < bx[:, None]) | (by[None, :] < by[:, None])
    return ok & ~(no_worse & better).any(axis=1)
