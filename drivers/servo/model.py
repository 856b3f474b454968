"""An X-series servo array in position control, vectorised over joints: firmware, motor, gearbox.

One model for every place the bench needs a servo's behaviour: each step runs, for all
joints at once (numpy, no loop per joint),

1. the firmware's profile (Profile Velocity / Acceleration, a trapezoid in ticks; 0 means
   unlimited), then its position PID on the integer encoder reading, in firmware units
   (KPP = P/128, P/256 on an XL330; KPI = I/65536, KPD = D/16 per 1 ms sample), the output limited to the PWM
   Limit (885 = 100 %), an optional deadband (ticks) where a worn servo stops correcting;
2. the motor: V = PWM/885 · V_in, I = (V − Ke·ω)/R clamped to ±Current Limit, τ = Kt·I;
3. the gearbox: friction of level τ_c + (τ_s − τ_c)·e^{−|ω/ω_s|^α} (Coulomb τ_c, Stribeck
   peak τ_s, Stribeck velocity ω_s, exponent α = 2 unless set) plus the friction of the torque
   the gearbox carries: |k_e·τ_e − k_m·τ_m| (τ_m the motor's torque, τ_e the load's, e.g.
   gravity), a part of it fading with the Stribeck curve, and BAM's quadratic terms (the
   load-dependent laws m3–m6 of Rhoban's "Better Actuator Models", measured on real
   Dynamixels); then viscous b·ω, and the armature (reflected rotor inertia) for the
   integrator that moves the joints (the laws: :mod:`drivers.servo.friction`, the integrator:
   :mod:`drivers.servo.joints`).

The supply (:attr:`ServoArray.supply`) is a register-like array the owner may set every step:
a log's measured input voltage drives the motor where it has one (a sagging supply weakens
the motor under load).

Units: goals and readings in SI at the output shaft (rad, rad/s); ticks and PWM units stay
inside this module and ``drivers/``. The parameters come from the datasheet
(:meth:`ServoParams.datasheet`, the control table's motor figures and the config's gains) or
from an identified model file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Sequence

import numpy as np

from drivers.dynamixel.control_table import model_spec, x_series_table

__all__ = ["FIRMWARE_PERIOD_S", "LOAD_FRICTION_FIELDS", "ServoArray", "ServoParams", "Transmission"]

#: The firmware's control loop period (s): the PID gains are per sample of this length.
FIRMWARE_PERIOD_S = 0.001


#: The load-dependent friction coefficients (dimensionless, 0: none): Coulomb-like, at rest
#: (fading with the Stribeck curve) and quadratic (1/(N·m)), each on the motor's and the load's torque.
LOAD_FRICTION_FIELDS = ("load_motor", "load_external", "load_stribeck_motor", "load_stribeck_external",
                        "load_quad_motor", "load_quad_external")

#: Optional fields and the value they take when not given (per joint).
_OPTIONAL_DEFAULTS = {"deadband_ticks": 0.0, "amps_per_unit": 0.0, "p_gain_divisor": 128.0,
                      "stribeck_alpha": 2.0, **{f: 0.0 for f in LOAD_FRICTION_FIELDS}}


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
    #: A per Goal/Present Current unit (the current-based position mode's PID output unit).
    amps_per_unit: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: The firmware's P divisor: PWM units per tick of error = P / divisor (128, the XL330's 256).
    p_gain_divisor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: Exponent of the Stribeck curve e^{-|ω/ω_s|^α}.
    stribeck_alpha: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Load-dependent friction (see LOAD_FRICTION_FIELDS), 0 where the gearbox has none.
    load_motor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_external: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_stribeck_motor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_stribeck_external: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_quad_motor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_quad_external: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        # an optional field left empty takes its default on every joint
        n = int(np.asarray(self.kt).shape[0])
        for name, default in _OPTIONAL_DEFAULTS.items():
            if np.asarray(getattr(self, name)).size == 0:
                object.__setattr__(self, name, np.full(n, default))

    @cached_property
    def has_load_friction(self) -> bool:
        """Whether any joint's friction grows with the torque its gearbox carries."""
        return any(bool(np.any(getattr(self, f) != 0.0)) for f in LOAD_FRICTION_FIELDS)

    @cached_property
    def has_dry_friction(self) -> bool:
        """Whether any joint's gearbox has dry friction (Coulomb, a Stribeck peak, load-dependent)."""
        return bool((self.coulomb > 0).any() or (self.stribeck > 0).any() or self.has_load_friction)

    @cached_property
    def _friction_terms(self) -> tuple[bool, bool, bool, bool]:
        """Which terms of :func:`~drivers.servo.friction.friction_level` any joint has: Stribeck peak,
        load, load at rest, quadratic (worked out once: the friction is evaluated every step)."""
        nonzero = lambda *names: any(bool(np.any(getattr(self, f) != 0.0)) for f in names)  # noqa: E731
        return (bool(np.any(self.stribeck > 0.0)), nonzero("load_motor", "load_external"),
                nonzero("load_stribeck_motor", "load_stribeck_external"),
                nonzero("load_quad_motor", "load_quad_external"))

    @cached_property
    def _stribeck_alpha(self) -> float | np.ndarray:
        """The Stribeck exponents as :func:`~drivers.servo.friction.stribeck_fade` takes them: the
        number 2.0 where every joint's is 2 (its square, not a power), else the array."""
        return 2.0 if bool(np.all(self.stribeck_alpha == 2.0)) else self.stribeck_alpha

    @property
    def n(self) -> int:
        return int(self.kt.shape[0])

    @classmethod
    def datasheet(cls, models: Sequence[int], *, gains: Sequence[tuple[int | None, int | None, int | None]] | None = None,
                  supply_voltage: float = 12.0, current_limit_a: Sequence[float | None] | None = None,
                  armature: float | Sequence[float] = 0.012, coulomb: float | Sequence[float] = 0.0,
                  viscous: float | Sequence[float] = 0.0, stribeck: float | Sequence[float] = 0.0,
                  stribeck_velocity: float | Sequence[float] = 0.1,
                  deadband_ticks: float | Sequence[float] = 0.0) -> "ServoParams":
        """Parameters from the control table's motor figures and factory registers, one per model
        number; ``gains`` (P, I, D register values, None: factory) and the current limits override
        the defaults."""
        specs = [model_spec(int(m)) for m in models]
        n = len(specs)
        table = [s.table for s in specs]
        reg = lambda name: np.array([float(t[name].default) if name in t else math.nan for t in table])  # noqa: E731
        factory = [(t["Position P Gain"].default, t["Position I Gain"].default, t["Position D Gain"].default)
                   for t in table]
        # a gain left None keeps the model's factory value
        g = np.array([[f if v is None else v for v, f in zip(given, fac)]
                      for given, fac in zip(gains or factory, factory)], dtype=float).reshape(n, 3)
        unit = np.array([s.amps_per_unit for s in specs])
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
            deadband_ticks=_arr(deadband_ticks, n), amps_per_unit=unit,
            p_gain_divisor=np.array([float(s.extra.get("p_gain_divisor", 128.0)) for s in specs]))

    def take(self, joints) -> "ServoParams":
        """The parameters of some joints (an index or index array; an int gives one slot): one
        servo's for an emulated servo, a joint's repeated for identification's slots."""
        index = np.atleast_1d(np.asarray(joints))
        return ServoParams(**{f: getattr(self, f)[index] for f in ServoParams.__dataclass_fields__})

    def with_(self, **changes) -> "ServoParams":
        """A copy with some fields replaced (scalars broadcast to every joint)."""
        return replace(self, **{k: _arr(v, self.n) for k, v in changes.items()})

    def with_motor_scale(self, kt_scale) -> "ServoParams":
        """The same servos with Kt and Ke (one constant in SI) scaled per joint: a stronger or
        weaker motor than the datasheet's."""
        return replace(self, kt=self.kt * _arr(kt_scale, self.n), ke=self.ke * _arr(kt_scale, self.n))

    def with_friction_scale(self, scale) -> "ServoParams":
        """The same servos with every friction level scaled per joint (Coulomb, Stribeck peak, viscous
        and the load-dependent coefficients; the Stribeck curve's shape kept): each term of the law is
        linear in its level, so the friction is ``scale`` × this one at any speed and load (a gearbox
        whose friction drifts as it wears or its grease thickens)."""
        s = _arr(scale, self.n)
        levels = ("coulomb", "stribeck", "viscous", *LOAD_FRICTION_FIELDS)
        return replace(self, **{f: getattr(self, f) * s for f in levels})

    @property
    def back_emf_damping(self) -> np.ndarray:
        """Kt·Ke/R (N·m·s/rad): the damping the motor's back-EMF gives at a fixed PWM."""
        return self.kt * self.ke / self.resistance


