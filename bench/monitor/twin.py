"""The twin: the servo model stepped beside the trial, one control interval at a time, from what
the joints were measured doing.

The twin runs the servo core (:class:`drivers.servo.fast.PositionLoop`, the friction laws, the
joint integrator :func:`drivers.servo.joints.step_joints`) over each control interval under the goal
the trial sent, from its own state, and predicts the next reading.

Why an observer. A free-running copy drifts from the robot by every small error of its model, and
after a few seconds its residual says more about that drift than about the joint. A copy restarted
from every reading (a one-step predictor) cannot drift, but it cannot see a slow fault either: a
contact of 0.3 N·m moves a wrist joint by under an encoder tick in 10 ms, within the encoder's own
rounding. So the twin is corrected towards each reading with a time constant (:data:`CORRECTION_S`):
a joint that sags six ticks within 50 ms under a contact its model does not know leaves a residual
of six ticks, which the correction takes up over a few tenths of a second, while the model's own
slow drift never builds up. The firmware's integrator is the twin's own, charged by its errors.

Why its integrators are seated on the first current. What the firmware's integrators hold is the
one state no reading of positions shows. A servo that has held its pose a while against dry
friction holds it with anything within the friction's band beside gravity's torque, and the
surplus stays in its integrator: a lean the joint carries through its next moves for as long as
the integrator takes to unwind, seconds at the rig's integral gain. On the worn emulated rig,
started as the twin assumed (gravity's torque alone), the wrist ran two ticks off its twin for
the first second and a half. So the twin starts holding gravity, and at its first prediction
(:meth:`ServoTwin.current_residual`) shifts its integrators to drive the currents the servos
report there, under the goal then in force: from then on it knows what they hold.

The robot's mass matrix and gravity's torques (PyBullet's, from the URDF, as the servo-model sim
and the emulated rig use) are those of the measured pose, where the robot is: a joint far from its
model then does not load its neighbours' twins as if the arm were where the model would have it.
They are kept until the pose has moved :data:`DYNAMICS_TOLERANCE`.

Why every 10 ms. The twin predicts a reading each :data:`PREDICTION_PERIOD_S`: every reading of a
100 Hz rig loop, every fifth of the 500 Hz sim's, the goals sent in between averaged over the time
each was in force. Its detector then meets residuals at one rate on every backend, so a σ and a
threshold measured on the rig mean the same in the sim (readings 2 ms apart are not five times the
evidence of one: the residual hardly changes between them). The model is stepped once a prediction:
the position loop's proportional torque taken at the step's mid-point (its stiffness half implicit,
beside the motor's fully implicit damping), and dry friction by its smoothed law at the speed the
step ends with (:func:`drivers.servo.friction.implicit_smooth_speed`: taken at the step's start, a
law that stiff through zero speed would chatter at 10 ms). On clean logs of the worn model's sims
its residuals were those of the twin stepped at the firmware's 1 kHz, which it replaced, within
0.05 tick rms (docs/monitor.md), at a fifth of the cost.

Why a timing spread. A rig's loop that runs late (a busy host, a slow bus answer) read its servos
and wrote their goals at moments its clock stamps only to within the delay, and a joint moving at
speed v is then known to within v times it. The twin says so: with each prediction,
:attr:`ServoTwin.timing` is each joint's measured speed times how far the intervals it spans
strayed from the loop's period, which the monitor adds to σ in quadrature. A loop on time (every
simulator) has none; a late cycle of a stiff slide at insertion speed no longer reads as a fault.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from drivers.servo import ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.friction import friction_level
from drivers.servo.joints import joint_damping, step_joints
from drivers.servo.model import FIRMWARE_PERIOD_S, ServoArray
from drivers.servo.plant import PyBulletPlant

__all__ = ["CORRECTION_S", "DYNAMICS_TOLERANCE", "FRICTION_SPREAD", "PREDICTION_PERIOD_S", "ServoTwin",
           "TwinSetup"]

#: How far the pose moves (Euclidean over the joints, rad and m) before the twin asks PyBullet for
#: the mass matrix and gravity again: the load moves by about that fraction of the links' weight.
DYNAMICS_TOLERANCE = 2e-3
#: The time constant (s) of the twin's correction towards the readings: long beside a servo's
#: response to a disturbance (tens of ms), short beside the model's drift. A wrist held by its own
#: static friction against a contact stops, and the residual grows only as its goal leaves it, a
#: tick in 30 ms: at 0.3 s the correction took up enough of it to flag 0.3 N·m on the worn
#: emulated rig's θ5 in 0.26 s, at 0.4 s in 0.24 s; at 0.5 s a datasheet model's clean drift
#: reached half the alarm threshold (docs/monitor.md).
CORRECTION_S = 0.4
#: The twin predicts a reading at most this often (s); see the module's docstring.
PREDICTION_PERIOD_S = 0.01
#: How well a model knows its joints' friction, as a share of each friction torque: identification
#: holds every friction value it tells to within 15 % (tests/test_identify_worn.py), and the current
#: that pushes against the friction is known no better. With the firmware sample's change of the P
#: term, the spread of the current's prediction (:attr:`ServoTwin.current_spread`), which the
#: monitor adds to σ in quadrature: a datasheet model, without friction, has none of it.
FRICTION_SPREAD = 0.15


@dataclass(frozen=True)
class TwinSetup:
    """What the twin is built from: the robot, its servos' parameters and transmissions."""

    robot_urdf: str
    joint_names: Sequence[str]
    params: ServoParams
    ratio: np.ndarray
    offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    #: per joint the motor constant (N·m/A) the backend turns Present Current into effort with
    #: (the datasheet's; None: the model's own, as the servo-model sim without one)
    reported_kt: np.ndarray | None = None

    def amps_per_effort(self) -> np.ndarray:
        """Per joint the motor current (A) behind a unit of the backend's effort reading: effort =
        reported Kt · current / ratio, as the backends read Present Current."""
        kt = self.params.kt if self.reported_kt is None else np.asarray(self.reported_kt, dtype=float)
        return np.asarray(self.ratio, dtype=float) / kt


