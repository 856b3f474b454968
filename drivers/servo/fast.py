"""The firmware's position loop in its plain case, fused: what a simulator steps thousands of times.

:meth:`ServoArray.step <drivers.servo.model.ServoArray.step>` serves every mode a register
write can set (profiles, PWM and current modes, deadbands, a slot without its PID), and on
nine joints its checks for them cost more than its arithmetic. A simulator whose servos all
run the position PID on the integer encoder, with no profile (Profile Velocity 0, as the
bench writes it), no deadband and no current-based mode, needs only the PID and the motor:
:class:`PositionLoop` runs exactly that, with the gains turned into per-sample constants once,
in the very operations and order of :meth:`ServoArray.step_ticks` (the same numbers, bit for
bit), on the array's own state, so the general step can take over at any sample. It is the
core's one fused loop: every simulator that steps a servo array fast steps this, from the shaft
(:meth:`PositionLoop.step`) or from the joints (:meth:`PositionLoop.step_joint`, the encoder read
through the transmission), and ``tests/test_servo_fast.py`` holds each bit-equal to the array's
own step (:meth:`ServoArray.step`, :meth:`ServoArray.step_joint`).
"""

from __future__ import annotations

import numpy as np

from drivers.servo.model import FIRMWARE_PERIOD_S, ServoArray

__all__ = ["PositionLoop"]


