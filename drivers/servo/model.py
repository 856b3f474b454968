"""An X-series servo array in position control, vectorised over joints: firmware, motor, gearbox.

One model for every place the bench needs a servo's behaviour: each step runs, for all
joints at once (numpy, no loop per joint),

1. the firmware's profile (Profile Velocity / Acceleration, a trapezoid in ticks; 0 means
   unlimited), then its position PID on the integer encoder reading, in firmware units
   (KPP = P/128, KPI = I/65536, KPD = D/16 per 1 ms sample), the output limited to the PWM
   Limit (885 = 100 %), an optional deadband (ticks) where a worn servo stops correcting;
2. the motor: V = PWM/885 · V_in, I = (V − Ke·ω)/R clamped to ±Current Limit, τ = Kt·I;
3. the gearbox: friction τ_f(ω) = (τ_c + (τ_s − τ_c)·e^{−(ω/ω_s)²})·tanh(ω/ω_ε) + b·ω
   (Coulomb τ_c, Stribeck peak τ_s, Stribeck velocity ω_s, viscous b), and the armature
   (reflected rotor inertia) for the integrator that moves the joints.

Units: goals and readings in SI at the output shaft (rad, rad/s); ticks and PWM units stay
inside this module and ``drivers/``. The parameters come from the datasheet
(:meth:`ServoParams.datasheet`, the control table's motor figures and the config's gains) or
from an identified model file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from drivers.dynamixel.control_table import model_spec
from drivers.dynamixel.units import ACCEL_UNIT_RAD_S2, PWM_FULL_SCALE, RAD_PER_TICK, VELOCITY_UNIT_RAD_S

__all__ = ["FIRMWARE_PERIOD_S", "FRICTION_SMOOTHING_RAD_S", "ServoArray", "ServoParams", "friction_torque"]

#: The firmware's control loop period (s): the PID gains are per sample of this length.
FIRMWARE_PERIOD_S = 0.001
#: Velocity below which Coulomb friction is smoothed (rad/s): tanh(ω/ω_ε), as the plant integrates it.
FRICTION_SMOOTHING_RAD_S = 1e-3


def _arr(value, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()


@dataclass(frozen=True)
class ServoParams:
    """Per-joint parameters (arrays of n) of the servo array, SI at the output shaft.

    Gains are the control-table register values (firmware units); everything else is SI:
    Kt (N·m/A), Ke (V·s/rad), R (Ω), current limit (A, inf where the model has none),
    supply (V), friction (N·m, N·m·s/rad, rad/s), armature (kg·m²).
    """

    kt: np.ndarray
    ke: np.ndarray
    resistance: np.ndarray
    current_limit: np.ndarray
    supply_voltage: np.ndarray
    pwm_limit: np.ndarray
    position_p: np.ndarray
    position_i: np.ndarray
    position_d: np.ndarray
    profile_velocity: np.ndarray
    profile_acceleration: np.ndarray
    armature: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray
    stribeck: np.ndarray
    stribeck_velocity: np.ndarray
    deadband_ticks: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n(self) -> int:
        return int(self.kt.shape[0])

    @classmethod
    def datasheet(cls, models: Sequence[int], *, gains: Sequence[tuple[int, int, int]] | None = None,
                  supply_voltage: float = 12.0, current_limit_a: Sequence[float | None] | None = None,
                  armature: float | Sequence[float] = 0.012, coulomb: float | Sequence[float] = 0.0,
                  viscous: float | Sequence[float] = 0.0, stribeck: float | Sequence[float] = 0.0,
                  stribeck_velocity: float | Sequence[float] = 0.1,
                  deadband_ticks: float | Sequence[float] = 0.0) -> "ServoParams":
        """Parameters from the control table's motor figures and factory registers, one per model
        number; ``gains`` (P, I, D register values) and the current limits override the defaults."""
        specs = [model_spec(int(m)) for m in models]
        n = len(specs)
        table = [s.table for s in specs]
        reg = lambda name: np.array([float(t[name].default) if name in t else math.nan for t in table])  # noqa: E731
        if gains is None:
            gains = [(t["Position P Gain"].default, t["Position I Gain"].default, t["Position D Gain"].default)
                     for t in table]
        g = np.asarray(gains, dtype=float).reshape(n, 3)
        unit = np.array([s.current_unit or s.motor.stall_current / 1000.0 for s in specs])
        limit = np.where([s.senses_current for s in specs], reg("Current Limit") * unit, np.inf)
        if current_limit_a is not None:
            limit = np.array([lim if a is None else float(a) for lim, a in zip(limit, current_limit_a)])
        return cls(
            kt=np.array([s.motor.kt for s in specs]), ke=np.array([s.motor.ke for s in specs]),
            resistance=np.array([s.motor.resistance for s in specs]), current_limit=limit,
            supply_voltage=_arr(supply_voltage, n), pwm_limit=reg("PWM Limit"),
            position_p=g[:, 0], position_i=g[:, 1], position_d=g[:, 2],
            profile_velocity=np.zeros(n), profile_acceleration=np.zeros(n),
            armature=_arr(armature, n), coulomb=_arr(coulomb, n), viscous=_arr(viscous, n),
            stribeck=_arr(stribeck, n), stribeck_velocity=_arr(stribeck_velocity, n),
            deadband_ticks=_arr(deadband_ticks, n))

    def with_(self, **changes) -> "ServoParams":
        """A copy with some fields replaced (scalars broadcast to every joint)."""
        return replace(self, **{k: _arr(v, self.n) for k, v in changes.items()})

    def with_motor_scale(self, kt_scale) -> "ServoParams":
        """The same servos with Kt and Ke (one constant in SI) scaled per joint: a stronger or
        weaker motor than the datasheet's."""
        return replace(self, kt=self.kt * _arr(kt_scale, self.n), ke=self.ke * _arr(kt_scale, self.n))

    @property
    def back_emf_damping(self) -> np.ndarray:
        """Kt·Ke/R (N·m·s/rad): the damping the motor's back-EMF gives at a fixed PWM."""
        return self.kt * self.ke / self.resistance


