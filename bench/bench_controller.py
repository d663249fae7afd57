"""Controller costs: vrsim's lifted closed loop against python-control on the same loop, batch
throughput, and the per-call cost of `ClosedLoop.step` that the field run pays ~130,000 times.

Figures
-------
controller_speedup_vs_python_control  python-control's cost per simulated second over vrsim's (n = 1)
controller_pc_s_per_sim_s             python-control input_output_response, wall s per simulated s
controller_vrsim_s_per_sim_s          vrsim ClosedLoop.step, wall s per simulated s
controller_pc_vs_vrsim_max_rel_diff   largest difference of the two shaft-speed records / peak speed
controller_batch_loops_per_s          10,000 loops (different gains) of 10 s simulated, loop-runs per s
controller_step_us                    ClosedLoop.step with n = 1 and a float target, us per call
controller_generic_step_us_n1         PlantLoop.step (the interface loop) with kind PID, n = 1, us per period
controller_generic_step_us_n1000      the same with n = 1000 loops, us per period (all loops)
controller_run_us_per_period_<kind>   loop.run over 20,000 periods of a stepping target, n = 1, per kind
                                      (python: the example user class scenarios/my_controller.py)

The loop: saturating valve (0-1 A), the paper's incremental PID at 50 ms, the plant at 1 ms, the sensor
delay rounded to 104 ms so python-control's 1 ms delay line is exactly the same loop; the setpoint
steps between 150, 40 and 190 rpm so the current limits are hit. python-control gets 20 s simulated,
vrsim 2,000 s. BLAS runs single-threaded unless OPENBLAS_NUM_THREADS says otherwise (see below).
"""

from __future__ import annotations

import os

# Single-threaded BLAS, set before numpy loads: the loop's products are small (16 x 17 per loop), and
# OpenBLAS's threads only fight over the 2 cores (on a loaded CI box the batch ran 3x slower with them).
# The field run is single-threaded anyway. Set OPENBLAS_NUM_THREADS yourself to measure otherwise.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

PC_SIM_S = 20.0
VRSIM_SIM_S = 2000.0
BATCH_LOOPS = 10_000
BATCH_SIM_S = 10.0
STEP_CALLS = 100_000
GENERIC_CALLS_N1000 = 2_000
RUN_PERIODS = 20_000


