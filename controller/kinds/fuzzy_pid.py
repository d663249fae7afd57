"""Kind ``fuzzy_pid``: a fuzzy self-tuning PID; the rule tables are data (``controller/data``).

Each period the error ``e = r - y_m`` [rpm] and its change ``ec = e - e(k-1)`` are scaled onto the
universe [-3, 3] (``3 e / error_span_rpm``, ``3 ec / error_change_span_rpm``, saturating) and
fuzzified on seven evenly spaced triangular terms NB, NM, NS, ZO, PS, PM, PB (NB and PB saturate at
the ends; with unit spacing at most two terms per input, so at most four rules fire). Each of the
49 rules "if e is A and ec is B then dKp is C" fires with strength ``min(mu_A(e), mu_B(ec))``;
each correction is the strength-weighted mean of its consequents' centres (zero-order Sugeno
inference, the weighted-average form of Mamdani inference with symmetric output
terms), scaled by its span: ``Kp = kp + dkp_span x dKp / 3`` (likewise Ki, Kd; gains stay >= 0). The
PID runs in the paper's incremental form with these gains, ``du = Kp (e - e1) + Ki T e +
Kd/T (e - 2 e1 + e2)`` on sensor volts, holding the saturated output (anti-windup).

Source of the scheme and of the rule tables: Liu Jinkun, *Advanced PID Control and MATLAB
Simulation* (Publishing House of Electronics Industry, 2nd ed. 2004), "fuzzy self-tuning PID"; the
seed paper (Liang et al. 2013) concludes that fuzzy control suits this drive and cites fuzzy rate
controllers ([13], [14]). Base gains and spans are vrsim's choice for its default plant (documented in
`FuzzyPidParams`).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources

import numpy as np

from vrsim.common import ControllerError, files
from vrsim.common.toml_text import loads_toml
from vrsim.controller import ops
from vrsim.controller.gains import GAIN_SOURCES, PidGains
from vrsim.controller.interface import LawController, LoopInfo
from vrsim.controller.lti import pid_lti
from vrsim.controller.params import KindParams, param
from vrsim.controller.pid_law import saturate
from vrsim.controller.registry import register
from vrsim.controller.tuning import gains_from_source

TERMS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
TABLES = ("delta_kp", "delta_ki", "delta_kd")
DEFAULT_RULES = "fuzzy_pid_rules.toml"


def _load_rules(path: str | None = None) -> np.ndarray:
    """The three 7x7 rule tables as consequent centres in [-3, 3], shape (3, 7, 7) (kp, ki, kd; rows e,
    columns ec), from `path` or the package's ``data/fuzzy_pid_rules.toml``."""
    where = path or f"controller/data/{DEFAULT_RULES}"
    try:
        if path is None:
            text = resources.files("vrsim.controller").joinpath("data", DEFAULT_RULES).read_text()
        else:
            with open(path, encoding="utf-8") as fh:
                text = fh.read(files.cap_for("toml") + 1)  # one more: over the cap is refused, not cut
        doc = loads_toml(text, f"fuzzy rules {where}", ControllerError)
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ControllerError(f"fuzzy rules {where}: cannot be read: {exc}") from None
    if doc.get("terms") != list(TERMS):
        raise ControllerError(f"fuzzy rules {where}: terms must be {list(TERMS)}, got {doc.get('terms')!r}")
    centre = {t: i - 3.0 for i, t in enumerate(TERMS)}
    tables = []
    for name in TABLES:
        table = doc.get(name)
        if not (isinstance(table, list) and len(table) == 7 and all(isinstance(r, list) and len(r) == 7
                                                                    for r in table)):
            raise ControllerError(f"fuzzy rules {where}: {name} must be 7 rows of 7 terms, got {table!r}")
        for row in table:
            for term in row:
                if term not in centre:
                    raise ControllerError(f"fuzzy rules {where}: {name} has unknown term {term!r} "
                                          f"(terms: {', '.join(TERMS)})")
        tables.append([[centre[t] for t in row] for row in table])
    return np.array(tables)


def _fuzzify(x):
    """The two terms x (on [-3, 3], saturating) belongs to: index i of the lower one (0 = NB) and
    membership w of the upper one (the lower has 1 - w). Seven unit-spaced triangles overlap only
    pairwise, so these two are all of x's memberships. Floats or arrays."""
    u = ops.clip(x, -3.0, 3.0) + 3.0
    i = np.minimum(u.astype(int), 5) if isinstance(u, np.ndarray) else min(int(u), 5)
    return i, u - i


