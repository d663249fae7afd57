"""The AOG_RC rate module's firmware, emulated on vrsim's plant: a class stepped once per 50 ms loop.

Read from SK21/AOG_RC at commit 6af548b905c4b52f4cad7d5bbb1c924c45ef662d, ``Modules/Teensy
Rate/RCteensy/``: ``RCteensy.ino`` (the 50 ms loop, the 4 s rule, when the PID runs), ``PID.ino`` (the
normalized valve and motor PID, the timed combo valve, ``AdjustFlow``), ``Rate.ino`` (pulses to Hz to
units per minute, the 4 s no-flow rule), ``Receive.ino`` (what the PGNs set) and ``Send.ino`` (what the
reports hold). Written from those, not copied. Every 50 ms, as the firmware's loop:

1. ``SensorConnected`` = a PGN 32500 within 4 s; ``PIDenabled`` = connected, AutoOn, MasterOn, a
   section relay on and a target above 0; ``Applying`` = MasterOn and (a target above 0 or manual);
2. the flow meter: pulses at the meter calibration the app sent (pulses per unit) from the flow vrsim's
   plant gives, counted only while a section is on; Hz smoothed 0.8/0.2, UPM = 60 Hz / MeterCal; no
   pulse for 4 s (or no section on): 0;
3. the PID, once its period (PIDtime) has passed; manual: the app's PWM;
4. ``AdjustFlow``: a valve gets its PWM while connected (0 otherwise: it holds), a motor or fan while
   connected and applying (0 otherwise: it stops), a combo-close valve is driven shut (-255) otherwise;
5. the plant advances 50 ms (`DrivePlant`).

What a module's board does that vrsim has no part of (pressure gate, bin sensor, wheel speed sensor,
CAN, PGN 32503-32507) is left out; the median of the pulse periods is the flow's period (vrsim's flow is
steady within a 50 ms loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vrsim.controller import LoopInfo, PlantLoop, PlantParams
from vrsim.services.aog.pgn import PidLog, PidSettings, RateCommand, RateReport, RelayCommand

__all__ = ["COMM_TIMEOUT_MS", "CONTROL_TYPES", "DrivePlant", "FAN", "FirmwarePid", "FlowMeter", "LOOP_MS",
           "MOTOR", "REPORT_MS", "RateModule", "SensorChannel", "TIMED_COMBO", "VALVE", "VALVE_TRAVEL_S"]

LOOP_MS = 50                # LoopTime
REPORT_MS = 200             # SendTime
COMM_TIMEOUT_MS = 4000      # SensorConnected
FLOW_TIMEOUT_MS = 4000      # FlowTimeout
MAX_SAMPLES, MIN_MEDIAN_SAMPLES = 25, 7
VALVE_KP_SCALE, VALVE_KI_SCALE = 1.0, 0.1
MOTOR_KP_SCALE, MOTOR_KI_SCALE = 0.1, 0.01
VALVE, COMBO_CLOSE, MOTOR, MOTOR_WEIGHTS, FAN, TIMED_COMBO = 0, 1, 2, 3, 4, 5
CONTROL_TYPES = {VALVE: "valve", COMBO_CLOSE: "combo close", MOTOR: "motor", MOTOR_WEIGHTS: "motor weights",
                 FAN: "fan", TIMED_COMBO: "combo close timed"}
#: A motorized flow-control valve's full stroke at PWM 255, s (*assumed*: the RC's ball valves take 1-4 s;
#: `vrsim serve aog-rc --valve-travel-s`). Its opening scales the plant's current range.
VALVE_TRAVEL_S = 3.0


def _clip(value: float, lo: float, hi: float) -> float:
    return lo if value < lo else (hi if value > hi else value)


@dataclass
class FirmwarePid:
    """The firmware's normalized PID of one sensor (``PIDvalve``, ``PIDmotor``, ``TimedCombo``) and its
    memory; `step` is called every 50 ms loop and acts once its period has passed."""

    integral: float = 0.0
    ref_upm: float = 0.0
    error_positive: bool = True
    last_pwm: float = 0.0
    last_check_ms: int = 0
    osc_damp: float = 1.0
    last_above: bool = False
    combo_ms: int = 0
    pause: bool = False
    sample: dict | None = None    # the latest PID sample (PGN 32402's fields), None once sent

    def step(self, now_ms: int, s: PidSettings, control_type: int, target: float, upm: float,
             enabled: bool, samples: int = 0) -> float:
        """The PWM for the loop at `now_ms` (auto control), -255..255."""
        if control_type in (MOTOR, FAN):
            return self._motor(now_ms, s, target, upm, enabled, samples)
        if control_type == TIMED_COMBO:
            return self._timed(now_ms, s, target, upm, enabled, samples)
        return self._valve(now_ms, s, target, upm, enabled, samples)

    def manual(self, now_ms: int, s: PidSettings, control_type: int, target: float, upm: float,
               manual_pwm: float) -> float:
        """The PWM with auto off: the app's manual PWM within +-MaxPWM (a timed combo valve in bursts)."""
        if control_type == TIMED_COMBO:
            return self._timed(now_ms, s, target, upm, False, 0, manual_pwm)
        return _clip(manual_pwm, -s.max_pwm, s.max_pwm)

    def _error(self, now_ms: int, s: PidSettings, target: float, upm: float, samples: int) -> float:
        """The sample's error; resets the integral on a genuine overshoot (beyond the dead band)."""
        self.last_check_ms = now_ms
        self.ref_upm = max(self.ref_upm, target)
        error = target - upm
        self.sample = dict(millis=now_ms, target_upm=target, applied_upm=upm, error_upm=error, change=0.0,
                           samples=samples)
        band = s.deadband * target
        if error > band and not self.error_positive:
            self.error_positive, self.integral = True, 0.0
        elif error < -band and self.error_positive:
            self.error_positive, self.integral = False, 0.0
        return error

    def _change(self, s: PidSettings, target: float, error: float, kp_scale: float, ki_scale: float) -> float:
        """The P and I terms' change in PWM units (conditional integration inside the brake point)."""
        error = _clip(error, -target, target)
        frac = error / self.ref_upm
        authority = max(s.max_pwm - s.min_pwm, 1.0)
        near = abs(frac) <= s.brake_point_pct / 100.0
        if near:
            self.integral += _clip(frac * s.ki * ki_scale * authority, -s.max_integral, s.max_integral)
        if s.ki <= 0:
            self.integral = 0.0
        self.integral = _clip(self.integral, -authority, authority)
        brake = s.slow_adjust_pct / 100.0 if near else 1.0
        return frac * s.kp * kp_scale * brake * authority + self.integral

    def _finish(self, pwm: float) -> float:
        if self.sample is not None and "pwm" not in self.sample:
            self.sample.update(integral=self.integral, pwm=pwm)
        return pwm

    def _valve(self, now_ms, s, target, upm, enabled, samples) -> float:
        if not enabled:
            self.integral = self.ref_upm = 0.0
            self.last_pwm = 0.0
            return 0.0
        result = self.last_pwm
        if now_ms - self.last_check_ms >= s.pid_time_ms:
            error = self._error(now_ms, s, target, upm, samples)
            if abs(error) > s.deadband * target:
                change = self._change(s, target, error, VALVE_KP_SCALE, VALVE_KI_SCALE)
                self.sample["change"] = change
                if abs(change) < 0.1:
                    result = 0.0
                else:
                    result = math.copysign(_clip(abs(change) + s.min_pwm, s.min_pwm, s.max_pwm), change)
            else:
                result, self.integral = 0.0, 0.0
            self._finish(result)
        self.last_pwm = result
        return result

    def _motor(self, now_ms, s, target, upm, enabled, samples) -> float:
        if not enabled:
            self.integral = self.ref_upm = 0.0
            return 0.0
        result = self.last_pwm
        if now_ms - self.last_check_ms >= s.pid_time_ms:
            error = self._error(now_ms, s, target, upm, samples)
            if abs(error) > s.deadband * target:
                change = _clip(self._change(s, target, error, MOTOR_KP_SCALE, MOTOR_KI_SCALE),
                               -s.slew_rate, s.slew_rate)
                self.sample["change"] = change
                result = _clip(result + change, s.min_pwm, s.max_pwm)
                self.last_pwm = result
            else:
                self.integral = 0.0
            self._finish(result)
        return result

    def _timed(self, now_ms, s, target, upm, enabled, samples, manual_pwm=None) -> float:
        if not (enabled or manual_pwm is not None):
            self.integral, self.osc_damp = 0.0, 1.0
            return 0.0
        if upm < s.timed_min_start * target:
            self.combo_ms, self.pause = now_ms, False
        if self.pause:
            if now_ms - self.combo_ms > s.timed_pause_ms:
                self.combo_ms, self.pause = now_ms, False
            return 0.0
        if now_ms - self.combo_ms > s.timed_adjust_ms:
            above = upm > target
            self.osc_damp = max(self.osc_damp * 0.7, 0.1) if above != self.last_above else \
                min(self.osc_damp * 1.1, 1.0)
            self.last_above = above
            self.combo_ms, self.pause = now_ms, True
            return 0.0
        if manual_pwm is not None:
            return _clip(manual_pwm, -s.max_pwm, s.max_pwm)
        return self._valve(now_ms, s, target, upm, enabled, samples) * self.osc_damp