def _setpoint(t_s):
    """Shaft-speed setpoint [rpm] at time t: steps every 2 s through 150, 40, 190."""
    return np.array([150.0, 40.0, 190.0])[(np.asarray(t_s) // 2.0).astype(int) % 3]


def _python_control_loop(plant, gains, T, h):
    """The same loop as a python-control interconnection of discrete systems at step h."""
    import control

    from vrsim.controller.plant import shaft_rpm_row, state_space

    A, B = state_space(plant)
    pl = control.sample_system(control.ss(A, B[:, :1], shaft_rpm_row(plant)[None, :], 0), h, method="zoh",
                               name="plant", inputs="i", outputs="y")
    d = round(plant.sensor_delay_s / h)
    shift = np.eye(d, k=-1)
    feed = np.zeros((d, 1))
    feed[0, 0] = 1.0
    delay = control.ss(shift, feed, np.eye(d)[-1:], 0, dt=h, name="sensor", inputs="y", outputs="ym")
    a, b, c = gains.incremental(T)
    every = round(T / h)
    ks, ka = plant.sensor_gain_v_per_rpm, plant.amplifier_gain_a_per_v
    lo, hi = plant.current_min_a, plant.current_max_a

    def pid(x, u):
        """New (saturated) current from state [count, held, e1, e2, u_prev] and inputs [r, ym]."""
        e = ks * (u[0] - u[1])
        cur = min(max(ka * (x[4] + a * e - b * x[2] + c * x[3]), lo), hi)
        return e, cur

    def update(t, x, u, params):
        if int(round(x[0])) % every:
            return np.array([x[0] + 1, x[1], x[2], x[3], x[4]])
        e, cur = pid(x, u)
        return np.array([x[0] + 1, cur, e, x[2], cur / ka])

    def output(t, x, u, params):
        return np.array([pid(x, u)[1] if int(round(x[0])) % every == 0 else x[1]])

    ctrl = control.NonlinearIOSystem(update, output, states=5, inputs=["r", "ym"], outputs=["i"], dt=h,
                                     name="pid")
    return control.interconnect([pl, delay, ctrl], inplist=["pid.r"], outlist=["plant.y"], dt=h)


def run() -> dict[str, float]:
    import control

    from vrsim.controller import (
        ClosedLoop,
        ControllerConfig,
        PidGains,
        PlantParams,
        build_loop,
        paper_gains,
        simulate,
    )

    T, h = 0.05, 0.001
    plant = replace(PlantParams(), sensor_delay_s=0.104)
    gains = paper_gains("PID")
    figures = {}

    # python-control: short horizon
    sys = _python_control_loop(plant, gains, T, h)
    t = np.arange(round(PC_SIM_S / h)) * h
    t0 = time.perf_counter()
    response = control.input_output_response(sys, t, _setpoint(t))
    pc_s = time.perf_counter() - t0
    y_pc = np.asarray(response.outputs).ravel()

    # vrsim, same loop and horizon, for agreement
    ref = simulate(plant, gains, _setpoint(np.arange(round(PC_SIM_S / T)) * T)[:, None], PC_SIM_S, T, h)
    y_vr = ref.shaft_rpm[0, :len(t)]
    figures["controller_pc_vs_vrsim_max_rel_diff"] = float(np.abs(y_pc - y_vr).max() / np.abs(y_vr).max())

    # vrsim: long horizon, the field run's call pattern
    loop = ClosedLoop(plant, gains, control_period_s=T, plant_step_s=h)
    ticks = round(VRSIM_SIM_S / T)
    targets = [float(x) for x in _setpoint(np.arange(ticks) * T)]
    t0 = time.perf_counter()
    for r in targets:
        loop.step(r)
    vr_s = time.perf_counter() - t0
    figures["controller_pc_s_per_sim_s"] = pc_s / PC_SIM_S
    figures["controller_vrsim_s_per_sim_s"] = vr_s / VRSIM_SIM_S
    figures["controller_speedup_vs_python_control"] = (pc_s / PC_SIM_S) / (vr_s / VRSIM_SIM_S)

    # batch: 10,000 loops with different gains, 10 s each
    kp = np.linspace(0.2, 0.8, BATCH_LOOPS)
    batch_gains = [PidGains(float(k), 2.0, 0.0) for k in kp]
    t0 = time.perf_counter()
    simulate(plant, batch_gains, 100.0, BATCH_SIM_S, T, h, fine=False)
    figures["controller_batch_loops_per_s"] = BATCH_LOOPS / (time.perf_counter() - t0)

    # per-call cost of step with n = 1
    loop = build_loop(PlantParams(), ControllerConfig())
    step = loop.step
    t0 = time.perf_counter()
    for k in range(STEP_CALLS):
        step(100.0 + (k & 63))
    figures["controller_step_us"] = (time.perf_counter() - t0) / STEP_CALLS * 1e6

    # the controller-interface loop: per-period cost at n = 1 and n = 1000, then a run per kind
    for n, calls in ((1, STEP_CALLS // 5), (1000, GENERIC_CALLS_N1000)):
        loop = build_loop(PlantParams(), ControllerConfig(), n=n, fast=False)
        targets = np.full(n, 100.0)
        t0 = time.perf_counter()
        for _ in range(calls):
            loop.step(targets)
        figures[f"controller_generic_step_us_n{n}"] = (time.perf_counter() - t0) / calls * 1e6
    series = np.repeat(np.random.default_rng(0).uniform(50.0, 150.0, RUN_PERIODS // 50), 50)
    example = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenarios",
                           "my_controller.py")
    configs = {kind: ControllerConfig(kind=kind) for kind in ("PID", "aog_pi", "ff_pi", "smith", "fuzzy_pid",
                                                              "ideal")}
    configs["python"] = ControllerConfig(kind="python", file=example, class_name="MyController")
    for kind, cfg in configs.items():
        loop = build_loop(PlantParams(), cfg)
        t0 = time.perf_counter()
        loop.run(series)
        figures[f"controller_run_us_per_period_{kind}"] = (time.perf_counter() - t0) / len(series) * 1e6
    return figures


if __name__ == "__main__":
    for name, value in run().items():
        print(f"{name:<40} {value:,.6g}")
