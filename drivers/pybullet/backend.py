"""PyBullet joints behind the :class:`~drivers.Actuators` interface.

One physics client per instance (never the global connection), a fixed physics
step (default 1 kHz), position control through PyBullet's joint motors with
per-joint force/torque and velocity limits, and a clock that only moves when
``wait_until`` steps the physics — so a trial runs as fast as the CPU allows
and gives the same numbers every time.
"""

from __future__ import annotations

import functools
import math
from array import array
from dataclasses import dataclass, field
from itertools import repeat
from pathlib import Path
from typing import Callable, Literal, Sequence

import numpy as np

from drivers import ActuatorError, BackendSetupError, JointLimits, JointState, NotEnabledError, frozen_array
from drivers.capabilities import checked_joint
from drivers.pybullet.stepped import SteppedActuators, block_commands
from drivers.quiet import muted_output, quiet_pybullet


@dataclass(frozen=True)
class SceneObject:
    """A static body of the room (gantry, bed, phantom) and where it stands."""

    urdf: Path
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # False keeps the body out of the physics world's contact pairs (the
    # gantry: a concave mesh there triples the cost of every step; proximity
    # to it is checked separately).
    collide: bool = True


@dataclass(frozen=True)
class BlockStates:
    """The states read at the start of each cycle of a block, rows ordered by cycle (SI); read-only."""

    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


@dataclass
class PyBulletSettings:
    """What the backend needs to start; the bench builds it from a trial config."""

    robot_urdf: Path
    joint_names: Sequence[str]
    scene: Sequence[SceneObject] = ()
    physics_hz: float = 1000.0
    control_period: float = 0.002
    max_effort: Sequence[float] | None = None  # N·m or N per joint; default: the URDF's
    max_velocity: Sequence[float] | None = None  # rad/s or m/s per joint; default: the URDF's
    position_gain: float = 1.0
    velocity_gain: float = 1.0
    initial_position: Sequence[float] | None = None  # default: zero, clipped to limits
    gravity: float = -9.81
    gui: bool = False
    safe_stop: Literal["hold", "torque_off"] = "hold"
    joint_damping: float = 0.02  # N·m·s/rad: gearbox and bearing losses
    # Constraint-solver iterations per step: the motors are constraints, and
    # PyBullet's default of 50 costs twice the time of 10 for no visible gain
    # in tracking (the trial tests hold the accuracy).
    solver_iterations: int = 10
    extra: dict = field(default_factory=dict)


def steps_per_period(physics_hz: float, control_period: float) -> int:
    """The control period as a whole number of physics steps, or a BackendSetupError."""
    if physics_hz <= 0 or control_period <= 0:
        raise BackendSetupError(
            f"physics_hz ({physics_hz}) and control_period ({control_period}) must be positive")
    n = control_period * physics_hz
    if abs(n - round(n)) > 1e-9 or round(n) < 1:
        raise BackendSetupError(
            f"control period {control_period * 1e3:g} ms is not an integer multiple of the "
            f"physics step {1e3 / physics_hz:g} ms ({n:.4g} steps)")
    return int(round(n))