@dataclass(frozen=True)
class FuzzyPidParams(KindParams):
    """Parameters of ``fuzzy_pid``.

    Parameters
    ----------
    gains : {"paper", "textbook", "relay", "manual"}
        Base gains (the PID that the rules adjust), as for kind PID with terms PID ("paper": the
        paper's printed PID).
    kp, ki, kd : float or None
        Base gains with ``gains="manual"``: kp [V/V], ki [1/s], kd [s].
    dkp_span : float
        Largest change of Kp the rules make [V/V] (0.4).
    dki_span_per_s : float
        Largest change of Ki [1/s] (4.0).
    dkd_span_s : float
        Largest change of Kd [s] (0.002).
    error_span_rpm : float
        Error mapped to the ends of the universe (PB/NB) [rpm] (20).
    error_change_span_rpm : float
        Change of error per control period mapped to PB/NB [rpm] (50).

    The spans were chosen on vrsim's default plant by a grid search over step responses (100 and
    30 rpm from rest): with the paper's gains as base they settle (2 %) in about 1.4 s instead of the
    paper PID's 2.05 s, with no overshoot of the per-period speed.
    rules_file : str or None
        A rule-table file (absolute path) replacing the package's ``data/fuzzy_pid_rules.toml``.
    """

    KIND = "fuzzy_pid"
    gains: str = param("paper", choices=GAIN_SOURCES)
    kp: float | None = param(None, number=True, lo=0.0)
    ki: float | None = param(None, number=True, lo=0.0)
    kd: float | None = param(None, number=True, lo=0.0)
    dkp_span: float = param(0.4, lo=0.0)
    dki_span_per_s: float = param(4.0, lo=0.0)
    dkd_span_s: float = param(0.002, lo=0.0)
    error_span_rpm: float = param(20.0, lo=0.0, lo_open=True)
    error_change_span_rpm: float = param(50.0, lo=0.0, lo_open=True)
    rules_file: str | None = param(None)

    def check(self) -> None:
        given = [k for k in ("kp", "ki", "kd") if getattr(self, k) is not None]
        if given and self.gains != "manual":
            raise ControllerError(f"controller fuzzy_pid {given[0]} is only used with gains='manual' "
                                  f"(gains is {self.gains!r}), got {getattr(self, given[0])!r}")
        if self.gains == "manual" and self.kp is None:
            raise ControllerError("controller fuzzy_pid kp is required with gains='manual', got None")


@register("fuzzy_pid", FuzzyPidParams, "fuzzy self-tuning PID, rule tables in data (Liu Jinkun 2004)")
class FuzzyPid(LawController):
    """Fuzzy self-tuning incremental PID; see the module docstring and `FuzzyPidParams`."""

    MEMORY = ("u_v", "e1_v", "e2_v")

    def __init__(self, params: FuzzyPidParams, loop: LoopInfo, n: int):
        super().__init__(params, loop, n)
        self.base = gains_from_source(params.gains, "PID", loop.plant, loop.control_period_s,
                                      params.kp, params.ki, params.kd)
        self.rules = _load_rules(params.rules_file)
        # consequent centres times the gain's span / 3: the rules' correction of (kp, ki, kd) directly
        spans = np.array([params.dkp_span, params.dki_span_per_s, params.dkd_span_s]) / 3.0
        self._scaled = self.rules * spans[:, None, None]
        self._scaled_lists = self._scaled.tolist()
        self._base = (self.base.kp, self.base.ki, self.base.kd)
        self._e_scale = 3.0 / params.error_span_rpm
        self._ec_scale = 3.0 / params.error_change_span_rpm
        self.reset()

    def reset(self):
        self.u_v = self.e1_v = self.e2_v = ops.zeros(self.n)

    def tuned_gains(self, error_rpm, change_rpm) -> PidGains:
        """The gains the rules give for these errors and changes [rpm] (floats, or arrays (n,))."""
        return PidGains(*self._gains(error_rpm, change_rpm))

    def _gains(self, error_rpm, change_rpm) -> tuple:
        """(kp, ki, kd): each the base gain plus the strength-weighted mean of the (at most) four rules
        that fire, e's lower/upper term with ec's lower/upper term, floored at 0."""
        ie, we = _fuzzify(self._e_scale * error_rpm)
        ic, wc = _fuzzify(self._ec_scale * change_rpm)
        ve, vc = 1.0 - we, 1.0 - wc
        if isinstance(ie, np.ndarray):
            s_ll, s_lu = np.minimum(ve, vc), np.minimum(ve, wc)
            s_ul, s_uu = np.minimum(we, vc), np.minimum(we, wc)
            total = s_ll + s_lu + s_ul + s_uu
            t = self._scaled
            delta = (s_ll * t[:, ie, ic] + s_lu * t[:, ie, ic + 1] + s_ul * t[:, ie + 1, ic]
                     + s_uu * t[:, ie + 1, ic + 1]) / total
            return tuple(np.maximum(base + d, 0.0) for base, d in zip(self._base, delta, strict=True))
        # one loop: the same sums with floats (a numpy call costs more than the whole inference)
        s_ll, s_lu = (ve if ve < vc else vc), (ve if ve < wc else wc)
        s_ul, s_uu = (we if we < vc else vc), (we if we < wc else wc)
        total = s_ll + s_lu + s_ul + s_uu
        out = []
        for base, t in zip(self._base, self._scaled_lists, strict=True):
            lo, hi = t[ie], t[ie + 1]
            g = base + (s_ll * lo[ic] + s_lu * lo[ic + 1] + s_ul * hi[ic] + s_uu * hi[ic + 1]) / total
            out.append(g if g > 0.0 else 0.0)
        return tuple(out)

    def linear_model(self):
        """Small-signal model: the PID with the gains the rules give at zero error and zero change
        (near the target the gains vary only at second order in the error)."""
        g = self.tuned_gains(0.0, 0.0)
        return pid_lti(PidGains(float(g.kp), float(g.ki), float(g.kd)), self.loop.control_period_s)

    def law(self, target_rpm, measured_rpm):
        info = self.loop
        ks, t = info.sensor_gain_v_per_rpm, info.control_period_s
        e, e1, e2 = ks * (target_rpm - measured_rpm), self.e1_v, self.e2_v
        kp, ki, kd = self._gains(e / ks, (e - e1) / ks)
        u = self.u_v + kp * (e - e1) + ki * t * e + kd / t * (e - 2.0 * e1 + e2)
        current = saturate(info.amplifier_gain_a_per_v * u, info.current_min_a, info.current_max_a)
        self.u_v = current / info.amplifier_gain_a_per_v
        self.e2_v, self.e1_v = e1, e
        return current