@dataclass
class FlowMeter:
    """The flow sensor and ``GetUPM``: pulses at ``meter_cal`` per unit from the true flow, Hz smoothed,
    units per minute; accumulated pulses for the quantity."""

    hz: float = 0.0
    upm: float = 0.0
    total_pulses: int = 0
    samples: int = 0
    _fraction: float = 0.0
    _last_pulse_ms: int = -FLOW_TIMEOUT_MS - 1

    def step(self, now_ms: int, flow_upm: float, meter_cal: float, any_on: bool, s: PidSettings) -> None:
        """One 50 ms loop of flow `flow_upm` [units/min] through the meter."""
        true_hz = flow_upm * meter_cal / 60.0 if meter_cal > 0 else 0.0
        pulses = 0
        if any_on and s.pulse_min_hz < true_hz < s.pulse_max_hz:
            self._fraction += true_hz * LOOP_MS / 1000.0
            pulses = int(self._fraction)
            self._fraction -= pulses
        if pulses:
            self.total_pulses += pulses
            self._last_pulse_ms = now_ms
            in_window = int(true_hz * s.sample_window_cs / 100.0)
            self.samples = min(MAX_SAMPLES, max(in_window, MIN_MEDIAN_SAMPLES))
            self.hz = true_hz * 0.8 + self.hz * 0.2
            self.upm = 60.0 * self.hz / meter_cal
        elif now_ms - self._last_pulse_ms > FLOW_TIMEOUT_MS or not any_on:
            self.hz = self.upm = 0.0
            self.samples = 0

    def quantity(self, meter_cal: float) -> float:
        """Units counted so far (``TotalPulses / MeterCal``)."""
        return self.total_pulses / meter_cal if meter_cal > 0 else 0.0