class PyBulletActuators(SteppedActuators):
    """The robot's joints in a private PyBullet world."""


    def __init__(self, settings: PyBulletSettings) -> None:

        pb = quiet_pybullet()
        self._pb = pb
        self.settings = settings
        self._steps_per_period = steps_per_period(settings.physics_hz, settings.control_period)
        urdf = Path(settings.robot_urdf)
        if not urdf.is_file():
            raise BackendSetupError(f"robot URDF not found: {urdf}")
        for obj in settings.scene:
            if not Path(obj.urdf).is_file():
                raise BackendSetupError(f"scene URDF not found: {obj.urdf}")
        self._dt = 1.0 / settings.physics_hz

        with muted_output():
            self._client = pb.connect(pb.GUI if settings.gui else pb.DIRECT)
        if self._client < 0:
            raise BackendSetupError("could not start a PyBullet client"
                                     + (" with a window (--gui needs a display)" if settings.gui else ""))
        try:
            self._setup(urdf)
        except Exception:
            pb.disconnect(self._client)
            raise
        self._step_count = 0
        self._block = None
        self.safe_stop_report: str | None = None

    # -- set-up ---------------------------------------------------------------
    def _setup(self, urdf: Path) -> None:
        pb, c, s = self._pb, self._client, self.settings
        pb.setTimeStep(self._dt, physicsClientId=c)
        pb.setGravity(0, 0, s.gravity, physicsClientId=c)
        if s.solver_iterations < 1:
            raise BackendSetupError(f"solver_iterations must be >= 1, got {s.solver_iterations}")
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1,
                                     numSolverIterations=int(s.solver_iterations), physicsClientId=c)
        self.robot = pb.loadURDF(str(urdf), useFixedBase=True, physicsClientId=c,
                                 flags=pb.URDF_USE_INERTIA_FROM_FILE)
        self.scene_bodies: dict[str, int] = {}
        for obj in s.scene:
            body = pb.loadURDF(str(obj.urdf), obj.position, pb.getQuaternionFromEuler(obj.rpy),
                               useFixedBase=True, physicsClientId=c)
            if not obj.collide:
                pb.setCollisionFilterGroupMask(body, -1, 0, 0, physicsClientId=c)
            self.scene_bodies[Path(obj.urdf).stem] = body
        by_name = {}
        for j in range(pb.getNumJoints(self.robot, physicsClientId=c)):
            info = pb.getJointInfo(self.robot, j, physicsClientId=c)
            by_name[info[1].decode()] = (j, info)
        missing = [n for n in s.joint_names if n not in by_name]
        if missing:
            raise BackendSetupError(
                f"joints {missing} are not in {urdf.name}; it has {sorted(by_name)}")
        self._joint_index = [by_name[n][0] for n in s.joint_names]
        self.link_index = {info[12].decode(): j for j, info in by_name.values()}
        infos = [by_name[n][1] for n in s.joint_names]
        self._kinds = ["prismatic" if i[2] == pb.JOINT_PRISMATIC else "revolute" for i in infos]
        # where a contact pushes: each joint's axis in its link's frame, and the link it reacts on
        self._axes = [np.array(i[13], dtype=float) for i in infos]
        self._parents = [i[16] for i in infos]
        self._loads: dict[int, float] = {}  # joint -> external torque (N·m) or force (N)
        lower = np.array([i[8] for i in infos])
        upper = np.array([i[9] for i in infos])
        effort = self._per_joint(s.max_effort, [i[10] for i in infos], "max_effort")
        velocity = self._per_joint(s.max_velocity, [i[11] for i in infos], "max_velocity")
        self._limits = JointLimits(lower, upper, velocity, effort)
        n = len(infos)
        self._forces = effort.tolist()
        self._kp, self._kd = [s.position_gain] * n, [s.velocity_gain] * n
        self._zeros = [0.0] * n
        q0 = (np.zeros(len(infos)) if s.initial_position is None
              else self._per_joint(s.initial_position, None, "initial_position"))
        q0 = np.clip(q0, lower, upper)
        for j, q in zip(self._joint_index, q0):
            pb.resetJointState(self.robot, j, float(q), 0.0, physicsClientId=c)
            pb.changeDynamics(self.robot, j, linearDamping=0.0, angularDamping=0.0,
                              jointDamping=s.joint_damping, physicsClientId=c)
        # Inactive: motors off except a little friction, like a servo with torque off.
        self._hold_target = q0.copy()
        self._motors_off()

    def _per_joint(self, values, default, what: str) -> np.ndarray:
        n = len(self.settings.joint_names)
        if values is None:
            return np.asarray(default, dtype=float)
        arr = np.asarray(values, dtype=float)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise BackendSetupError(f"{what} needs {n} finite values, got {values!r}")
        if what != "initial_position" and np.any(arr <= 0):
            raise BackendSetupError(f"{what} must be positive, got {values!r}")
        return arr

    # -- the Actuators interface ---------------------------------------------

    @property
    def client(self) -> int:
        return self._client

    @property
    def physics_dt(self) -> float:
        return self._dt

    def read(self) -> JointState:
        states = self._pb.getJointStates(self.robot, self._joint_index, physicsClientId=self._client)
        position, velocity, _, effort = zip(*states)
        return JointState(self.now(), position, velocity, effort)  # fresh read-only arrays

    def wait_until(self, t: float) -> None:
        target = int(math.floor(t / self._dt + 1e-6))
        step = self._step_pushed if self._loads else self._pb.stepSimulation
        c = self._client
        while self._step_count < target:
            step(physicsClientId=c)
            self._step_count += 1

    def _enable(self) -> None:
        q = self.read().position
        self._send(q, None)

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        lim = self._limits
        self._send(np.minimum(np.maximum(position, lim.lower), lim.upper), velocity)

    def _send(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        self._hold_target = position
        if velocity is None:
            qd = self._zeros
        else:
            v = self._limits.velocity
            qd = np.minimum(np.maximum(velocity, -v), v).tolist()
        self._pb.setJointMotorControlArray(
            self.robot, self._joint_index, self._pb.POSITION_CONTROL,
            targetPositions=position.tolist(), targetVelocities=qd, forces=self._forces,
            positionGains=self._kp, velocityGains=self._kd, physicsClientId=self._client)

    # -- block execution (the runner's fast path) -----------------------------
    @functools.cached_property
    def _flatten_states(self) -> Callable[[tuple], list]:
        """getJointStates' tuples → [positions…, velocities…, efforts…] in one list display.

        Unrolled for this robot's joint count (as namedtuple builds its class): a third
        cheaper than zip and concatenation, and it runs once per control cycle.
        """
        n = self._n_joints
        body = ", ".join(f"s[{j}][{f}]" for f in (0, 1, 3) for j in range(n))
        return eval(f"lambda s: [{body}]")  # noqa: S307 - built from integers only

    def execute_block(self, position: np.ndarray, velocity: np.ndarray,
                      ends: np.ndarray) -> BlockStates:
        """Run a block of control cycles: read, command row k, step to ``ends[k]``.

        Exactly the cycles ``read(); command(position[k], velocity[k]);
        wait_until(ends[k])`` would run, without a Python object per sample:
        the commands are checked and clipped for the whole block first, and the
        states read at each cycle's start come back as arrays. The block's
        states are kept so :meth:`rewind` can put the robot back where it was
        at any of its cycles.
        """
        if not self._enabled:
            raise NotEnabledError(f"{type(self).__name__}.execute_block() before enable()")
        position, velocity = block_commands(position, velocity, ends, self._limits)
        k, n = len(ends), self._n_joints
        targets, speeds = position.tolist(), velocity.tolist()
        targets_steps = np.floor(np.asarray(ends) / self._dt + 1e-6).astype(np.int64)
        # the step count when each cycle reads: it only moves forward
        counts = np.maximum.accumulate(np.concatenate(([self._step_count], targets_steps)))
        pb, c, body, idx = self._pb, self._client, self.robot, self._joint_index
        read, send = pb.getJointStates, pb.setJointMotorControlArray
        step = self._step_pushed if self._loads else pb.stepSimulation
        mode, forces, kp, kd = pb.POSITION_CONTROL, self._forces, self._kp, self._kd
        # Each cycle's reading goes straight into one flat buffer: keeping PyBullet's
        # tuples alive instead costs more than the conversion (fresh memory every cycle).
        buf = array("d")
        put, flat = buf.fromlist, self._flatten_states
        for q, qd, steps in zip(targets, speeds, np.diff(counts).tolist()):
            put(flat(read(body, idx, physicsClientId=c)))
            send(body, idx, mode, targetPositions=q, targetVelocities=qd, forces=forces,
                 positionGains=kp, velocityGains=kd, physicsClientId=c)
            if steps == 1:
                step(physicsClientId=c)
            else:
                for _ in repeat(None, steps):
                    step(physicsClientId=c)
        self._step_count = int(counts[-1])
        counts = counts[:-1].tolist()
        self._hold_target = np.array(targets[-1]) if k else self._hold_target
        # read-only, on an immutable copy: what a caller does to them cannot change a rewind
        rows = np.frombuffer(buf.tobytes(), dtype=float).reshape(k, 3, n)
        states = BlockStates(frozen_array(np.array(counts, dtype=float) * self._dt), rows[:, 0],
                             rows[:, 1], rows[:, 2])
        self._block = (states, counts, targets, speeds)
        return states

    def rewind(self, cycle: int) -> JointState:
        """Put the robot back in the state read at ``cycle`` of the last block.

        Positions, velocities and the clock are restored exactly; the physics
        engine's solver caches are not, so what follows matches a run that
        stopped there to within the solver's tolerance.
        """
        if self._block is None:
            raise ActuatorError("rewind() without a block to rewind")
        states, counts, targets, speeds = self._block
        pb, c, body = self._pb, self._client, self.robot
        for j, q, qd in zip(self._joint_index, states.position[cycle], states.velocity[cycle]):
            pb.resetJointState(body, j, float(q), float(qd), physicsClientId=c)
        if cycle > 0:  # the motors hold the previous cycle's command, as they did then
            self._hold_target = np.array(targets[cycle - 1])
            pb.setJointMotorControlArray(
                body, self._joint_index, pb.POSITION_CONTROL, targetPositions=targets[cycle - 1],
                targetVelocities=speeds[cycle - 1], forces=self._forces, positionGains=self._kp,
                velocityGains=self._kd, physicsClientId=c)
        self._step_count = counts[cycle]
        self._block = None
        return JointState(float(states.time[cycle]), states.position[cycle].copy(),
                          states.velocity[cycle].copy(), states.effort[cycle].copy())

    def _disable(self) -> None:
        if self.settings.safe_stop == "hold":
            self._send(self.read().position, None)
            self.safe_stop_report = "holding the measured position"
        else:
            self._motors_off()
            self.safe_stop_report = "torque off (motors free)"

    def _motors_off(self) -> None:
        n = len(self._joint_index)
        self._pb.setJointMotorControlArray(
            self.robot, self._joint_index, self._pb.VELOCITY_CONTROL,
            targetVelocities=[0.0] * n, forces=[0.0] * n, physicsClientId=self._client)

    def _close(self) -> None:
        try:
            self._pb.disconnect(self._client)
        except Exception:  # already gone (e.g. the GUI window was closed)
            pass

    # -- extras for the bench (not part of the protocol) -----------------------
    def set_effort_limit(self, joint: int, effort: float) -> None:
        """Scale a joint's available torque/force (used by the torque-limit fault)."""
        eff = self._limits.effort.copy()
        eff[joint] = effort
        self._limits = JointLimits(self._limits.lower, self._limits.upper, self._limits.velocity, eff)
        self._forces = eff.tolist()
        if self.enabled:
            self._send(self._hold_target, None)

    def set_external_effort(self, joint: int, effort: float) -> None:
        """A contact's torque (N·m) or force (N) on a joint from the next physics step on (0: none).

        Applied every step as an action on the joint's link and its reaction on the parent link (a
        torque about the joint's axis, or a force along it through one point), so the joint alone
        feels it, as a generalised force, and its position motor, its force limited, fights it."""
        j = checked_joint(joint, self._n_joints, effort, "set_external_effort")
        if effort == 0.0:
            self._loads.pop(j, None)
        else:
            self._loads[j] = float(effort)

    def _step_pushed(self, physicsClientId: int) -> None:  # noqa: N803 - stepSimulation's own keyword
        """One physics step with the contacts applied (PyBullet clears external forces after each step)."""
        pb, body = self._pb, self.robot
        for j, effort in self._loads.items():
            link = self._joint_index[j]
            st = pb.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=physicsClientId)
            push = (np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3) @ self._axes[j]) * effort
            for on, sign in ((link, 1.0), (self._parents[j], -1.0)):
                if self._kinds[j] == "prismatic":
                    pb.applyExternalForce(body, on, (sign * push).tolist(), st[4], pb.WORLD_FRAME,
                                          physicsClientId=physicsClientId)
                else:
                    pb.applyExternalTorque(body, on, (sign * push).tolist(), pb.WORLD_FRAME,
                                           physicsClientId=physicsClientId)
        pb.stepSimulation(physicsClientId=physicsClientId)

    def link_pose(self, link_name: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and rotation matrix of a URDF link frame."""
        if link_name not in self.link_index:
            raise BackendSetupError(f"no link {link_name!r}; the robot has {sorted(self.link_index)}")
        st = self._pb.getLinkState(self.robot, self.link_index[link_name],
                                   computeForwardKinematics=True, physicsClientId=self._client)
        return np.array(st[4]), np.array(self._pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)

    def true_position(self) -> np.ndarray:
        """The joints' positions: the simulator reads them exactly."""
        return self.read().position

    def reset_position(self, q: np.ndarray) -> None:
        """Teleport the joints (only while inactive; for set-up and pictures)."""
        if self.enabled:
            raise BackendSetupError("reset_position() while enabled would jump the robot")
        for j, v in zip(self._joint_index, q):
            self._pb.resetJointState(self.robot, j, float(v), 0.0, physicsClientId=self._client)
