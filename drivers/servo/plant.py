"""The robot's rigid-body dynamics (from PyBullet) under servo torques: the plant of the emulated rig
and of the simulator when it runs a servo model.

The emulated servos return shaft torques; this plant applies them to the
robot's joints through each servo's transmission, with gravity and the link
inertias computed by PyBullet from the URDF, so a joint that carries the arm
lags the way a weak servo lags on the real robot.

Why not ``stepSimulation`` under torque control: a geared servo's reflected
rotor inertia (the armature, ~0.01 kg·m² at an XM430's output) and its
back-EMF damping (Kt·Ke/R ≈ 0.9 N·m·s/rad) dwarf the small links of the
wrist, and PyBullet has no armature and integrates damping explicitly, which
goes unstable at 1 kHz. Here the joint-space equation

    (M(q) + J_a + dt·B) Δq̇ = dt · (τ_drive + τ_ext − B q̇ − h(q, q̇) − friction)

with B the back-EMF damping plus the gearbox's viscous friction and ``friction`` its
Coulomb, Stribeck and load-dependent parts (:mod:`drivers.servo.friction`), all from
the joints' :class:`~drivers.servo.model.ServoParams` (scaled by :meth:`PyBulletPlant.set_friction_scale`
where a fault makes it drift) and τ_ext a contact's torque or force on a joint
(:meth:`PyBulletPlant.set_external_effort`), is integrated semi-implicitly by the core's
one integrator (:func:`~drivers.servo.joints.step_joints`), with M and h = C q̇ + g from PyBullet's
``calculateMassMatrix`` and ``calculateInverseDynamics``. Stable for any
damping; joint limits act as hard stops.

h is computed every step. The matrix on the left changes only with the pose, and slowly (the
armature dominates it), so its Cholesky factor is kept and computed afresh only once the pose
has moved :data:`MASS_MATRIX_TOLERANCE` from where it was: a 9×9 mass matrix, its conversion and
a factorisation cost more than the rest of a step together.

Shaft angle and joint value: ``joint = offset + ratio · shaft``; joint torque
is ``shaft torque / ratio``; armature and damping scale by ``1 / ratio²``.
"""

from __future__ import annotations

from itertools import chain
from pathlib import Path
from typing import Sequence

import numpy as np

from drivers import BackendSetupError
from drivers.capabilities import checked_joint
from drivers.quiet import muted_output, quiet_pybullet
from drivers.servo.friction import FrictionLaw, friction_level, smooth_friction
from drivers.servo.joints import JointMatrix, joint_damping, step_joints
from drivers.servo.model import ServoParams

#: How far (rad and m, Euclidean over the joints) the pose may move from where the mass matrix was
#: computed before it is computed again: M(q) moves by about this fraction of the links' inertia
#: (tests/test_servo_fast.py holds a move's trajectory to the one with a matrix every step).
MASS_MATRIX_TOLERANCE = 1e-4