class _HeldCurrent:
    """A vrsim controller that holds the current the module's driver sets (`controller.interface`)."""

    def __init__(self):
        self.current_a = 0.0

    def step(self, target_rpm, measured_rpm):
        return np.array((self.current_a,))

    def step_one(self, target_rpm: float, measured_rpm: float) -> float:
        return self.current_a

    def reset(self) -> None:
        self.current_a = 0.0

    def state(self) -> dict:
        return {"current_a": self.current_a}

    def set_state(self, state: dict) -> None:
        self.current_a = float(state["current_a"])


class DrivePlant:
    """One sensor's drive: the module's PWM through its actuator onto vrsim's plant loop
    (`controller.PlantLoop`, the scenario's machine: `services.sim.core.machine_plant`), 50 ms a step.

    A valve type's PWM moves a motorized valve whose opening (0-1, full stroke in `valve_travel_s`)
    sets the plant's current within its range; a motor or fan's PWM sets it directly (PWM / 255 of the
    range). The flow is the plant's sensor reading (its speed sensor's delay and the machine's dead
    time) times `units_per_rev` (units per loop revolution: kg per shaft revolution, or per litre).
    """

    def __init__(self, plant: PlantParams, units_per_rev: float, plant_step_s: float = 0.001,
                 valve_travel_s: float = VALVE_TRAVEL_S):
        self._held = _HeldCurrent()
        self.loop = PlantLoop(LoopInfo(plant, LOOP_MS / 1000.0, plant_step_s), self._held, 1)
        self.units_per_rev = units_per_rev
        self.valve_travel_s = valve_travel_s
        self._lo, self._hi = plant.current_min_a, plant.current_max_a
        self.opening = 0.0
        self.flow_upm = 0.0     # what the flow meter sees [units/min]
        self.shaft_rpm = self.shaft_rev = self.current_a = 0.0

    def step(self, pwm: float, control_type: int) -> None:
        """Hold `pwm` (-255..255) for 50 ms."""
        if control_type in (MOTOR, FAN):
            share = max(pwm, 0.0) / 255.0
        elif control_type == MOTOR_WEIGHTS:   # the firmware drives no output for it
            share = 0.0
        else:
            stroke = pwm / 255.0 * (LOOP_MS / 1000.0) / self.valve_travel_s
            self.opening = share = _clip(self.opening + stroke, 0.0, 1.0)
        self._held.current_a = self._lo + share * (self._hi - self._lo)
        out = self.loop.step(0.0)
        self.shaft_rpm, self.shaft_rev = float(out.shaft_rpm[0]), float(out.shaft_rev[0])
        self.current_a = float(out.current_a[0])
        self.flow_upm = max(float(out.measured_rpm[0]), 0.0) * self.units_per_rev


