"""The robot in simulation as the rig runs it: servo firmware, motors and gearboxes in the loop.

PyBullet's ideal position motors (:class:`~drivers.pybullet.backend.PyBulletActuators`) track
almost perfectly; the rig's servos do not (firmware PID, back-EMF, current limits, friction,
gravity sag). This backend drives the same URDF through the shared servo model
(:class:`~drivers.servo.model.ServoArray`) and the rig's plant
(:class:`~drivers.servo.plant.PyBulletPlant`): every physics step the firmware turns the goals
it has received into motor torques, and the plant integrates the joints under gravity.

What the bench sees is what the rig's driver sees: positions quantised to encoder ticks and
velocities to 0.229 rev/min through each joint's transmission (joint = offset + ratio · shaft),
goals that reach the servos ``transport_delay_s`` after they are commanded, and efforts from
the motor current.

The runner hands it whole blocks of cycles (:meth:`ServoSimActuators.execute_block`, the
:class:`~drivers.capabilities.BlockExecution` capability): the same cycles, the same numbers,
without a reading object per cycle; a rewind goes back to the block's start and runs its
cycles again, which the simulator, deterministic, repeats exactly.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal, Sequence

import numpy as np

from drivers import ActuatorError, BackendSetupError, JointLimits, JointState, NotEnabledError, frozen_array
from drivers.dynamixel.control_table import x_series_table
from drivers.pybullet.backend import BlockStates, steps_per_period
from drivers.pybullet.stepped import SteppedActuators, block_commands
from drivers.servo import ServoArray, ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.plant import PyBulletPlant
from drivers.train_loop import SensedDistance, TrainLoop

__all__ = ["ServoSimActuators", "ServoSimSettings", "TrainSensor"]


@dataclass
class TrainSensor:
    """The rig's ultrasonic sensor on the train, for the simulator: what it sees and how the
    driver maps a reading back to the joint (the bench's kinematics), its rate and median."""

    joint: int
    to_distance: Callable[[float], float]  # joint value -> distance the sensor sees (m)
    to_joint: Callable[[float], float]  # reading (m) -> joint value, as the driver maps it
    rate_hz: float
    median_window: int = 5
    noise_std_m: float = 0.0  # reading noise (1σ, m), before the sensor's whole millimetres
    seed: int = 0


@dataclass
class ServoSimSettings:
    """What the servo simulator needs; the bench builds it from a trial config's servo table."""

    robot_urdf: Path
    joint_names: Sequence[str]
    servos: ServoParams
    ratio: Sequence[float]  # joint units per shaft radian
    offset: Sequence[float]  # joint value at shaft angle 0
    max_velocity: Sequence[float]  # rad/s or m/s per joint (the bench's limits)
    max_effort: Sequence[float]  # N·m or N per joint
    physics_hz: float = 1000.0
    control_period: float = 0.002
    initial_position: Sequence[float] | None = None
    transport_delay_s: float = 0.0
    safe_stop: Literal["hold", "torque_off"] = "hold"
    gravity: float = -9.81
    #: Start as the lab keeps the rig: servos holding the initial pose with torque on, their
    #: integrators charged against gravity (False: torque off until enable()).
    start_holding: bool = False
    #: With ``start_holding``: per joint, the effort (as reported, N·m or N) the servo holds at the
    #: start; NaN: what holds the pose against gravity. A servo that crept to its pose against
    #: friction holds more or less than gravity alone, and its integrator says by how much.
    initial_effort: Sequence[float] | None = None
    #: The train read through its ultrasonic sensor and steered by the host loop, as on the rig.
    train_sensor: TrainSensor | None = None
    #: Per joint: the servo in current-based position mode (its PID drives a current, capped at
    #: the current limit, as Goal Current is on the rig).
    current_based: Sequence[bool] | None = None
    #: Per joint: the motor constant (N·m/A) the rig's driver converts current with, its servo's
    #: datasheet value; None: the model's own. A model whose motor is weaker than the datasheet
    #: (kt_scale < 1) draws more current for a torque, and the driver reports that current as more
    #: torque, as it does on the rig.
    reported_kt: Sequence[float] | None = None


class ServoSimActuators(SteppedActuators):
    """PyBullet joints moved by simulated X-series servos (torque control through the servo model)."""

    def __init__(self, settings: ServoSimSettings) -> None:
        s = settings
        self.settings = s
        steps_per_period(s.physics_hz, s.control_period)  # refuses a period that is not whole steps
        if s.transport_delay_s < 0:
            raise BackendSetupError(f"transport delay must be >= 0 s, got {s.transport_delay_s}")
        n = len(s.joint_names)
        if s.servos.n != n:
            raise BackendSetupError(f"{s.servos.n} servos for {n} joints")
        self._dt = 1.0 / s.physics_hz
        self._ratio = np.asarray(s.ratio, dtype=float)
        self._offset = np.asarray(s.offset, dtype=float)
        q0 = np.zeros(n) if s.initial_position is None else np.asarray(s.initial_position, dtype=float)
        self.plant = PyBulletPlant(Path(s.robot_urdf), s.joint_names, self._ratio, self._offset, q0,
                                   s.servos, physics_dt=self._dt, gravity=s.gravity)
        self.servos = ServoArray(s.servos)
        if s.current_based is not None:
            self.servos.current_based[:] = np.asarray(s.current_based, dtype=bool)
            self.servos.goal_current[:] = s.servos.current_limit / s.servos.amps_per_unit
        lower, upper = self.plant.limits
        self._limits = JointLimits(lower, upper, np.asarray(s.max_velocity, dtype=float),
                                   np.asarray(s.max_effort, dtype=float))
        self._kinds = list(self.plant.kinds)
        self._reported_kt = (s.servos.kt.copy() if s.reported_kt is None
                             else np.asarray(s.reported_kt, dtype=float))
        self._torque_on = False
        self._pending: deque[tuple[int, np.ndarray]] = deque()
        self._no_torque = np.zeros(n)
        self._delay_steps = int(round(s.transport_delay_s / self._dt))
        self._step_count = 0
        self.safe_stop_report: str | None = None
        self._sensed: SensedDistance | None = None
        self._train_loop: TrainLoop | None = None
        self._last: JointState | None = None
        self._lost = False  # the bench lost the train's last reading (HostLoop)
        if s.train_sensor is not None:
            ts = s.train_sensor
            self._sensed = SensedDistance(lambda: ts.to_distance(float(self.plant.joint_position()[ts.joint])),
                                          ts.rate_hz, ts.median_window, ts.noise_std_m, ts.seed)
            self._sensed.update(0.0)
            self._train_loop = TrainLoop(ts.joint)
        if s.start_holding:
            self._torque_on = True
            torque = self.plant.holding_torque()
            if s.initial_effort is not None:  # effort = reported Kt · current / ratio
                effort = np.asarray(s.initial_effort, dtype=float)
                held = effort * self._ratio / self._reported_kt * s.servos.kt
                torque = np.where(np.isfinite(held), held, torque)
            self.servos.hold(self.plant.position(), torque)
        # what read() converts with, from the control table
        table = x_series_table()
        self._tick_scale = table["Present Position"].scale
        self._velocity_units = table["Present Velocity"]
        self._loop = PositionLoop(self.servos, self._dt, self._ratio, self._offset)
        self._reading: tuple[int, float] = (-1, math.nan)  # the train's (sensor sample, joint value)
        self._block: tuple | None = None  # the last block's start and commands, for rewind()

    # -- the Actuators interface ---------------------------------------------

    def read(self) -> JointState:
        """What the rig's driver reads: ticks and velocity units through the transmissions."""
        position, velocity, effort = self._readings(self.plant.position(), self.plant.velocity(),
                                                    self.servos.current)
        if self._sensed is not None:
            position[self.settings.train_sensor.joint] = self._train_reading()
        self._last = JointState(self.now(), position, velocity, effort)  # read-only
        self._lost = False
        return self._last

    def _readings(self, shaft: np.ndarray, omega: np.ndarray, current: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and effort as the driver reads them from shaft angles, speeds and
        motor currents (one row, or a row per cycle of a block: the same numbers either way)."""
        ticks = self.servos.ticks(shaft)
        units = self._velocity_units
        velocity = self._ratio * units.to_si(np.round(units.from_si(omega)))
        effort = (self._reported_kt * current / self._ratio if self._torque_on
                  else np.zeros_like(shaft))
        return self._offset + self._ratio * ticks * self._tick_scale, velocity, effort

    def _train_reading(self) -> float:
        """The train's joint value from its sensor's median, as the driver maps it (mapped again
        only when the sensor has taken a new reading)."""
        sensed = self._sensed
        if self._reading[0] != sensed.samples:
            self._reading = (sensed.samples, self.settings.train_sensor.to_joint(sensed.read()))
        return self._reading[1]

    def status_lost(self, joints: Sequence[str]) -> None:
        """The bench lost the train's last reading: the host loop holds its correction until the next."""
        ts = self.settings.train_sensor
        if ts is not None and self.settings.joint_names[ts.joint] in joints:
            self._lost = True

    def true_position(self) -> np.ndarray:
        """The joints where they really are (not quantised): the simulator's ground truth."""
        return self.plant.joint_position()

    def wait_until(self, t: float) -> None:
        self._advance(int(math.floor(t / self._dt + 1e-6)))

    def _advance(self, target: int) -> None:
        """Step the physics to step ``target``: the sensor's readings, the goals that arrived,
        the firmware and the plant, every step."""
        plant, loop, dt, pending, sensed = self.plant, self._loop, self._dt, self._pending, self._sensed
        step = self._step_count
        due = sensed.due if sensed is not None else math.inf
        while step < target:
            if step * dt >= due:
                sensed.update(step * dt)
                due = sensed.due
            while pending and pending[0][0] <= step:
                loop.set_goal(pending.popleft()[1])
            if self._torque_on:
                plant.step_joint(loop.step_joint(*plant.state()))
            else:
                plant.step_joint(self._no_torque)
            step += 1
            self._step_count = step

    def _enable(self) -> None:
        """As the rig's driver: goals = present positions, then torque on (a servo already holding
        keeps its integrator)."""
        self._pending.clear()
        if self._train_loop is not None:
            self._train_loop.reset()
        if self._torque_on:
            self._loop.set_goal(self.plant.position())
        else:
            self.servos.reset(self.plant.position())  # a reset: the fused loop refreshes at its next step
            self._torque_on = True

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        lim = self._limits
        q = np.minimum(np.maximum(position, lim.lower), lim.upper)
        if self._train_loop is not None and self._last is not None:
            q = self._train_loop.goal(q, self._last.position[self._train_loop.joint], self._last.time,
                                      valid=not self._lost)
        goal = (q - self._offset) / self._ratio
        self._pending.append((self._step_count + self._delay_steps, goal))

    # -- block execution (the runner's fast path) -----------------------------
    def execute_block(self, position: np.ndarray, velocity: np.ndarray, ends: np.ndarray) -> BlockStates:
        """Run a block of control cycles: read, command row k, step to ``ends[k]``.

        The cycles ``read(); command(position[k], velocity[k]); wait_until(ends[k])`` would run,
        with the same numbers, without a reading object per cycle: the commands are checked,
        clipped and turned into shaft goals for the whole block first, the host loop corrects
        the train's goal each cycle by its reading, and the readings are converted for the whole
        block after it ran. What the block started from is kept for :meth:`rewind`.
        """
        if not self._enabled:
            raise NotEnabledError(f"{type(self).__name__}.execute_block() before enable()")
        position, _ = block_commands(position, velocity, ends, self._limits)
        self._block = (self._snapshot(), position, np.asarray(ends, dtype=float))
        return self._run_block(position, self._block[2])

    def rewind(self, cycle: int) -> JointState:
        """Put the simulator back as it was read at ``cycle`` of the last block: the state the
        block started from, and its first ``cycle`` cycles run again (the same steps, so the
        same state, servos, sensor and host loop included)."""
        if self._block is None:
            raise ActuatorError("rewind() without a block to rewind")
        start, position, ends = self._block
        self._restore(start)
        self._run_block(position[:cycle], ends[:cycle])
        self._block = None
        return self.read()

    def _run_block(self, position: np.ndarray, ends: np.ndarray) -> BlockStates:
        goals = (position - self._offset) / self._ratio
        targets = np.floor(ends / self._dt + 1e-6).astype(np.int64).tolist()
        host, delay, pending, dt = self._train_loop, self._delay_steps, self._pending, self._dt
        plant, servos = self.plant, self.servos
        q_rows, qd_rows, current_rows, steps, train = [], [], [], [], []
        tj = host.joint if host is not None else -1
        offset, ratio = float(self._offset[tj]), float(self._ratio[tj])
        wanted = position[:, tj].tolist()
        for i in range(len(ends)):
            # read (the arrays are kept: each step replaces them, none is changed in place)
            step = self._step_count
            q, qd = plant.state()
            q_rows.append(q)
            qd_rows.append(qd)
            current_rows.append(servos.current)
            steps.append(step)
            # command
            if host is not None:  # each row of the block's goals is its own cycle's, written once
                sensed = self._train_reading()
                train.append(sensed)
                goals[i, tj] = (wanted[i] + host.correct(wanted[i], sensed, step * dt) - offset) / ratio
            pending.append((step + delay, goals[i]))
            # wait
            self._advance(targets[i])
        return self._block_states(steps, q_rows, qd_rows, current_rows, train)

    def _block_states(self, steps: list, q_rows: list, qd_rows: list, current_rows: list,
                      train: list) -> BlockStates:
        """The block's readings, converted whole as :meth:`read` converts one."""
        n = len(self._ratio)
        if not steps:
            empty = frozen_array(np.zeros((0, n)))
            return BlockStates(frozen_array(np.zeros(0)), empty, empty, empty)
        q = np.array(q_rows)
        position, velocity, effort = self._readings((q - self._offset) / self._ratio,
                                                    np.array(qd_rows) / self._ratio, np.array(current_rows))
        if self._train_loop is not None:
            position[:, self._train_loop.joint] = train
        time = np.array(steps, dtype=float) * self._dt
        states = BlockStates(frozen_array(time), frozen_array(position), frozen_array(velocity),
                             frozen_array(effort))
        self._last = JointState(float(time[-1]), states.position[-1], states.velocity[-1], states.effort[-1])
        self._lost = False
        return states

    def _snapshot(self) -> tuple:
        """Everything a cycle's outcome depends on, copied: the core's state through its own
        snapshots (the plant's joints and matrix, the servo array's registers and firmware; the
        fused loop works its constants out again from the array)."""
        return (self.plant.snapshot(), self.servos.snapshot(), list(self._pending),
                self._step_count, self._last, self._lost, self._reading,
                copy.deepcopy(self._sensed), copy.copy(self._train_loop))

    def _restore(self, snapshot: tuple) -> None:
        plant, servos, pending, self._step_count, self._last, self._lost, self._reading, \
            self._sensed, self._train_loop = snapshot
        self.plant.restore(plant)
        self.servos.restore(servos)
        self._pending = deque(pending)

    def _disable(self) -> None:
        self._pending.clear()
        if self.settings.safe_stop == "hold":
            self._loop.set_goal(self.plant.position())
            self.safe_stop_report = "holding the measured position"
        else:
            self._torque_on = False
            self.safe_stop_report = "torque off (motors free)"

    def _close(self) -> None:
        self.plant.close()

    # -- extras ----------------------------------------------------------------
    def set_effort_limit(self, joint: int, effort: float) -> None:
        """Lower a joint's available torque/force: its servo's current limit, through the transmission."""
        self.servos.set_current_limit(joint, effort * abs(self._ratio[joint]) / self._reported_kt[joint])
        eff = self._limits.effort.copy()
        eff[joint] = effort
        self._limits = JointLimits(self._limits.lower, self._limits.upper, self._limits.velocity, eff)

    def set_external_effort(self, joint: int, effort: float) -> None:
        """A contact's torque (N·m) or force (N) on a joint, in the plant's torque sum from the next step:
        the servo fights it through its PID as it fights gravity."""
        self.plant.set_external_effort(joint, effort)

    def set_friction_scale(self, joint: int, scale: float) -> None:
        """A joint's friction as a multiple of the servo model's (the plant's law, its levels scaled)."""
        self.plant.set_friction_scale(joint, scale)