class PositionLoop:
    """The position PID and motor of every slot of ``servos`` at a sample of ``dt`` s.

    :attr:`fused` says whether the plain case holds; :meth:`refresh` works the constants out
    again; the array's setters (:meth:`ServoArray.set_current_limit`, the resets, :meth:`ServoArray.restore`)
    bump its :attr:`ServoArray.version` and the next step refreshes by itself (an owner writing a
    register array in place calls :meth:`refresh`); a new :attr:`ServoArray.supply` array is taken
    as it comes. Outside the plain case,
    and on the first sample after a reset (the derivative has no previous error yet),
    :meth:`step` is :meth:`ServoArray.step`.
    """

    def __init__(self, servos: ServoArray, dt: float, ratio: np.ndarray | None = None,
                 offset: np.ndarray | None = None) -> None:
        self.servos = servos
        self.dt = float(dt)
        # the transmissions (joint = offset + ratio · shaft) for step_joint
        self._ratio = np.ones(servos.params.n) if ratio is None else np.asarray(ratio, dtype=float)
        self._offset = np.zeros(servos.params.n) if offset is None else np.asarray(offset, dtype=float)
        self.refresh()

    def refresh(self) -> None:
        """Constants from the registers as they are now; whether the plain case holds."""
        s, p = self.servos, self.servos.params
        self._version = s.version
        self.fused = bool(s.pid.all() and not s.profile_velocity.any() and np.isinf(s.vmax).all()
                          and not (s.deadband > 0).any() and not s.current_based.any())
        self._primed = bool(s.has_prev.all())
        samples = self.dt / FIRMWARE_PERIOD_S
        g = s.gains
        self._inv_tick = 1.0 / s._rad_per_tick
        self._rad_per_tick = s._rad_per_tick
        self._ki = g[:, 1] * (samples / 65536.0)
        self._kp = g[:, 0] / s.p_divisor
        self._kd = g[:, 2] / (16.0 * samples)
        self._lim, self._neg_lim = s.pwm_limit.copy(), -s.pwm_limit
        self._cap, self._neg_cap = s.pwm_cap.copy(), -s.pwm_cap
        self._supply = s.supply
        self._volts = np.maximum(s.supply, 1e-6) / s._pwm_full
        self._ke, self._resistance, self._kt = p.ke, p.resistance, p.kt
        self._ilim, self._neg_ilim = s.current_limit.copy(), -s.current_limit
        # the same through the transmissions: ticks from joint values, torque at the joint
        self._transmission = s.transmission(self._ratio, self._offset)
        self._joint_tick, self._joint_zero = self._transmission.tick, self._transmission.zero
        self._joint_kt = self._transmission.kt
        self._goal_zero = self._joint_zero - 0.5  # a joint goal's ticks: goal · tick + this, rounded

    def joint_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """The loop's proportional and derivative gains as torques at the joints, per joint value
        (N·m/rad or N/m) and per joint speed (N·m·s/rad or N·s/m), the PWM and current unsaturated:
        what an integrator stepping the loop coarser than the firmware takes implicitly."""
        per_tick = np.abs(self._joint_kt * self._joint_tick) * self._volts / self._resistance  # 1/ratio²: sign-free
        return per_tick * self._kp, per_tick * self._kd * self.dt

    def unsaturated(self) -> np.ndarray:
        """Per slot, whether the last sample's PWM and current were inside their limits (where
        :meth:`joint_gains` hold)."""
        s = self.servos
        return (np.abs(s.pwm) < self._cap) & (np.abs(s.current) < self._ilim)

    def set_goal(self, goal: np.ndarray) -> None:
        """New goal positions (rad), in ticks as the bus writes them: with no profile the
        trajectory is the goal at the next sample."""
        s = self.servos
        if s.version != self._version:
            self.refresh()
        if not self.fused:
            s.set_goal(goal)
            return
        ticks = np.rint(goal / self._rad_per_tick)  # np.round's own rounding, without its wrapper
        s.goal = ticks
        s.traj = ticks.copy()

    def set_goal_joint(self, goal: np.ndarray) -> None:
        """:meth:`set_goal` from joint values, through the transmissions."""
        if self.servos.version != self._version or not self.fused:
            self.set_goal((goal - self._offset) / self._ratio)
            return
        ticks = self._goal_ticks(goal)
        self.servos.goal = ticks
        self.servos.traj = ticks.copy()

    def _goal_ticks(self, goal: np.ndarray) -> np.ndarray:
        """Joint goals in the ticks the bus writes (a fresh array)."""
        ticks = np.multiply(goal, self._joint_tick)
        ticks += self._goal_zero
        return np.rint(ticks, out=ticks)

    def step(self, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """One firmware sample at the shaft state (rad, rad/s); the motor torque (N·m)."""
        s = self.servos
        if s.version != self._version:  # a setter of the array changed what the constants hold
            self.refresh()
        if not (self.fused and self._primed):
            torque = s.step(self.dt, position, velocity)
            self._primed = bool(s.has_prev.all())
            return torque
        present = np.floor(position * self._inv_tick + 0.5)
        return self._kt * self._drive(s, present, velocity)

    def step_present(self, present: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """One firmware sample from the encoders' readings ``present`` (ticks, as the owner's encoders
        read them) at shaft speeds ``omega`` (rad/s): the motor currents (A). A goal just written
        (its trajectory still to be set) takes the array's own step, as outside the plain case."""
        s = self.servos
        if s.version != self._version:
            self.refresh()
        if not (self.fused and self._primed) or s.ongoing.any():
            s.present, s.omega = present, omega
            s.step_ticks(self.dt)
            self._primed = bool(s.has_prev.all())
            return s.current
        return self._drive(s, present, omega)

    def step_joint(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """:meth:`step` from joint values and speeds, torques at the joints (shaft torque / ratio),
        the transmissions folded into the constants: :meth:`ServoArray.step_joint`'s very numbers."""
        s = self.servos
        if s.version != self._version:
            self.refresh()
        if not (self.fused and self._primed):
            torque = s.step_joint(self.dt, q, qd, self._transmission)
            self._primed = bool(s.has_prev.all())
            return torque
        present = np.floor(q * self._joint_tick + self._joint_zero)
        return self._joint_kt * self._drive(s, present, qd / self._ratio)

    def current_at_joint(self, q: np.ndarray, qd: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The motor currents (A) the loop drives at joint values ``q`` and speeds ``qd`` under joint
        goals ``goal``, its state untouched: what a servo there reports as Present Current (the fused,
        primed loop's, as :meth:`step_joint` would take it next)."""
        present = np.multiply(q, self._joint_tick)
        present += self._joint_zero
        np.floor(present, out=present)
        # the integral as the last sample left it: one sample more adds its gain times the error,
        # a hundredth of the proportional term's
        s = self.servos
        return self._command(s, present, qd / self._ratio, self._goal_ticks(goal), s.integral)[3]

    def seat_integral(self, off: np.ndarray) -> None:
        """Shift the integrators so that the loop drives ``off`` (A) more current than it would (a NaN
        leaves its slot as it is): with ``off`` a reported current less :meth:`current_at_joint`'s,
        the integrators' charge, which no reading of positions shows, from what the servos report.
        Exact where the PWM and current are inside their limits; clipped to the integrator's as the
        firmware clips it."""
        shift = np.where(np.isfinite(off), off, 0.0) * self._resistance / self._volts
        s = self.servos
        s.integral = np.clip(s.integral + shift, self._neg_lim, self._lim)

    def _command(self, s: ServoArray, present: np.ndarray, omega: np.ndarray, traj: np.ndarray | None = None,
                 integral: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The PID and the motor for encoder readings ``present`` (ticks) at shaft speeds ``omega``
        towards the array's trajectory (or ``traj``, ticks), the integral charged by this sample's
        error (or ``integral`` as given): (error, integral, PWM, current), the array's state read,
        not changed."""
        error = (s.traj if traj is None else traj) - present
        if integral is None:
            integral = np.minimum(np.maximum(s.integral + self._ki * error, self._neg_lim), self._lim)
        u = self._kp * error + integral
        u += self._kd * (error - s.prev_error)
        pwm = np.minimum(np.maximum(u, self._neg_cap), self._cap)
        if s.supply is not self._supply:  # the owner handed in a new supply (a log's measured one)
            self._supply = s.supply
            self._volts = np.maximum(s.supply, 1e-6) / s._pwm_full
        current = (pwm * self._volts - self._ke * omega) / self._resistance
        current = np.minimum(np.maximum(current, self._neg_ilim), self._ilim)
        return error, integral, pwm, current

    def _drive(self, s: ServoArray, present: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """:meth:`_command`, the array's state advanced (the one copy of the fused loop): the motor
        currents (A)."""
        error, integral, pwm, current = self._command(s, present, omega)
        s.present, s.omega, s.integral, s.prev_error, s.pwm, s.current = (present, omega, integral, error,
                                                                          pwm, current)
        return current