@dataclass
class SensorChannel:
    """One sensor (product) of a module: what the app last sent it and the firmware's state."""

    plant: DrivePlant
    settings: PidSettings = field(default_factory=PidSettings)
    command: RateCommand | None = None
    comm_ms: int = -COMM_TIMEOUT_MS - 1
    auto_on: bool = True
    meter: FlowMeter = field(default_factory=FlowMeter)
    pid: FirmwarePid = field(default_factory=FirmwarePid)
    pwm: float = 0.0            # Sensor[i].PWM, what PGN 32400 reports
    output_pwm: float = 0.0     # what AdjustFlow drove
    connected: bool = False
    pid_enabled: bool = False
    applying: bool = False

    @property
    def target_upm(self) -> float:
        return self.command.target_upm if self.command is not None else 0.0

    @property
    def control_type(self) -> int:
        return self.command.control_type if self.command is not None else VALVE

    @property
    def meter_cal(self) -> float:
        return self.command.meter_cal if self.command is not None else 0.0


class RateModule:
    """A rate module (module ID 0-7) with its sensors, stepped every `LOOP_MS` by `tick`.

    Parameters
    ----------
    module_id : int
    plants : list of DrivePlant
        One per sensor (sensor IDs 0, 1, ...).
    """

    def __init__(self, module_id: int, plants: list[DrivePlant]):
        self.module_id = module_id
        self.sensors = [SensorChannel(plant=p) for p in plants]
        self.relays = RelayCommand(module_id, 0, 0, 0, 255)
        self.master_on = False
        self.pid_logging = False

    def any_section_on(self) -> bool:
        return self.relays.any_section_on()

    def has_sensor(self, sensor: int) -> bool:
        return 0 <= sensor < len(self.sensors)

    def apply(self, message, now_ms: int) -> None:
        """Take a decoded PGN 32500/32501/32502 for this module (its sensor checked by the caller)."""
        if isinstance(message, RelayCommand):
            self.relays = message
        elif isinstance(message, PidSettings):
            self.sensors[message.sensor].settings = message
        elif isinstance(message, RateCommand):
            ch = self.sensors[message.sensor]
            if message.reset_quantity:
                ch.meter.total_pulses = 0
            ch.command, ch.comm_ms, ch.auto_on = message, now_ms, message.auto_on
            self.master_on, self.pid_logging = message.master_on, message.pid_logging

    def tick(self, now_ms: int) -> None:
        """One 50 ms loop of the firmware and the plant."""
        any_on = self.any_section_on()
        for ch in self.sensors:
            ch.connected = now_ms - ch.comm_ms < COMM_TIMEOUT_MS
            ch.pid_enabled = ch.connected and ch.auto_on and self.master_on and any_on and ch.target_upm > 0
            ch.applying = self.master_on and (ch.target_upm > 0 or not ch.auto_on)
            ch.meter.step(now_ms, ch.plant.flow_upm, ch.meter_cal, any_on, ch.settings)
            manual = ch.command.manual_pwm if ch.command is not None else 0
            if ch.auto_on:
                ch.pwm = ch.pid.step(now_ms, ch.settings, ch.control_type, ch.target_upm, ch.meter.upm,
                                     ch.pid_enabled, ch.meter.samples)
            else:
                ch.pwm = ch.pid.manual(now_ms, ch.settings, ch.control_type, ch.target_upm, ch.meter.upm,
                                       manual)
            ch.output_pwm = self._drive(ch)
            ch.plant.step(ch.output_pwm, ch.control_type)

    @staticmethod
    def _drive(ch: SensorChannel) -> float:
        """``AdjustFlow``: the PWM the actuator gets."""
        pwm = _clip(ch.pwm, -255.0, 255.0)
        kind = ch.control_type
        if kind == VALVE:
            return pwm if ch.connected else 0.0
        if kind in (MOTOR, FAN):
            return pwm if ch.connected and ch.applying else 0.0
        if kind in (COMBO_CLOSE, TIMED_COMBO):
            return pwm if ch.connected and ch.applying else -255.0
        return ch.output_pwm

    def reports(self) -> list[RateReport]:
        """The PGN 32400 of each sensor, as ``SendComm`` fills it."""
        return [RateReport(self.module_id, i, ch.meter.upm, ch.meter.quantity(ch.meter_cal), int(ch.pwm),
                           ch.connected, False, ch.meter.hz) for i, ch in enumerate(self.sensors)]

    def pid_logs(self) -> list[PidLog]:
        """The PID samples taken since the last call (PGN 32402; sent only while the app asks)."""
        out = []
        for i, ch in enumerate(self.sensors):
            sample, ch.pid.sample = ch.pid.sample, None
            if sample is not None and "pwm" in sample and self.pid_logging:
                out.append(PidLog(self.module_id, i, **sample))
        return out