def friction_torque(params: ServoParams, omega: np.ndarray) -> np.ndarray:
    """Gearbox friction at output speed ``omega`` (rad/s): Coulomb with a Stribeck peak, plus viscous."""
    ws = np.maximum(params.stribeck_velocity, 1e-9)
    level = params.coulomb + (params.stribeck - params.coulomb) * np.exp(-(omega / ws) ** 2)
    level = np.where(params.stribeck > 0.0, level, params.coulomb)
    return level * np.tanh(omega / FRICTION_SMOOTHING_RAD_S) + params.viscous * omega


class ServoArray:
    """The firmware and motors of n servos in position control, stepped together.

    :meth:`reset` starts the profile and the PID at the present positions (as a servo does at
    torque on); :meth:`step` takes the goals and the shaft state and returns the motor torque
    (N·m, before friction), the current (A) and the PWM (units of 885 = 100 %).
    """

    def __init__(self, params: ServoParams) -> None:
        self.params = params
        n = params.n
        self._kp = params.position_p / 128.0
        self._ki = params.position_i / 65536.0
        self._kd = params.position_d / 16.0
        self._traj = np.zeros(n)
        self._traj_vel = np.zeros(n)
        self._integral = np.zeros(n)
        self._prev_error = np.zeros(n)
        self._has_prev = np.zeros(n, dtype=bool)
        self._vmax = np.full(n, np.inf)
        self._amax = np.full(n, np.inf)
        self._goal = np.zeros(n)
        self.current = np.zeros(n)
        self.pwm = np.zeros(n)
        self._unlimited = True
        self._no_profile = np.zeros(n, dtype=bool)
        self._has_prev_all = False
        self._deadband = bool((params.deadband_ticks > 0).any())
        self._volts_per_pwm = np.maximum(params.supply_voltage, 1e-6) / PWM_FULL_SCALE

    @staticmethod
    def ticks(position: np.ndarray) -> np.ndarray:
        """Encoder reading (integer ticks, 0 at shaft angle 0) of shaft angles (rad)."""
        return np.floor(np.asarray(position, dtype=float) / RAD_PER_TICK + 0.5)

    def reset(self, position: np.ndarray) -> None:
        """Torque on at ``position`` (rad): goal = trajectory = present, PID state cleared."""
        present = self.ticks(position)
        self._traj[:] = present
        self._goal[:] = present
        self._traj_vel[:] = 0.0
        self._integral[:] = 0.0
        self._has_prev[:] = False
        self._has_prev_all = False
        self._vmax[:] = np.inf
        self._amax[:] = np.inf
        self._unlimited = True

    def hold(self, position: np.ndarray, torque: np.ndarray) -> None:
        """Torque on at ``position``, settled: the integrators already give the motor ``torque``
        (N·m at the shaft, e.g. against gravity), as in a servo that has held its pose a while."""
        self.reset(position)
        p = self.params
        pwm = np.asarray(torque, dtype=float) / p.kt * p.resistance / np.maximum(p.supply_voltage, 1e-6)
        self._integral = np.clip(pwm * PWM_FULL_SCALE, -p.pwm_limit, p.pwm_limit)

    def set_goal(self, goal: np.ndarray) -> None:
        """New goal positions (rad): ticks as the bus writes them, with the profile planned."""
        goal_ticks = np.round(np.asarray(goal, dtype=float) / RAD_PER_TICK)
        changed = goal_ticks != self._goal
        if not changed.any():
            return
        self._goal = np.where(changed, goal_ticks, self._goal)
        p = self.params
        pv, pa = p.profile_velocity, p.profile_acceleration
        vmax = np.where(pv == 0, np.inf, pv * VELOCITY_UNIT_RAD_S / RAD_PER_TICK)
        amax = np.where((pv == 0) | (pa == 0), np.inf, pa * ACCEL_UNIT_RAD_S2 / RAD_PER_TICK)
        self._vmax = np.where(changed, vmax, self._vmax)
        self._amax = np.where(changed, amax, self._amax)
        self._unlimited = bool(np.isinf(self._vmax).all())

    def _advance_profile(self, dt: float) -> np.ndarray:
        if self._unlimited:  # Profile Velocity 0 everywhere (the bench's setting): the goal at once
            self._traj = self._goal
            return self._no_profile
        goal, traj, vel = self._goal, self._traj, self._traj_vel
        remaining = goal - traj
        direction = np.sign(remaining)
        with np.errstate(invalid="ignore"):  # inf · 0 where a joint has no profile or no distance left
            target = direction * np.minimum(self._vmax, np.sqrt(2.0 * self._amax * np.abs(remaining)))
            accel = np.clip(target - vel, -self._amax * dt, self._amax * dt)
            vel = np.where(np.isinf(self._amax), direction * self._vmax, vel + np.nan_to_num(accel))
        step = vel * dt
        arrive = (np.isinf(self._vmax) | (remaining == 0.0) | (np.abs(step) >= np.abs(remaining))
                  | (np.abs(remaining) < 1e-3))
        self._traj = np.where(arrive, goal, traj + np.where(arrive, 0.0, step))
        self._traj_vel = np.where(arrive, 0.0, vel)
        return self._traj != goal  # profile still running

    def step(self, dt: float, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """One firmware sample of ``dt`` s at the shaft state (rad, rad/s); the motor torque (N·m)."""
        p = self.params
        present = np.floor(position * (1.0 / RAD_PER_TICK) + 0.5)
        ongoing = self._advance_profile(dt)
        error = self._traj - present
        samples = dt / FIRMWARE_PERIOD_S
        lim = p.pwm_limit
        integral = np.minimum(np.maximum(self._integral + self._ki * error * samples, -lim), lim)
        u = self._kp * error + integral
        if self._has_prev_all:
            u += self._kd * ((error - self._prev_error) / samples)
        else:
            u += self._kd * np.where(self._has_prev, (error - self._prev_error) / samples, 0.0)
            self._has_prev[:] = True
            self._has_prev_all = True
        self._prev_error = error
        pwm = np.minimum(np.maximum(u, -lim), lim)
        if self._deadband:
            held = (p.deadband_ticks > 0) & ~ongoing & (np.abs(self._goal - present) <= p.deadband_ticks)
            integral = np.where(held, 0.0, integral)
            pwm = np.where(held, 0.0, pwm)
        self._integral = integral
        current = (pwm * self._volts_per_pwm - p.ke * velocity) / p.resistance
        current = np.minimum(np.maximum(current, -p.current_limit), p.current_limit)
        self.pwm, self.current = pwm, current
        return p.kt * current
