"""The PID's law is defined once (`controller.pid_law`): every path that runs it gives its numbers.

Over many random draws of gains, current limits, forms and targets (numpy's seeded Generator), the
one-loop path of `ClosedLoop` (the law written inline for speed), its n-loop tick, its shared-plant
batch (`_run_shared_plant`), its per-plant batch (`_run_per_plant`) and the interface law
(`PidController` in `PlantLoop`) agree; the draws drive the valve into both limits and the positional
form's clamping, so a change of the law in one path alone fails here.
"""

import dataclasses

import numpy as np

from vrsim.controller import ClosedLoop, ControllerConfig, PidGains, PlantLoop, PlantParams, loop_info
from vrsim.controller.factory import build_controller
from vrsim.controller.pid_law import clamped, saturate

DRAWS = 120
TICKS = 160
FORMS = ("incremental", "positional")


def _draw(rng: np.random.Generator):
    """One random loop: plant limits, gains, form, derivative placement, targets (K,), load."""
    lo = float(rng.uniform(-0.3, 0.2))
    plant = dataclasses.replace(PlantParams(), current_min_a=lo, current_max_a=float(rng.uniform(0.8, 1.6)),
                                shaft_rpm_max=float(rng.uniform(120.0, 200.0)))
    gains = PidGains(kp=float(rng.uniform(0.0, 3.0)), ki=float(rng.uniform(0.0, 20.0)),
                     kd=float(rng.choice([0.0, rng.uniform(0.0, 0.03)])))
    holds = rng.uniform(-40.0, 1.3 * plant.shaft_rpm_max, TICKS // 20)   # beyond both ends of the range
    targets = np.repeat(holds, 20)
    load = float(rng.choice([0.0, rng.uniform(-2.0, 2.0)]))
    return plant, gains, str(rng.choice(FORMS)), bool(rng.integers(2)), targets, load


def test_saturate_and_clamped_give_the_same_on_floats_and_arrays():
    rng = np.random.default_rng(7)
    unsat, e = rng.normal(0.5, 1.0, 5000), rng.normal(0.0, 1.0, 5000)
    lo, hi = rng.uniform(-0.5, 0.2, 5000), rng.uniform(0.5, 1.5, 5000)
    unsat[::50], unsat[::97] = lo[::50], hi[::97]                          # exactly at a limit, too
    cur, frozen = saturate(unsat, lo, hi), clamped(unsat, e, lo, hi)
    floats = list(zip(unsat.tolist(), e.tolist(), lo.tolist(), hi.tolist(), strict=True))
    assert np.array_equal(cur, [saturate(u, low, high) for u, _, low, high in floats])
    assert np.array_equal(frozen, [clamped(*a) for a in floats])
    assert np.all((lo <= cur) & (cur <= hi)) and np.array_equal(cur == unsat, (lo <= unsat) & (unsat <= hi))
    assert np.array_equal(frozen, ((unsat > hi) & (e > 0)) | ((unsat < lo) & (e < 0)))


def test_every_path_of_the_pid_runs_one_law_over_random_gains_limits_and_targets():
    rng = np.random.default_rng(2024)
    hit = {"low": 0, "high": 0, "positional_at_a_limit": 0}
    for _ in range(DRAWS):
        plant, gains, form, dom, targets, load = _draw(rng)
        kw = {"form": form, "derivative_on_measurement": dom}
        inline = ClosedLoop(plant, gains, **kw)                  # n = 1, float targets: the inline law
        ref = np.array([[o.current_a[0], o.shaft_rpm[0], o.shaft_rev[0]]
                        for o in (inline.step(float(r), load) for r in targets)])
        tick = ClosedLoop(plant, gains, **kw)                    # n = 1, array targets: `_tick`
        got = np.array([[o.current_a[0], o.shaft_rpm[0], o.shaft_rev[0]]
                        for o in (tick.step(np.array([r]), np.array([load])) for r in targets)])
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)

        other = PidGains(gains.kp * 0.5, gains.ki, gains.kd)
        shared = ClosedLoop(plant, [gains, other], n=2, **kw).run(np.column_stack([targets, targets]), load)
        per_plant = ClosedLoop([plant, dataclasses.replace(plant, inertia_kg_m2=plant.inertia_kg_m2 * 1.1)],
                               [gains, other], n=2, **kw).run(np.column_stack([targets, targets]), load)
        cfg = ControllerConfig(kind="PID", gains="manual", kp=gains.kp, ki=gains.ki, kd=gains.kd, **kw)
        law = PlantLoop(loop_info(plant), build_controller(cfg, plant)).run(targets, load)
        for out in (shared, per_plant, law):
            np.testing.assert_allclose(np.column_stack([out.current_a[:, 0], out.shaft_rpm[:, 0],
                                                        out.shaft_rev[:, 0]]), ref, rtol=1e-9, atol=1e-9)
        cur = ref[:, 0]
        hit["low"] += int(np.any(cur == plant.current_min_a))
        hit["high"] += int(np.any(cur == plant.current_max_a))
        hit["positional_at_a_limit"] += int(form == "positional" and np.any((cur == plant.current_max_a)
                                                                | (cur == plant.current_min_a)))
    # the draws exercise what is being proven: both limits, and the positional form held at one
    assert min(hit.values()) >= DRAWS // 10, hit
