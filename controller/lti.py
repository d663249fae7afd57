"""python-control models of the sampled loop's parts, at the control period T (``dt = T``).

* `plant_lti`: valve current [A] -> speed-sensor reading [rpm], the exact pulse transfer function of
  the 1 ms ZOH model held over T with the sensor delay split as the loops do it
  (``G(z) = z^-d (c Phi_s (z I - Phi_T)^-1 Gamma_T + c Gamma_s)``, `controller.discretize`);
* `undelayed_lti`: valve current -> shaft speed at the start of each period (what a delay-free sensor
  would read), the Smith predictor's ``y0``;
* `pid_lti`: the discrete PID ``C(z) = kp + ki T z/(z - 1) + kd/T (z - 1)/z`` [V/V] (both forms of the
  paper's law give it while unsaturated).

python-control is imported only when one of these is called (it takes about 2 s to import).
"""

from __future__ import annotations

from vrsim.controller.discretize import Lifted, lift
from vrsim.controller.gains import PidGains
from vrsim.controller.plant import IX_ANGLE, N_STATES, PlantParams, shaft_rev_row, shaft_rpm_row, state_space

# The motor angle integrates the speed but feeds nothing back: leaving it out keeps the models minimal
# (its pole at z = 1 would otherwise sit, unobservable, in every closed loop).
SPEED_STATES = slice(0, IX_ANGLE)


def _speed_part(plant: PlantParams, control_period_s: float):
    """(Phi_T, Gamma_T) of the states other than the angle, and the whole lifted period."""
    A, B = state_space(plant)
    lifted = lift(A, B, shaft_rpm_row(plant), shaft_rev_row(plant), control_period_s, control_period_s,
                  plant.sensor_delay_s)
    return (lifted.step[SPEED_STATES, SPEED_STATES], lifted.step[SPEED_STATES, N_STATES:N_STATES + 1],
            lifted)


def plant_lti(plant: PlantParams, control_period_s: float = 0.05):
    """Discrete model current [A] -> sensor reading [rpm], delay included (a `control.StateSpace`)."""
    import control

    phi, gamma, lifted = _speed_part(plant, control_period_s)
    sample = lifted.step[Lifted.ROW_SAMPLE]
    sampled = control.ss(phi, gamma, sample[None, SPEED_STATES], sample[N_STATES], control_period_s)
    delay = control.tf([1.0], [1.0] + [0.0] * lifted.delay_periods, control_period_s)
    return control.series(sampled, control.ss(delay))


def undelayed_lti(plant: PlantParams, control_period_s: float = 0.05):
    """Discrete model current [A] -> shaft speed at the start of each period [rpm] (no sensor delay)."""
    import control

    phi, gamma, _ = _speed_part(plant, control_period_s)
    return control.ss(phi, gamma, shaft_rpm_row(plant)[None, SPEED_STATES], 0.0, control_period_s)


def pid_lti(gains: PidGains, control_period_s: float = 0.05):
    """The discrete PID from error volts to output volts (a `control.TransferFunction`)."""
    import control

    t = control_period_s
    terms = [control.tf([gains.kp], [1.0], t)]
    if gains.ki:
        terms.append(control.tf([gains.ki * t, 0.0], [1.0, -1.0], t))
    if gains.kd:
        terms.append(control.tf([gains.kd / t, -gains.kd / t], [1.0, 0.0], t))
    return sum(terms[1:], terms[0])