class PyBulletPlant:
    """``Plant`` for :class:`~drivers.emulator.bus.DynamixelBusEmulator` and the servo simulator."""

    def __init__(self, urdf: Path, joint_names: Sequence[str], ratio: Sequence[float],
                 offset: Sequence[float], initial_position: Sequence[float], servos: ServoParams,
                 physics_dt: float = 0.001, gravity: float | Sequence[float] = -9.81,
                 joint_friction: Sequence[float] | None = None, friction_law: FrictionLaw = "smooth") -> None:
        """``gravity``: along z (m/s²), or the whole vector (a stand tilted from plumb).
        ``friction_law``: how the gearbox's dry friction is applied (:mod:`drivers.servo.friction`;
        ``"stick"`` needs a diagonal mass matrix: one joint)."""
        pb = quiet_pybullet()
        self._pb = pb
        urdf = Path(urdf)
        if not urdf.is_file():
            raise BackendSetupError(f"plant URDF not found: {urdf}")
        with muted_output():
            self._c = pb.connect(pb.DIRECT)
        c = self._c
        pb.setGravity(*((0.0, 0.0, gravity) if np.ndim(gravity) == 0 else gravity), physicsClientId=c)
        self.body = pb.loadURDF(str(urdf), useFixedBase=True, flags=pb.URDF_USE_INERTIA_FROM_FILE,
                                physicsClientId=c)
        infos = [pb.getJointInfo(self.body, j, physicsClientId=c)
                 for j in range(pb.getNumJoints(self.body, physicsClientId=c))]
        movable = [i for i in infos if i[2] != pb.JOINT_FIXED]
        names = [i[1].decode() for i in movable]
        if list(joint_names) != names:
            raise BackendSetupError(
                f"plant joints must be the URDF's movable joints in order {names}, got {list(joint_names)}")
        n = len(names)
        if friction_law == "stick" and n != 1:
            raise BackendSetupError(f"stick-slip friction needs a diagonal mass matrix: one joint, not {n}")
        self.friction_law: FrictionLaw = friction_law
        self.joint_names = names
        self._lower = np.array([i[8] for i in movable])
        self._upper = np.array([i[9] for i in movable])
        self.kinds = tuple("prismatic" if i[2] == pb.JOINT_PRISMATIC else "revolute" for i in movable)
        self._ratio = np.asarray(ratio, dtype=float)
        self._offset = np.asarray(offset, dtype=float)
        self._dt = physics_dt
        self._q = np.clip(np.asarray(initial_position, dtype=float), self._lower, self._upper)
        self._qd = np.zeros(n)
        self._zeros = [0.0] * n
        self._inv_ratio = 1.0 / self._ratio
        self._abs_inv_ratio = np.abs(self._inv_ratio)  # a level at the shaft, at the joint
        self._diagonal = np.diag_indices(n)
        # the friction as identified, which a scale multiplies (FrictionScaled), and a load from outside
        # the robot on each joint (ExternalLoad): both 1 and 0 until a fault sets them
        self._identified = servos
        self._identified_joint_friction = (np.zeros(n) if joint_friction is None
                                           else np.asarray(joint_friction, dtype=float))
        self._friction_scale = np.ones(n)
        self._external = np.zeros(n)
        self._has_external = False
        self._use_friction(servos, self._identified_joint_friction)
        # the matrix's Cholesky factor and the pose it is of (LAPACK's own calls: numpy's solve
        # costs five times the arithmetic of a 9×9 in its checks)
        from scipy.linalg import lapack  # heavy: loaded with the first plant
        self._potrf, self._potrs = lapack.dpotrf, lapack.dpotrs
        self._cholesky = np.eye(n)
        self._matrix: JointMatrix = self._solve  # A for the integrator: its solve, or its diagonal (one joint)
        self._factored_q = self._q
        self._reach = MASS_MATRIX_TOLERANCE ** 2
        self._stale = True  # factor the matrix at the next step

    def _use_friction(self, servos: ServoParams, joint_friction: np.ndarray) -> None:
        """The step's constants from the servos' parameters (the back-EMF's damping and the viscous
        friction implicit, in the matrix, which is factored again at the next step)."""
        self.servos = servos
        damping = joint_damping(servos, self._ratio)
        self._has_friction = servos.has_dry_friction
        self._joint_friction = joint_friction
        self._viscous = damping.viscous
        self._implicit = damping.implicit(self._dt)
        self._has_joint_friction = bool(self._joint_friction.any())
        self._has_viscous = bool(self._viscous.any())
        self._stale = True

    def set_friction_scale(self, joint: int, scale: float) -> None:
        """Scale a joint's friction from its identified value (every level of the servo's friction law,
        and the joint's own dry friction): the friction drifts (a fault) while the law stays one."""
        j = checked_joint(joint, len(self._q), scale, "set_friction_scale")
        if scale < 0:
            raise BackendSetupError(f"set_friction_scale: a friction scale must be >= 0, got {scale} "
                                    f"for joint {j}")
        self._friction_scale[j] = scale
        self._scale_friction()

    def _scale_friction(self) -> None:
        s = self._friction_scale
        self._use_friction(self._identified.with_friction_scale(s), self._identified_joint_friction * s)

    def set_external_effort(self, joint: int, effort: float) -> None:
        """A torque (N·m, revolute) or force (N, prismatic) on a joint from outside the robot (a
        contact), summed with the servos' torques into the joints' dynamics from the next step on."""
        j = checked_joint(joint, len(self._q), effort, "set_external_effort")
        self._external[j] = effort
        self._has_external = bool(self._external.any())

    @property
    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) joint limits of the URDF: where the hard stops are."""
        return self._lower.copy(), self._upper.copy()

    @property
    def joint_count(self) -> int:
        return len(self._q)

    def joint_position(self) -> np.ndarray:
        """Joint values (rad or m), for sensors that see the joint rather than the shaft."""
        return self._q.copy()

    def joint_velocity(self) -> np.ndarray:
        return self._qd.copy()

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The joints' positions and velocities themselves, not copies: a step replaces them and
        never changes them in place, so a caller may keep them (and must not write to them)."""
        return self._q, self._qd

    def position(self) -> np.ndarray:
        return (self._q - self._offset) / self._ratio

    def velocity(self) -> np.ndarray:
        return self._qd / self._ratio

    def holding_torque(self) -> np.ndarray:
        """Shaft torques (N·m) that hold the joints still where they are, against gravity."""
        pb, c = self._pb, self._c
        g = np.array(pb.calculateInverseDynamics(self.body, self._q.tolist(), self._zeros, self._zeros,
                                                 physicsClientId=c))
        return g * self._ratio

    def dynamics(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mass matrix M(q) and the bias torques h(q, q̇) = C q̇ + g at a joint state
        (joint units), from the URDF: what identification puts around each joint."""
        pb, c = self._pb, self._c
        ql = np.asarray(q, dtype=float).tolist()
        n = len(ql)
        M = np.fromiter(chain.from_iterable(pb.calculateMassMatrix(self.body, ql, physicsClientId=c)), float,
                        n * n).reshape(n, n)  # from PyBullet's rows without a list of lists' conversion
        h = np.fromiter(pb.calculateInverseDynamics(self.body, ql, np.asarray(qd, dtype=float).tolist(),
                                                    self._zeros, physicsClientId=c), float, n)
        return M, h

    def _factor(self, q: np.ndarray) -> None:
        """The Cholesky factor of M(q) + J_a + dt·B (symmetric, positive definite) at ``q``, kept
        until the pose is :data:`MASS_MATRIX_TOLERANCE` away."""
        n = len(q)
        A = np.fromiter(chain.from_iterable(
            self._pb.calculateMassMatrix(self.body, q.tolist(), physicsClientId=self._c)), float, n * n)
        A = A.reshape(n, n)
        A[self._diagonal] += self._implicit
        if self.friction_law == "stick":  # one joint: A is its own diagonal
            self._matrix = A[self._diagonal].copy()
        self._cholesky, info = self._potrf(A)
        if info != 0:
            raise ValueError(f"the plant's matrix is not positive definite at {q.tolist()} (LAPACK info {info})")
        self._factored_q = q
        self._reach = MASS_MATRIX_TOLERANCE ** 2

    def snapshot(self) -> tuple:
        """The plant's state (the joints, the kept matrix, loads and friction scales), for :meth:`restore`."""
        matrix = self._matrix.copy() if isinstance(self._matrix, np.ndarray) else self._matrix
        return (self._q, self._qd, self._cholesky.copy(), matrix, self._factored_q, self._reach, self._stale,
                self._external.copy(), self._friction_scale.copy())

    def restore(self, snapshot: tuple) -> None:
        """Back to a :meth:`snapshot`: the same steps from there give the same states."""
        self._q, self._qd, cholesky, matrix, self._factored_q, self._reach, stale, external, scale = snapshot
        if not np.array_equal(scale, self._friction_scale):
            self._friction_scale = scale.copy()
            self._scale_friction()
        self._stale = stale
        self._external = external.copy()
        self._has_external = bool(external.any())
        self._cholesky = cholesky.copy()
        self._matrix = matrix.copy() if isinstance(matrix, np.ndarray) else matrix

    def _solve(self, b: np.ndarray) -> np.ndarray:
        """A⁻¹ b through the kept Cholesky factor."""
        return self._potrs(self._cholesky, b)[0]

    def step(self, dt: float, torque: np.ndarray) -> None:
        """One physics step of ``dt`` (the plant's own) under the servos' shaft torques (N·m)."""
        if abs(dt - self._dt) > 1e-12:
            raise ValueError(f"plant steps {self._dt} s, asked for {dt} s")
        torque = np.asarray(torque, dtype=float)
        self.step_joint(torque * self._inv_ratio, torque)

    def step_joint(self, joint_torque: np.ndarray, torque: np.ndarray | None = None) -> None:
        """One physics step under the servos' torques at the joints (N·m or N: shaft torque / ratio;
        ``torque``, the shaft torques themselves, where the caller has them)."""
        q, qd = self._q, self._qd
        h = np.array(self._pb.calculateInverseDynamics(self.body, q.tolist(), qd.tolist(), self._zeros,
                                                       physicsClientId=self._c))
        # The servo's torque already holds the back-EMF's -B_emf·qd (explicit); its damping and
        # the viscous friction are applied implicitly through the matrix, so only the viscous
        # part stays here: τ/r + B_emf·qd − B·qd = τ/r − (viscous/r²)·qd.
        if self._has_external:  # a contact: one more torque in the joints' sum, a load on the gearbox
            h = h - self._external
        rhs = joint_torque - h
        if self._has_viscous:
            rhs -= self._viscous * qd
        if self._has_joint_friction:
            rhs -= smooth_friction(self._joint_friction, qd)
        dry = speed = None
        if self._has_friction:
            # the gearbox carries the motor's torque and the load's (gravity, the links' bias, a contact)
            shaft = joint_torque * self._ratio if torque is None else torque
            speed = qd * self._abs_inv_ratio  # the shaft's speed, signed as the joint's
            dry = friction_level(self.servos, speed, shaft, -h * self._ratio) * self._abs_inv_ratio
        if self._stale:
            self._factor(q)
        q_new, qd_new = step_joints(q, qd, self._dt, rhs, self._matrix, dry, self.friction_law, speed,
                                    self._lower, self._upper)
        moved = q_new - self._factored_q
        self._stale = moved.dot(moved) > self._reach
        self._q, self._qd = q_new, qd_new

    def close(self) -> None:
        try:
            self._pb.disconnect(self._c)
        except Exception:
            pass