class ServoTwin:
    """The servo model of every joint, stepped beside the trial and corrected by its readings.

    :meth:`start` at the first reading; then :meth:`advance` at each reading after it, with the
    goal the trial sent at the reading before: the residual (measured minus predicted, joint units)
    at the readings it predicts (:data:`PREDICTION_PERIOD_S` apart), None at the others.
    """

    def __init__(self, setup: TwinSetup, correction_s: float = CORRECTION_S,
                 period_s: float = PREDICTION_PERIOD_S) -> None:
        self.setup = setup
        n = len(setup.joint_names)
        self.n = n
        self.params = setup.params
        self.correction_s = float(correction_s)
        self.period_s = float(period_s)
        p = setup.params
        self._has_friction = p.has_dry_friction
        #: the integrator's step: one a prediction (dry friction by the implicit law)
        self.step_s = self.period_s
        self._ratio = np.asarray(setup.ratio, dtype=float)
        self._offset = np.asarray(setup.offset, dtype=float)
        self._lower, self._upper = np.asarray(setup.lower, float), np.asarray(setup.upper, float)
        self._dynamics = PyBulletPlant(setup.robot_urdf, setup.joint_names, self._ratio, self._offset,
                                       np.clip(np.zeros(n), self._lower, self._upper), setup.params)
        self._servos = ServoArray(setup.params)
        self._loop = PositionLoop(self._servos, self.step_s, self._ratio, self._offset)
        if not self._loop.fused:
            raise ValueError("the twin models the position loop without a profile, deadband or "
                             "current-based mode; a servo of this model has one")
        damping = joint_damping(p, self._ratio)
        self._abs_inv_ratio = np.abs(1.0 / self._ratio)
        self._viscous = damping.viscous
        self._has_viscous = bool(self._viscous.any())
        # the armature, and the back-EMF's and viscous damping stepped implicitly, on each joint's
        # inertia; the loop's derivative gain as a damping too, its proportional one at mid-step
        gain, derivative = self._loop.joint_gains()
        amps_per_torque = np.abs(self._ratio / p.kt)  # the motor current a joint torque takes
        self._amps_per_error_sample = gain * amps_per_torque * FIRMWARE_PERIOD_S  # the P term's, a sample
        self._amps_per_friction = FRICTION_SPREAD * amps_per_torque
        self._implicit = damping.implicit(self.step_s) + self.step_s * derivative
        self._midstep = 0.5 * self.step_s * gain  # N·m·s/rad: the P torque's change over half a step's travel
        self._pose: np.ndarray | None = None
        self._still = np.zeros(n)  # the joints' speeds for gravity's torques alone
        self._loop_period: float | None = None
        self._stray = 0.0
        #: per joint, the timing spread of the last prediction (joint units; None: the loop was on time)
        self.timing: np.ndarray | None = None
        self._bias = np.zeros(n)
        self.q = np.zeros(n)
        self.qd = np.zeros(n)
        self._amps_per_effort = setup.amps_per_effort()
        #: per joint, the motor current (A) the last prediction expects the servo to report, and what
        #: the model cannot tell of it there (:data:`FRICTION_SPREAD`, the current's sample moment)
        self.current = np.zeros(n)
        self.current_spread = np.zeros(n)
        self._seated = False  # whether the integrators have met a reported current
        self._latest = np.zeros(n)  # the goal in force at the last reading (joint values)

    def close(self) -> None:
        self._dynamics.close()

    def amps(self, effort: np.ndarray) -> np.ndarray:
        """The motor currents (A) behind a backend's effort reading (its reported Kt undone)."""
        return effort * self._amps_per_effort

    def current_residual(self, amps: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The motor currents (A) the servos reported at the reading just predicted minus the
        prediction's (:attr:`current`). At the first prediction after :meth:`start`, the twin's
        integrators are seated on them instead (see the module's docstring): the residual there is
        nil where a current was reported, NaN where none was."""
        off = np.subtract(amps, self.current, out=out)
        if not self._seated:  # the integrators hold what the servos report: the prediction is theirs
            self._seated = True
            self._loop.seat_integral(off)
            off[np.isfinite(off)] = 0.0
        return off

    def _load(self, q: np.ndarray) -> None:
        """Each joint's inertia for the integrator, its coupling to the others and gravity's torques, at pose ``q``."""
        if self._pose is not None:
            d = q - self._pose
            if d.dot(d) < DYNAMICS_TOLERANCE ** 2:
                return
        M, h = self._dynamics.dynamics(q, self._still)
        self._diagonal = M.diagonal() + self._implicit
        np.fill_diagonal(M, 0.0)  # M is the twin's own: its off-diagonal part is the coupling
        self._coupling = M
        self._bias, self._pose = h, q.copy()

    def start(self, q: np.ndarray, qd: np.ndarray, loop_period_s: float | None = None) -> None:
        """At the first reading: the servos holding pose ``q`` against gravity, as a trial starts;
        ``loop_period_s``, the period the readings are due at (None: no timing spread)."""
        self.q, self.qd = np.asarray(q, dtype=float).copy(), np.asarray(qd, dtype=float).copy()
        self._loop_period, self._stray, self.timing = loop_period_s, 0.0, None
        self._reading, self._speed = self.q, self.qd
        self._acceleration = np.zeros(self.n)
        self._elapsed, self._behind = 0.0, 0.0
        self._goal_area = np.zeros(self.n)
        self._load(self.q)
        shafts = (self.q - self._offset) / self._ratio
        self._servos.hold(shafts, self._bias * self._ratio)
        self._servos.has_prev[:] = True
        self._loop.refresh()
        self._seated = False

    def advance(self, goal: np.ndarray, q: np.ndarray, qd: np.ndarray, interval_s: float) -> np.ndarray | None:
        """The interval ``interval_s`` that ends at reading ``q``, ``qd``, under ``goal`` (joint values,
        as sent at the reading before): the residual (measured minus predicted) when a prediction is
        due, the twin then corrected towards the reading; None between predictions."""
        self._elapsed += interval_s
        self._goal_area += goal * interval_s
        self._latest = goal
        if self._loop_period is not None:  # how far the loop strayed from its period
            self._stray += abs(interval_s - self._loop_period)
        if self._elapsed < self.period_s - 0.5 * interval_s:
            return None
        return self._predict(q, qd)

    def advance_rows(self, goals: np.ndarray, q: np.ndarray, qd: np.ndarray,
                     intervals: np.ndarray) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        """:meth:`advance` over rows (a block of readings, each row's goal the one sent at the
        reading before): (row, residual, :attr:`timing`) for each row it predicts. The predictions of
        row by row (to rounding: the goals are summed in one product); the rows between predictions
        cost a float's addition each, not an array's. A caller that stops taking them (a trip) leaves
        the twin at the last row it took."""
        begin, period = 0, self.period_s
        elapsed = self._elapsed
        for k, dt in enumerate(intervals.tolist()):
            elapsed += dt
            if elapsed < period - 0.5 * dt:
                continue
            self._take(goals[begin:k + 1], intervals[begin:k + 1])
            self._latest = goals[k]
            self._elapsed = elapsed
            residual = self._predict(q[k], qd[k])
            begin, elapsed = k + 1, 0.0
            yield k, residual, self.timing
        if begin < len(intervals):
            self._take(goals[begin:], intervals[begin:])
            self._latest = goals[-1]
        self._elapsed = elapsed

    def _take(self, goals: np.ndarray, intervals: np.ndarray) -> None:
        """Rows of goals in force for ``intervals`` into the prediction's goal sum (and stray)."""
        if len(intervals) == 1:
            self._goal_area += goals[0] * intervals[0]
        else:
            self._goal_area += intervals @ goals
        if self._loop_period is not None:
            self._stray += float(np.abs(intervals - self._loop_period).sum())

    def _predict(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The prediction due at reading ``q``, ``qd`` under the goals summed since the last one."""
        elapsed, goal = self._elapsed, self._goal_area / self._elapsed  # the goals as they were in force
        self._elapsed = 0.0
        self._goal_area.fill(0.0)
        span = elapsed + self._behind  # the twin's state lags the reading by this (leads: below 0)
        samples = int(round(span / self.step_s))
        self._behind = span - samples * self.step_s
        loop, dt = self._loop, self.step_s
        loop.set_goal_joint(goal)
        x, xd = self.q, self.qd
        self._load(self._reading)  # the load where the robot is, not where the twin is
        # each joint feels its neighbours as they were measured moving, not as their models would
        load = self._bias + self._coupling @ self._acceleration
        dry = None
        for _ in range(samples):
            torque = loop.step_joint(x, xd)
            midstep = self._midstep * loop.unsaturated()
            matrix = self._diagonal + dt * midstep
            rhs = torque - load - midstep * xd
            if self._has_viscous:
                rhs -= self._viscous * xd
            dry = speed = None
            if self._has_friction:
                speed = xd * self._abs_inv_ratio
                dry = (friction_level(self.params, speed, torque * self._ratio, -load * self._ratio)
                       * self._abs_inv_ratio)
            x, xd = step_joints(x, xd, dt, rhs, matrix, dry, "implicit", speed, self._lower, self._upper,
                                self._abs_inv_ratio)
        predicted = x + xd * self._behind  # the prediction carried to the reading's time
        residual = q - predicted
        # the current the firmware drove in its last sample, under the goal in force at the reading
        # (not the interval's mean: a slide at insertion speed sees its goal move 2 mm in 10 ms), from
        # the encoder as it read it a sample before: the reading's, not the twin's position, whose
        # residual the position's signal already holds (taken at the twin's, a worn θ4 creeping through
        # its Stribeck friction left its current 2 σ off for a second on a clean trial); what the
        # current then tells beyond the reading is the twin's integrators against the servo's. Known
        # to within a sample of the P term's change and the friction's identification spread
        speed = np.abs(xd)
        self.current = loop.current_at_joint(q - qd * FIRMWARE_PERIOD_S, qd, self._latest)
        spread = self._amps_per_error_sample * speed
        if self._has_friction or self._has_viscous:  # at the joints, the last sample's
            friction = self._viscous * speed if dry is None else dry + self._viscous * speed
            told = self._amps_per_friction * friction
            spread = np.sqrt(spread * spread + told * told)
        self.current_spread = spread
        if self._stray > 1e-4:  # the goals' and the reading's moments known to within the stray
            self.timing = np.maximum(np.abs(qd), np.abs(self._speed)) * self._stray
        else:
            self.timing = None
        self._stray = 0.0
        self._acceleration = (qd - self._speed) * (1.0 / max(elapsed, 1e-6))
        self._reading, self._speed = q, qd  # readings are the backend's, never changed after
        gain = min(1.0, elapsed / self.correction_s)
        self.q = x + gain * residual
        self.qd = xd + gain * (qd - xd)
        return residual
