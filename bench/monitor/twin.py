"""The twin: the servo model stepped beside the trial, one control interval at a time, from what
the joints were measured doing.

The twin runs the servo core (:class:`drivers.servo.fast.PositionLoop`, the friction laws, the
joint integrator :func:`drivers.servo.joints.step_joints`) over each control interval under the goal
the trial sent, from its own state, and predicts the next reading.

Why an observer. A free-running copy drifts from the robot by every small error of its model, and
after a few seconds its residual says more about that drift than about the joint. A copy restarted
from every reading (a one-step predictor) cannot drift, but it cannot see a slow fault either: a
contact of 0.3 N·m moves a joint by a fortieth of an encoder tick in 2 ms, under the encoder's own
noise. So the twin is corrected towards each reading with a time constant (:data:`CORRECTION_S`):
a joint that sags six ticks within 50 ms under a contact its model does not know leaves a residual
of six ticks, which the correction takes up over a few tenths of a second, while the model's own
slow drift never builds up. The firmware's integrator is the twin's own, charged by its errors.

The robot's mass matrix and gravity's torques (PyBullet's, from the URDF, as the servo-model sim
and the emulated rig use) are those of the measured pose, where the robot is: a joint far from its
model then does not load its neighbours' twins as if the arm were where the model would have it.
They are kept until the pose has moved :data:`DYNAMICS_TOLERANCE`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from drivers.servo import ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.friction import friction_level
from drivers.servo.joints import joint_damping, step_joints
from drivers.servo.model import FIRMWARE_PERIOD_S, ServoArray
from drivers.servo.plant import PyBulletPlant

__all__ = ["CORRECTION_S", "DYNAMICS_TOLERANCE", "ServoTwin", "TwinSetup"]

#: How far the pose moves (Euclidean over the joints, rad and m) before the twin asks PyBullet for
#: the mass matrix and gravity again: the load moves by about that fraction of the links' weight.
DYNAMICS_TOLERANCE = 2e-3
#: The time constant (s) of the twin's correction towards the readings: long beside a servo's
#: response to a disturbance (tens of ms), short beside the model's drift.
CORRECTION_S = 0.3


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


class ServoTwin:
    """The servo model of every joint, stepped beside the trial and corrected by its readings.

    :meth:`start` at the first reading; then :meth:`advance` at each reading after it, with the
    goal the trial sent at the reading before: the residual (measured minus predicted, joint units).
    """

    def __init__(self, setup: TwinSetup, correction_s: float = CORRECTION_S) -> None:
        self.setup = setup
        n = len(setup.joint_names)
        self.n = n
        self.params = setup.params
        self.correction_s = float(correction_s)
        self._ratio = np.asarray(setup.ratio, dtype=float)
        self._offset = np.asarray(setup.offset, dtype=float)
        self._lower, self._upper = np.asarray(setup.lower, float), np.asarray(setup.upper, float)
        self._dynamics = PyBulletPlant(setup.robot_urdf, setup.joint_names, self._ratio, self._offset,
                                       np.clip(np.zeros(n), self._lower, self._upper), setup.params)
        self._servos = ServoArray(setup.params)
        self._loop = PositionLoop(self._servos, FIRMWARE_PERIOD_S, self._ratio, self._offset)
        if not self._loop.fused:
            raise ValueError("the twin models the position loop without a profile, deadband or "
                             "current-based mode; a servo of this model has one")
        p = setup.params
        damping = joint_damping(p, self._ratio)
        self._inv_ratio = 1.0 / self._ratio
        self._abs_inv_ratio = np.abs(self._inv_ratio)
        self._viscous = damping.viscous
        self._has_viscous = bool(self._viscous.any())
        # the armature, and the back-EMF's and viscous damping stepped implicitly, on each joint's inertia
        self._implicit = damping.implicit(FIRMWARE_PERIOD_S)
        self._has_friction = bool((p.coulomb > 0).any() or (p.stribeck > 0).any() or p.has_load_friction)
        self._pose: np.ndarray | None = None
        self._bias = np.zeros(n)
        self.q = np.zeros(n)
        self.qd = np.zeros(n)

    def close(self) -> None:
        self._dynamics.close()

    def _load(self, q: np.ndarray) -> None:
        """Each joint's inertia for the integrator, its coupling to the others and gravity's torques, at pose ``q``."""
        if self._pose is not None:
            d = q - self._pose
            if d.dot(d) < DYNAMICS_TOLERANCE ** 2:
                return
        M, h = self._dynamics.dynamics(q, np.zeros_like(q))
        self._diagonal = np.diag(M) + self._implicit
        self._coupling = M - np.diag(np.diag(M))
        self._bias, self._pose = h, q.copy()

    def start(self, q: np.ndarray, qd: np.ndarray) -> None:
        """At the first reading: the servos holding pose ``q`` against gravity, as a trial starts."""
        self.q, self.qd = np.asarray(q, dtype=float).copy(), np.asarray(qd, dtype=float).copy()
        self._reading, self._speed = self.q, self.qd
        self._acceleration = np.zeros(self.n)
        self._load(self.q)
        shafts = (self.q - self._offset) / self._ratio
        self._servos.hold(shafts, self._bias * self._ratio)
        self._servos.has_prev[:] = True
        self._loop.refresh()

    def advance(self, goal: np.ndarray, q: np.ndarray, qd: np.ndarray, interval_s: float) -> np.ndarray:
        """Step the model over ``interval_s`` under ``goal`` (joint values, as sent), compare with the
        reading ``q``, ``qd`` that ends the interval, and correct towards it: the residual."""
        samples = max(1, int(round(interval_s / FIRMWARE_PERIOD_S)))
        loop, dt = self._loop, FIRMWARE_PERIOD_S
        loop.set_goal((goal - self._offset) * self._inv_ratio)
        x, xd = self.q, self.qd
        self._load(self._reading)  # the load where the robot is, not where the twin is
        # each joint feels its neighbours as they were measured moving, not as their models would
        load = self._bias + self._coupling @ self._acceleration
        matrix = self._diagonal
        for _ in range(samples):
            torque = loop.step_joint(x, xd)
            rhs = torque - load
            if self._has_viscous:
                rhs -= self._viscous * xd
            dry = speed = None
            if self._has_friction:
                speed = xd * self._abs_inv_ratio
                dry = (friction_level(self.params, speed, torque * self._ratio, -load * self._ratio)
                       * self._abs_inv_ratio)
            x, xd = step_joints(x, xd, dt, rhs, matrix, dry, "smooth", speed, self._lower, self._upper)
        residual = q - x
        self._acceleration = (qd - self._speed) * (1.0 / max(interval_s, 1e-6))
        self._reading, self._speed = q, qd  # readings are the backend's, never changed after
        gain = min(1.0, interval_s / self.correction_s)
        self.q = x + gain * residual
        self.qd = xd + gain * (qd - xd)
        return residual
