"""What identification reads from the rig's trial logs: per joint, the goals the servo was sent,
the position and current it reported, and the torque the rest of the robot put on it.

A joint is simulated on its own (:mod:`bench.identify.simulate`); the robot around it enters as
measured: its inertia ``M_jj(q)`` and the torque ``h_j(q, q̇) + Σ_{k≠j} M_jk q̈_k`` (gravity,
Coriolis and the other joints' accelerations) at the logged configuration, from the URDF through
PyBullet. Logs of different robots or servo tables do not mix: one identification, one rig.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from bench.config.models import TrialConfig, model_number
from bench.core.log import TrialLog
from bench.identify.errors import IdentifyError
from bench.kinematics.registry import get_robot
from bench.rig.backends import servo_params, servo_table
from bench.trial.record import load_checked
from drivers.dynamixel.control_table import model_spec
from drivers.servo import ServoParams
from drivers.servo.model import FIRMWARE_PERIOD_S
from drivers.servo.plant import PyBulletPlant
from drivers.train_loop import TrainLoop

__all__ = ["LoggedRun", "RigSetup", "load_runs"]

#: The least motion (joint units: rad or m) a joint's goals must span in a log to be identified there.
MIN_EXCURSION = {"revolute": np.radians(0.5), "prismatic": 0.5e-3}


@dataclass(frozen=True)
class RigSetup:
    """The rig the logs came from: its joints, servos and transmissions (one for every log)."""

    robot: str
    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]
    models: tuple[int, ...]  # each joint's servo model number
    ratio: np.ndarray
    offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    datasheet: ServoParams  # the servos' datasheet parameters with the config's gains
    kt_datasheet: np.ndarray  # N·m/A at each shaft, what the log's effort was converted with
    train: int | None  # the joint read by the ultrasonic sensor (its goals carry the host loop)
    signature: tuple  # what must match between logs


@dataclass(frozen=True)
class LoggedRun:
    """One trial log, arranged for identification (rows at the logged control cycles)."""

    run_dir: Path
    sha256: str
    time: np.ndarray  # s from the first row
    goal: np.ndarray  # (K, n) joint goals the servos were sent (the train's with its host loop)
    q: np.ndarray  # (K, n) measured joint positions
    qd: np.ndarray  # (K, n) measured joint velocities
    current: np.ndarray  # (K, n) measured motor currents (A)
    inertia: np.ndarray  # (K, n) M_jj at the measured configuration (joint units)
    load: np.ndarray  # (K, n) h_j + Σ_{k≠j} M_jk q̈_k (N·m or N)
    excited: np.ndarray  # (n,) bool: the goals moved this joint enough to learn from
    #: the train's ``q`` is its servo's pinion encoder (the log's encoder channel), not the sensor's
    #: reading: it is then fitted on its position like every other joint
    train_on_encoder: bool = False
    #: (K,) when each row's reading was taken and when its goal took effect in the servos (s, the
    #: clock of ``time``): the loop's latency (:func:`loop_latency`); None: both at ``time``
    sampled: np.ndarray | None = None
    applied: np.ndarray | None = None

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0]) if len(self.time) else 0.0


def _signature(config: TrialConfig, names: Sequence[str]) -> tuple:
    table = servo_table(config, get_robot(config.robot))
    rows = []
    for n in names:
        s = table[n]
        rows.append((n, model_number(s.model), s.mode, round(s.ratio, 12), round(s.offset, 12),
                     s.position_p, s.position_i, s.position_d, s.current_limit_a))
    return (config.robot, tuple(rows))


def _describe_difference(a: tuple, b: tuple) -> str:
    if a[0] != b[0]:
        return f"robot {b[0]} (the first log's is {a[0]})"
    for ra, rb in zip(a[1], b[1]):
        if ra != rb:
            return f"servo table differs at joint {ra[0]}: {rb[1:]} (the first log's: {ra[1:]})"
    return "a different servo table"


def _setup(config: TrialConfig) -> RigSetup:
    robot = get_robot(config.robot)
    names = tuple(robot.joint_names)
    table = servo_table(config, robot)
    rows = robot.chain.rows
    models = [model_number(table[n].model) for n in names]
    u = getattr(config.backend, "ultrasonic", None)
    return RigSetup(
        robot=config.robot, joint_names=names,
        kinds=tuple(r.kind for r in rows), models=tuple(models),
        ratio=np.array([table[n].ratio for n in names]), offset=np.array([table[n].offset for n in names]),
        lower=np.array([r.lower for r in rows]), upper=np.array([r.upper for r in rows]),
        datasheet=servo_params(table, names), kt_datasheet=np.array([model_spec(m).motor.kt for m in models]),
        train=names.index(u.joint) if u is not None else None, signature=_signature(config, names))


def _host_loop_goals(log: TrialLog, setup: RigSetup) -> np.ndarray:
    """The goals the driver sent: the logged commands, the train's nudged by the host loop that
    read the train's sensed position (the logged one) of the cycle before."""
    goal = np.clip(log.q_cmd, setup.lower, setup.upper)
    if setup.train is None:
        return goal.copy()
    loop = TrainLoop(setup.train)  # the driver's loop, with its gains
    out = goal.copy()
    t, q = log.time, log.q
    for k in range(1, len(t)):  # the cycle's command follows its read (row k's q)
        out[k] = loop.goal(goal[k], float(q[k, setup.train]), float(t[k]))
    return out


