"""The test stand simulated through the shared servo model: a pendulum on one servo, stepped
analytically, many (log, parameter set) slots at once.

Each slot is one log under one set of servo physics. Every 5 ms sample of its log the slot's
goal and torque enable are written as the host wrote them and, where the slot uses it, the
measured supply voltage drives the motor; in between, the firmware and motor
(:class:`~drivers.servo.model.ServoArray`, 1 kHz) and the stand

    (m L² + m_arm L²/3 + J_a) q̈ = τ_motor − (m + m_arm/2) g L sin(q + q_off) + τ_friction

step together through the core's one integrator (:func:`~drivers.servo.joints.step_joints`, the
pendulum's closed form as its diagonal mass matrix and bias), the friction applied as the
stick-slip force of :mod:`drivers.servo.friction` (the load-dependent level from the motor's and
gravity's torques), as the emulated stand's plant applies it. The rollout is open loop, as BAM
scores a model: from the log's first measured position and velocity, never reset. ``tests/test_stand.py`` checks these dynamics
against the stand's URDF in PyBullet.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bench.stand.logs import SAMPLE_S, StandLog
from drivers.servo import FIRMWARE_PERIOD_S, ServoArray, ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.friction import friction_level
from drivers.servo.joints import joint_damping, step_joints

__all__ = ["GRAVITY", "Slots", "rollout", "stand_inertia"]

#: Standard gravity (m/s²), as BAM's pendulum.
GRAVITY = 9.80665


def stand_inertia(log: StandLog) -> float:
    """The pendulum's inertia about the shaft (kg·m²): a point mass and a uniform arm."""
    return log.mass * log.length ** 2 + log.arm_mass / 3.0 * log.length ** 2


@dataclass(frozen=True)
class Slots:
    """What each slot simulates: its log (index), its servo physics (the log's P gain is set on
    top) and the stand's gravity offset (rad: how far the stand's zero is from hanging plumb)."""

    log: np.ndarray  # (S,) int
    params: ServoParams  # S slots
    gravity_offset: np.ndarray  # (S,)
    measured_supply: np.ndarray  # (S,) bool: drive the motor with the log's measured supply


def rollout(logs: Sequence[StandLog], slots: Slots, substeps: int = int(round(SAMPLE_S / FIRMWARE_PERIOD_S))
            ) -> np.ndarray:
    """Simulated position (rad) of every slot at its log's samples, (K, S) with K the longest log
    (a shorter log's slots hold their last inputs past its end)."""
    S = len(slots.log)
    K = max(len(g) for g in logs)
    pad = lambda a: np.concatenate([a, np.full(K - len(a), a[-1])])  # noqa: E731
    goal = np.stack([pad(g.goal) for g in logs], axis=1)[:, slots.log]
    torque = np.stack([pad(g.torque.astype(float)) for g in logs], axis=1)[:, slots.log]
    nominal = np.array([g.vin for g in logs])[slots.log]
    volts = np.stack([pad(g.volts) if g.volts is not None else np.full(K, g.vin) for g in logs],
                     axis=1)[:, slots.log]
    supply = np.where(slots.measured_supply[None, :], volts, nominal[None, :])
    pendulum = np.array([stand_inertia(g) for g in logs])[slots.log]
    weight = np.array([(g.mass + g.arm_mass / 2.0) * GRAVITY * g.length for g in logs])[slots.log]
    kp = np.array([g.kp for g in logs])[slots.log]
    p = slots.params.with_(position_p=kp, position_i=0.0, position_d=0.0)
    servo = ServoArray(p)
    q = np.array([g.position[0] for g in logs])[slots.log].astype(float)
    qd = np.array([g.velocity[0] for g in logs])[slots.log].astype(float)
    servo.reset(q)
    loop = PositionLoop(servo, SAMPLE_S / substeps)
    dt = SAMPLE_S / substeps
    offset, viscous = slots.gravity_offset, p.viscous
    # A, diagonal: the pendulum, the armature and the back-EMF's and viscous damping (implicit)
    matrix = pendulum + joint_damping(p).implicit(dt)
    out = np.empty((K, S))
    on_before = torque[0] > 0.5
    for k in range(K):
        out[k] = q
        on = torque[k] > 0.5
        started = on & ~on_before
        if started.any():  # torque on again: the firmware starts from where the shaft is
            servo.reset_slot(np.flatnonzero(started), servo.ticks(q[started]))
        on_before = on
        loop.set_goal(goal[k])
        servo.supply = supply[k]
        enable = torque[k]
        for _ in range(substeps):
            tau_m = loop.step(q, qd) * enable
            tau_g = -weight * np.sin(q + offset)
            dry = friction_level(p, qd, tau_m, tau_g)
            q, qd = step_joints(q, qd, dt, tau_m + tau_g - viscous * qd, matrix, dry, "stick")
    return out