@dataclass(frozen=True)
class Transmission:
    """Joints behind the servos' shafts (joint = offset + ratio · shaft), per joint: the encoder's
    ticks per joint unit and its reading at joint value 0 (+ ½, for the rounding), Kt at the joint."""

    ratio: np.ndarray
    offset: np.ndarray
    tick: np.ndarray
    zero: np.ndarray
    kt: np.ndarray


class ServoArray:
    """The firmware and motors of n servos, stepped together (the emulated rig's servos and the
    simulator's are both one of these).

    The position loop (profile and PID, in ticks) runs on the slots in a position mode; a slot
    may instead be given a PWM (velocity and PWM modes) or a current to drive (current mode),
    and a current-based position slot turns the PID's output into a current first, as the
    firmware does. The firmware settings the registers hold (gains, limits, supply, mode) are
    arrays the owner may change between steps: :attr:`gains`, :attr:`pwm_limit`,
    :attr:`pwm_cap`, :attr:`current_limit`, :attr:`supply`, :attr:`current_based`,
    :attr:`goal_current`, :attr:`deadband`.
    """

    def __init__(self, params: ServoParams) -> None:
        self.params = params
        n = params.n
        # register units, from the control table: rad per tick, PWM units at 100 % duty,
        # rad/s per Profile Velocity unit, rad/s² per Profile Acceleration unit
        table = x_series_table()
        self._rad_per_tick = table["Present Position"].scale
        self._pwm_full = table["Present PWM"].from_si(1.0)
        self._velocity_unit = table["Profile Velocity"].scale
        self._accel_unit = table["Profile Acceleration"].scale
        # the registers' firmware settings
        self.gains = np.stack([params.position_p, params.position_i, params.position_d], axis=1).astype(float)
        self.p_divisor = params.p_gain_divisor.astype(float).copy()  # the firmware's KPP = P / divisor
        self.pwm_limit = params.pwm_limit.astype(float).copy()  # PWM Limit: bounds the integrator
        self.pwm_cap = self.pwm_limit.copy()  # min(PWM Limit, |Goal PWM|): bounds the output
        self.current_limit = params.current_limit.astype(float).copy()
        self.supply = params.supply_voltage.astype(float).copy()
        self.deadband = params.deadband_ticks.astype(float).copy()
        self.current_based = np.zeros(n, dtype=bool)
        self.goal_current = np.full(n, np.inf)  # |Goal Current| (units) in current-based position mode
        self.amps_per_unit = params.amps_per_unit.astype(float).copy()
        self.profile_velocity = params.profile_velocity.astype(float).copy()
        self.profile_acceleration = params.profile_acceleration.astype(float).copy()
        # the firmware's state, in ticks
        self.traj = np.zeros(n)
        self.traj_vel = np.zeros(n)
        self.integral = np.zeros(n)
        self.prev_error = np.zeros(n)
        self.has_prev = np.zeros(n, dtype=bool)
        self.vmax = np.full(n, np.inf)
        self.amax = np.full(n, np.inf)
        self.goal = np.zeros(n)
        self.ongoing = np.zeros(n, dtype=bool)
        # what the owner hands in for one step
        self.present = np.zeros(n)
        self.omega = np.zeros(n)
        self.pid = np.ones(n, dtype=bool)
        self.pwm_in = np.full(n, np.nan)
        self.current_in = np.full(n, np.nan)
        # what comes out
        self.current = np.zeros(n)
        self.pwm = np.zeros(n)
        #: Bumped by every setter that changes what a fused loop works out once (drivers.servo.fast).
        self.version = 0

    def set_current_limit(self, slot, amps: float) -> None:
        """A servo's Current Limit (A), as a register write sets it."""
        self.current_limit[slot] = amps
        self.version += 1

    def snapshot(self) -> dict[str, object]:
        """The array's whole state (registers and firmware), copied: :meth:`restore` puts it back."""
        return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in vars(self).items()}

    def restore(self, snapshot: dict[str, object]) -> None:
        """Back to a :meth:`snapshot` (copied again: one snapshot may be restored many times)."""
        version = self.version
        vars(self).update({k: v.copy() if isinstance(v, np.ndarray) else v for k, v in snapshot.items()})
        self.version = version + 1

    @classmethod
    def gather(cls, servos) -> "ServoArray":
        """One array for several emulated servos (each servo then moves its loop into a slot)."""
        params = [s._bank.params for s in servos]
        fields = {f: np.concatenate([getattr(p, f) for p in params]) for f in ServoParams.__dataclass_fields__}
        return cls(ServoParams(**fields))

    def ticks(self, position: np.ndarray) -> np.ndarray:
        """Encoder reading (integer ticks, 0 at shaft angle 0) of shaft angles (rad)."""
        return np.floor(np.asarray(position, dtype=float) / self._rad_per_tick + 0.5)

    # -- per slot: what a servo does on a register write ---------------------------------
    def reset_slot(self, i, present) -> None:
        """Torque on (or a reboot): trajectory at ``present`` ticks, PID state cleared, no profile."""
        self.version += 1
        self.traj[i] = present
        self.traj_vel[i] = 0.0
        self.integral[i] = 0.0
        self.has_prev[i] = False
        self.vmax[i] = np.inf
        self.amax[i] = np.inf
        self.ongoing[i] = False

    def track_slot(self, i, present) -> None:
        """Torque off: the trajectory follows the encoder, nothing planned."""
        self.traj[i] = present
        self.traj_vel[i] = 0.0
        self.ongoing[i] = False

    def plan_slot(self, i, goal, vmax, amax) -> None:
        """A new goal (ticks) with its profile limits (ticks/s, ticks/s²; inf: none)."""
        self.goal[i] = goal
        self.vmax[i] = vmax
        self.amax[i] = amax
        self.ongoing[i] = True

    # -- the simulator's side: SI in, torque out -----------------------------------------
    def reset(self, position: np.ndarray) -> None:
        """Torque on at ``position`` (rad): goal = trajectory = present, PID state cleared."""
        present = self.ticks(position)
        self.reset_slot(slice(None), present)
        self.goal[:] = present

    def hold(self, position: np.ndarray, torque: np.ndarray) -> None:
        """Torque on at ``position``, settled: the integrators already give the motor ``torque``
        (N·m at the shaft, e.g. against gravity), as in a servo that has held its pose a while."""
        self.reset(position)
        p = self.params
        pwm = np.asarray(torque, dtype=float) / p.kt * p.resistance / np.maximum(self.supply, 1e-6)
        self.integral = np.clip(pwm * self._pwm_full, -self.pwm_limit, self.pwm_limit)
        self.current = np.asarray(torque, dtype=float) / p.kt

    def resume(self, position: np.ndarray, velocity: np.ndarray, goal: np.ndarray, current: np.ndarray) -> None:
        """Torque on mid-motion, as a log found the servo: trajectory at ``goal`` (rad, no profile
        under way), the derivative primed with the present error, and the integrator holding what
        the PID must add to the proportional term to drive ``current`` (A) at ``velocity`` (rad/s)."""
        present = self.ticks(position)
        goal_ticks = np.round(np.asarray(goal, dtype=float) / self._rad_per_tick)
        self.reset_slot(slice(None), goal_ticks)
        self.goal[:] = goal_ticks
        error = goal_ticks - present
        self.prev_error = error.astype(float)
        self.has_prev[:] = True
        p = self.params
        vin = np.maximum(self.supply, 1e-6)
        pwm = (np.asarray(current, dtype=float) * p.resistance + p.ke * np.asarray(velocity, dtype=float)) / vin
        self.integral = np.clip(pwm * self._pwm_full - (self.gains[:, 0] / self.p_divisor) * error,
                                -self.pwm_limit, self.pwm_limit)
        self.current = np.asarray(current, dtype=float).copy()
        self.pwm = pwm * self._pwm_full

    def set_goal(self, goal: np.ndarray) -> None:
        """New goal positions (rad): ticks as the bus writes them, with the profile planned."""
        goal_ticks = np.round(np.asarray(goal, dtype=float) / self._rad_per_tick)
        changed = goal_ticks != self.goal
        if not changed.any():
            return
        pv, pa = self.profile_velocity, self.profile_acceleration
        vmax = np.where(pv == 0, np.inf, pv * self._velocity_unit / self._rad_per_tick)
        amax = np.where((pv == 0) | (pa == 0), np.inf, pa * self._accel_unit / self._rad_per_tick)
        idx = np.flatnonzero(changed)
        self.plan_slot(idx, goal_ticks[idx], vmax[idx], amax[idx])

    def transmission(self, ratio: Sequence[float] | np.ndarray,
                     offset: Sequence[float] | np.ndarray) -> "Transmission":
        """The joints behind the shafts (joint = offset + ratio · shaft), its constants worked out once."""
        ratio, offset = np.asarray(ratio, dtype=float), np.asarray(offset, dtype=float)
        tick = (1.0 / self._rad_per_tick) / ratio
        return Transmission(ratio, offset, tick, 0.5 - offset * tick, self.params.kt / ratio)

    def step_joint(self, dt: float, q: np.ndarray, qd: np.ndarray,
                   transmission: "Transmission") -> np.ndarray:
        """One firmware sample from the joints' values and speeds behind ``transmission``: the
        encoder read from the joint value, the torques at the joints (shaft torque / ratio)."""
        self.present = np.floor(q * transmission.tick + transmission.zero)
        self.omega = qd / transmission.ratio
        self.step_ticks(dt)
        return transmission.kt * self.current

    def step(self, dt: float, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """One firmware sample of ``dt`` s at the shaft state (rad, rad/s); the motor torque (N·m)."""
        self.present = np.floor(position * (1.0 / self._rad_per_tick) + 0.5)
        self.omega = velocity
        self.step_ticks(dt)
        return self.params.kt * self.current

    # -- one step for every slot -----------------------------------------------------------
    def _advance_profile(self, dt: float, pid: np.ndarray, every: bool) -> None:
        goal, traj, vel, vmax, amax = self.goal, self.traj, self.traj_vel, self.vmax, self.amax
        if np.isinf(vmax).all():  # no profile anywhere (the bench's Profile Velocity 0): the goal at once
            if every:
                self.traj = goal.copy()
                self.traj_vel[:] = 0.0
                self.ongoing[:] = False
            else:
                self.traj = np.where(pid, goal, traj)
                self.traj_vel = np.where(pid, 0.0, vel)
                self.ongoing = np.where(pid, False, self.ongoing)
            return
        remaining = goal - traj
        direction = np.sign(remaining)
        with np.errstate(invalid="ignore"):  # inf · 0 where a joint has no profile or no distance left
            target = direction * np.minimum(vmax, np.sqrt(2.0 * amax * np.abs(remaining)))
            accel = np.clip(target - vel, -amax * dt, amax * dt)
            new_vel = np.where(np.isinf(amax), direction * vmax, vel + np.nan_to_num(accel))
            step = new_vel * dt
        arrive = (np.isinf(vmax) | (remaining == 0.0) | (np.abs(step) >= np.abs(remaining))
                  | (np.abs(remaining) < 1e-3))
        new_traj = np.where(arrive, goal, traj + np.where(arrive, 0.0, step))
        new_vel = np.where(arrive, 0.0, new_vel)
        self.traj = np.where(pid, new_traj, traj)
        self.traj_vel = np.where(pid, new_vel, vel)
        self.ongoing = np.where(pid, new_traj != goal, self.ongoing)

    def step_ticks(self, dt: float) -> None:
        """One firmware sample for every slot from :attr:`present` (ticks) and :attr:`omega`
        (rad/s); fills :attr:`pwm` and :attr:`current` (A)."""
        p, pid, present, omega = self.params, self.pid, self.present, self.omega
        every = bool(pid.all())
        self._advance_profile(dt, pid, every)
        error = self.traj - present
        samples = dt / FIRMWARE_PERIOD_S
        lim = self.pwm_limit
        g = self.gains
        integral = np.minimum(np.maximum(self.integral + (g[:, 1] * (samples / 65536.0)) * error, -lim), lim)
        u = (g[:, 0] / self.p_divisor) * error + integral
        if self.has_prev.all():
            u += (g[:, 2] / (16.0 * samples)) * (error - self.prev_error)
        else:
            u += (g[:, 2] / 16.0) * np.where(self.has_prev, (error - self.prev_error) / samples, 0.0)
        if (self.deadband > 0).any():
            held = (self.deadband > 0) & ~self.ongoing & (np.abs(self.goal - present) <= self.deadband)
            u = np.where(held, 0.0, u)
            integral = np.where(held, 0.0, integral)
        cap = self.pwm_cap
        pwm = np.minimum(np.maximum(u, -cap), cap)
        if every:
            self.integral, self.prev_error = integral, error
            self.has_prev[:] = True
            current_cmd = None
        else:
            self.integral = np.where(pid, integral, self.integral)
            self.prev_error = np.where(pid, error, self.prev_error)
            self.has_prev = self.has_prev | pid
            pwm = np.where(pid, pwm, np.nan_to_num(self.pwm_in))
            current_cmd = np.where(pid, np.nan, self.current_in)
        if self.current_based.any():
            cb = np.minimum(np.maximum(u, -self.goal_current), self.goal_current) * self.amps_per_unit
            mask = pid & self.current_based
            current_cmd = np.where(mask, cb, np.nan if current_cmd is None else current_cmd)
        vin = np.maximum(self.supply, 1e-6)
        if current_cmd is not None:
            commanded = np.isfinite(current_cmd)
            if commanded.any():
                needed = (np.nan_to_num(current_cmd) * p.resistance + p.ke * omega) / vin * self._pwm_full
                pwm = np.where(commanded, np.minimum(np.maximum(needed, -lim), lim), pwm)
        current = (pwm * (vin / self._pwm_full) - p.ke * omega) / p.resistance
        self.current = np.minimum(np.maximum(current, -self.current_limit), self.current_limit)
        self.pwm = pwm