def _train_encoder(log: TrialLog, setup: RigSetup) -> np.ndarray | None:
    """The train's position as its own servo read it (the log's encoder channel), where the log has
    it for the train on every row; None otherwise (an older log: the train is then fitted on its
    servo's velocity). The host loop's goals still follow the sensor's reading, as the driver's did."""
    encoder = log.q_encoder
    if encoder is None or setup.train is None or log.encoder_joint != setup.joint_names[setup.train]:
        return None
    return encoder.copy() if np.all(np.isfinite(encoder)) else None


#: A read or a write taking longer than this (s) is taken as this long: a cycle's bus time beyond
#: a few periods is a stall the loop already waited out (the next row's time holds it), or a
#: damaged log, whose goals must not be put off without end.
MAX_LATENCY_S = 0.05


def loop_latency(log: TrialLog, time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """When each row's reading was taken and when its goal took effect (s, on ``time``'s clock).

    A row's time is stamped when its read returned. The servos answered the read when its request
    went out (the cycle's start, ``loop_start``), and the goal went out after it, its Sync Write
    taking the rest of the cycle's bus time; the firmware then takes it up at its next sample
    (:data:`~drivers.servo.model.FIRMWARE_PERIOD_S`; its readings are as old again on average).
    So the goal reaches the servo some milliseconds after the reading it answers: a fit that
    ignored it would read the servo's extra lag while it accelerates as friction rising with
    speed. A log without the loop's timing is taken as read and written at its rows' times,
    plus the firmware's sample."""
    if not log.timed:
        return time.copy(), time + FIRMWARE_PERIOD_S
    read = np.clip(log.time - log.loop_start, 0.0, MAX_LATENCY_S)
    write = np.clip(log.bus_s - read, 0.0, MAX_LATENCY_S)
    untimed = ~(np.isfinite(read) & np.isfinite(write))
    if untimed.all():
        read[:], write[:] = 0.0, 0.0
    elif untimed.any():
        read[untimed], write[untimed] = np.median(read[~untimed]), np.median(write[~untimed])
    sampled = np.minimum(time - read, time)
    applied = np.maximum.accumulate(time + write + FIRMWARE_PERIOD_S)
    return sampled, applied


def _dynamics(plant: PyBulletPlant, q: np.ndarray, qd: np.ndarray, time: np.ndarray):
    """M_jj and the rest of the robot's torque on each joint, along the measured motion."""
    qdd = np.gradient(qd, time, axis=0) if len(time) > 2 else np.zeros_like(qd)
    width = 5  # 50 ms at 100 Hz: the measured velocity is quantised, its derivative noisy
    kernel = np.ones(width) / width
    qdd = np.stack([np.convolve(c, kernel, mode="same") for c in qdd.T], axis=1)
    inertia = np.empty_like(q)
    load = np.empty_like(q)
    for k in range(len(q)):
        M, h = plant.dynamics(q[k], qd[k])
        inertia[k] = np.diag(M)
        load[k] = h + M @ qdd[k] - inertia[k] * qdd[k]
    return inertia, load


def load_runs(run_dirs: Sequence[Path]) -> tuple[RigSetup, list[LoggedRun]]:
    """The rig and its logs, checked to be one rig's; IdentifyError naming the first misfit."""
    if not run_dirs:
        raise IdentifyError("give at least one trial run directory")
    setup: RigSetup | None = None
    plant: PyBulletPlant | None = None
    runs: list[LoggedRun] = []
    try:
        for run_dir in map(Path, run_dirs):
            try:
                saved, prep = load_checked(run_dir)
            except Exception as e:  # TrialError, a missing or unreadable record
                raise IdentifyError(str(e) if str(run_dir) in str(e) else f"{run_dir}: {e}") from None
            log, config = saved.log, prep.config
            if config.backend.kind != "dynamixel":
                raise IdentifyError(f"{run_dir}: a {config.backend.kind} trial; identification reads the "
                                    f"rig's logs (backend dynamixel, real or --emulate)")
            here = _setup(config)
            if setup is None:
                setup = here
                plant = PyBulletPlant(config.robot_urdf, setup.joint_names, setup.ratio, setup.offset,
                                      prep.robot.chain.home, setup.datasheet)
            elif here.signature != setup.signature:
                raise IdentifyError(f"{run_dir}: not the same rig as {runs[0].run_dir}: "
                                    f"{_describe_difference(setup.signature, here.signature)}")
            if len(log) < 10:
                raise IdentifyError(f"{run_dir}: the log has {len(log)} rows; too short to learn from")
            t = log.time - log.time[0]
            q, qd = log.q.copy(), log.qd.copy()
            on_encoder = _train_encoder(log, setup)
            if on_encoder is not None:
                q[:, setup.train] = on_encoder
            current = log.effort * setup.ratio / setup.kt_datasheet
            goal = _host_loop_goals(log, setup)
            inertia, load = _dynamics(plant, q, qd, t)
            span = goal.max(axis=0) - goal.min(axis=0)
            excited = span >= np.array([MIN_EXCURSION[k] for k in setup.kinds])
            sampled, applied = loop_latency(log, t)
            runs.append(LoggedRun(run_dir=run_dir, sha256=saved.record.sha256, time=t, goal=goal,
                                  q=q, qd=qd, current=current, inertia=inertia, load=load, excited=excited,
                                  train_on_encoder=on_encoder is not None, sampled=sampled, applied=applied))
    finally:
        if plant is not None:
            plant.close()
    assert setup is not None
    return setup, runs
