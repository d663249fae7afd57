"""Tuning on the model: the fitted sensor, the simulated ultimate-gain experiment, the relay."""

from dataclasses import replace

import pytest

from vrsim.controller import (
    PlantParams,
    fit_sensor,
    relay_autotune,
    ultimate_from_pulse,
    ultimate_gain_experiment,
)

P = PlantParams()


def test_defaults_are_the_fit_to_the_papers_ku_and_tu():
    fit = fit_sensor(P, 0.955, 0.31)
    assert P.sensor_delay_s == pytest.approx(fit.sensor_delay_s, abs=1e-6)
    assert P.sensor_gain_v_per_rpm == pytest.approx(fit.sensor_gain_v_per_rpm, rel=1e-5)


def test_simulated_ultimate_gain_experiment_lands_within_2pct_of_the_fit():
    result = ultimate_gain_experiment(P)
    assert result.ku == pytest.approx(0.955, rel=0.02)
    assert result.tu_s == pytest.approx(0.31, rel=0.02)
    ku, tu = ultimate_from_pulse(P)
    assert result.ku == pytest.approx(ku, rel=1e-3) and result.tu_s == pytest.approx(tu, rel=1e-3)


def test_without_the_delay_the_loop_oscillates_at_nyquist():
    result = ultimate_gain_experiment(replace(P, sensor_delay_s=0.0))
    assert result.tu_s == pytest.approx(0.1, rel=1e-6)
    assert result.ku == pytest.approx(ultimate_from_pulse(replace(P, sensor_delay_s=0.0))[0], rel=1e-3)


def test_fit_follows_a_different_target():
    fit = fit_sensor(P, 1.5, 0.5)
    plant = replace(P, sensor_delay_s=fit.sensor_delay_s, sensor_gain_v_per_rpm=fit.sensor_gain_v_per_rpm)
    ku, tu = ultimate_from_pulse(plant)
    assert ku == pytest.approx(1.5, rel=1e-6) and tu == pytest.approx(0.5, rel=1e-6)


def test_relay_estimate_is_near_the_ultimate_point():
    r = relay_autotune(P)
    # describing-function estimate; with a 50 ms relay the period is a whole number of periods
    assert r.ku == pytest.approx(0.955, rel=0.15)
    assert r.tu_s == pytest.approx(0.31, rel=0.25)
    assert round(r.tu_s / 0.05, 6) == int(round(r.tu_s / 0.05))


def test_paper_run_reports_the_step_and_duration_it_used():
    from vrsim.controller.experiment import run_paper

    run = run_paper(step_rpm=50.0, duration_s=10.0)
    assumed = run.summary["assumptions"]
    assert assumed["step_rpm"]["value"] == 50.0 and assumed["duration_s"]["value"] == 10.0
    assert run.t_s[-1] == pytest.approx(10.0)
    # each controller's loop figures: for P the gain margin is the ultimate gain over its kp
    p_loop = run.summary["P"]["loop"]
    assert p_loop["gain_margin"] == pytest.approx(run.summary["ultimate"]["Ku"] / 0.573, rel=1e-3)
    assert p_loop["phase_margin_deg"] is None        # |L| < 1 everywhere: no crossover
    assert run.summary["textbook"]["PI"]["loop"]["phase_margin_deg"] > 60
