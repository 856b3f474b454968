"""Each joint's servo simulated on its own along a logged trial, many parameter sets at once.

A *slot* is one joint under one set of physics; all slots step together through the shared
:class:`~drivers.servo.model.ServoArray` (firmware and motor) and the joint's own equation

    (M_jj + J_a/r² + dt·B/r²) Δq̇ = dt · (τ/r + B_emf q̇ − B q̇ − load − τ_f(q̇/r)/r)

integrated by the core's one integrator (:func:`~drivers.servo.joints.step_joints`, as
:class:`~drivers.servo.plant.PyBulletPlant` integrates the whole robot), with ``M_jj`` and ``load``
(gravity, Coriolis, the other joints' accelerations) taken from the log as its diagonal mass
matrix and bias, and every friction law of :mod:`drivers.servo.friction` (the Stribeck exponent and
the load-dependent gear friction included).
The goals arrive at the logged cycle times; position and current are sampled where the driver
read them, just before each goal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bench.identify.logs import LoggedRun, RigSetup
from drivers.servo import ServoArray, ServoParams
from drivers.servo.fast import PositionLoop
from drivers.servo.friction import friction_level
from drivers.servo.joints import joint_damping, step_joints
from drivers.servo.model import FIRMWARE_PERIOD_S

__all__ = ["FILE_KEYS", "PHYSICS", "SlotPhysics", "file_values", "merge_runs", "WINDOW_S", "simulate_run", "windows_of"]

#: The length of the windows a log is simulated in, each from its logged start (s).
WINDOW_S = 5.0

#: The physics identification fits, in this order: the motor constant's factor, the armature
#: (kg·m²), viscous friction (N·m·s/rad), the Coulomb level (N·m), the friction at rest (the
#: Stribeck peak, N·m: above the Coulomb level on a fresh gearbox, below it on some worn ones) and
#: the Stribeck velocity (rad/s). Each is its own value, so a peak below Coulomb is one a fit can find.
PHYSICS = ("kt_scale", "armature_kgm2", "viscous_nms", "coulomb_nm", "stribeck_nm", "stribeck_velocity_rads")
#: The keys of a servo model file (``emulator.servo_physics``), in the order of the report.
FILE_KEYS = ("kt_scale", "armature_kgm2", "viscous_nms", "coulomb_nm", "stribeck_nm", "stribeck_velocity_rads")


def file_values(values: np.ndarray, stderr: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
    """A fit's parameters and standard errors (in :data:`PHYSICS`) in the file's keys."""
    v = dict(zip(PHYSICS, map(float, values)))
    e = dict(zip(PHYSICS, map(float, stderr)))
    return {k: v[k] for k in FILE_KEYS}, {k: e[k] for k in FILE_KEYS}


@dataclass(frozen=True)
class SlotPhysics:
    """The physics of each slot (arrays of S) and the joint each slot simulates."""

    joint: np.ndarray  # (S,) int
    values: np.ndarray  # (S, len(PHYSICS)) in the order of PHYSICS

    def params(self, datasheet: ServoParams) -> ServoParams:
        """The servo parameters of every slot: its joint's datasheet with the slot's physics."""
        j = self.joint
        base = ServoParams(**{f: getattr(datasheet, f)[j] for f in ServoParams.__dataclass_fields__})
        v = self.values
        return base.with_(armature=v[:, 1], viscous=v[:, 2], coulomb=v[:, 3],
                          stribeck=v[:, 4], stribeck_velocity=v[:, 5]).with_motor_scale(v[:, 0])


def windows_of(time: np.ndarray, window_s: float = WINDOW_S) -> list[tuple[int, int]]:
    """The log's rows cut into windows of about ``window_s`` (row ranges [start, stop) covering
    every row, each at least two rows long)."""
    n = len(time)
    count = max(1, int(round((time[-1] - time[0]) / window_s))) if n > 1 else 1
    edges = np.searchsorted(time, time[0] + np.arange(1, count) * (time[-1] - time[0]) / count)
    bounds = [0]
    for e in (int(e) for e in edges):
        if e - bounds[-1] >= 2 and n - e >= 2:
            bounds.append(e)
    bounds.append(n)
    return list(zip(bounds[:-1], bounds[1:]))


def merge_runs(runs: Sequence[LoggedRun], window_s: float = WINDOW_S
               ) -> tuple[LoggedRun, list[tuple[int, int]], list[slice]]:
    """Several logs as one for :func:`simulate_run`: rows end to end (times apart by a second),
    the windows of each log (never one across two logs), and each log's rows in the whole."""
    if len(runs) == 1:
        return runs[0], windows_of(runs[0].time, window_s), [slice(0, len(runs[0].time))]
    parts, windows, rows, offset, t0 = [], [], [], 0, 0.0
    for r in runs:
        parts.append(r)
        windows += [(a + offset, b + offset) for a, b in windows_of(r.time, window_s)]
        rows.append(slice(offset, offset + len(r.time)))
        offset += len(r.time)
    times, sampled, applied, t0 = [], [], [], 0.0
    for r in runs:
        shift = t0 - r.time[0]
        times.append(r.time + shift)
        sampled.append((r.time if r.sampled is None else r.sampled) + shift)
        applied.append((r.time if r.applied is None else r.applied) + shift)
        t0 = times[-1][-1] + 1.0
    cat = lambda name: np.concatenate([getattr(r, name) for r in runs])  # noqa: E731
    merged = LoggedRun(run_dir=runs[0].run_dir, sha256="", time=np.concatenate(times), goal=cat("goal"), q=cat("q"),
                       qd=cat("qd"), current=cat("current"), inertia=cat("inertia"), load=cat("load"),
                       excited=np.any([r.excited for r in runs], axis=0),
                       sampled=np.concatenate(sampled), applied=np.concatenate(applied))
    return merged, windows, rows


def simulate_run(setup: RigSetup, run: LoggedRun, slots: SlotPhysics, dt: float = FIRMWARE_PERIOD_S,
                 window_s: float = WINDOW_S, windows: Sequence[tuple[int, int]] | None = None,
                 log_starts: Sequence[int] = (0,)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position (joint units), motor current (A) and velocity (joint units/s) of every slot at the
    log's rows, (K, S) each.

    The log is cut into windows of about ``window_s``, each started from the logged state (position,
    velocity, and the integrator that gives the logged current), and all windows of all slots
    step together in one servo array: a long log costs the steps of one window, and a model's
    error cannot pile up over minutes (multiple shooting). ``windows``: the row ranges to use
    instead (several logs merged by :func:`merge_runs`, ``log_starts`` the rows where each begins).
    A row is sampled when its reading was taken and its goal applied when it took effect
    (``run.sampled`` and ``run.applied``, the loop's latency: :func:`~bench.identify.logs.loop_latency`;
    both at the row's time when the run has none)."""
    wins = list(windows) if windows is not None else windows_of(run.time, window_s)
    W, S, n = len(wins), len(slots.joint), len(setup.joint_names)
    # one simulated servo per (window, slot): window-major
    win = np.repeat(np.arange(W), S)
    j = np.tile(slots.joint, W)
    p = SlotPhysics(joint=j, values=np.tile(slots.values, (W, 1))).params(setup.datasheet)
    r = setup.ratio[j]
    inv_r = 1.0 / r
    off = setup.offset[j]
    lower, upper = setup.lower[j], setup.upper[j]
    abs_inv_r = np.abs(inv_r)
    damping = joint_damping(p, r)
    viscous = damping.viscous

    # each window's rows on its own step grid, and the robot around the joint along it
    t = run.time
    sampled = t if run.sampled is None else run.sampled
    applied = t if run.applied is None else run.applied
    # per window, the step of each row's reading and of its goal taking effect (a window starts
    # at its first reading)
    steps = [np.maximum.accumulate(np.rint((sampled[a:z] - sampled[a]) / dt).astype(np.int64)) for a, z in wins]
    lands = [np.maximum(np.maximum.accumulate(np.rint((applied[a:z] - sampled[a]) / dt).astype(np.int64)), st)
             for (a, z), st in zip(wins, steps)]
    n_steps = int(max(max(st[-1], la[-1]) for st, la in zip(steps, lands))) + 1
    grid = np.arange(n_steps) * dt
    inertia = np.empty((n_steps, W, n))
    load = np.empty((n_steps, W, n))
    for w, (start, stop) in enumerate(wins):
        tw = t[start:stop] - sampled[start]
        for k in range(n):
            inertia[:, w, k] = np.interp(grid, tw, run.inertia[start:stop, k])
            load[:, w, k] = np.interp(grid, tw, run.load[start:stop, k])
    flat = win * n + j  # slot -> (window, joint) in a step's (W·n) row
    inertia = inertia.reshape(n_steps, W * n)
    load = load.reshape(n_steps, W * n)
    extra = damping.implicit(dt)
    # the rows read and the goals written, per step: (row, window) events
    reads: dict[int, list[tuple[int, int]]] = {}
    writes: dict[int, list[tuple[int, int]]] = {}
    for w, ((a, _), st, la) in enumerate(zip(wins, steps, lands)):
        for i, (s_, l_) in enumerate(zip(st.tolist(), la.tolist())):
            reads.setdefault(s_, []).append((a + i, w))
            writes.setdefault(l_, []).append((a + i, w))
    columns = np.arange(S)

    servo = ServoArray(p)
    first = np.array([a for a, _ in wins])
    q = run.q[first][:, slots.joint].reshape(-1).astype(float)
    qd = run.qd[first][:, slots.joint].reshape(-1).astype(float)
    # each window's servos as the log found them: at the goal of the cycle before, the integrator
    # giving the current they reported
    before = np.where(np.isin(first, list(log_starts)), first, first - 1)  # a log's first row: its own goal
    goal = (run.goal[before][:, slots.joint].reshape(-1) - off) * inv_r
    servo.resume((q - off) * inv_r, qd * inv_r, goal, run.current[first][:, slots.joint].reshape(-1))
    loop = PositionLoop(servo, dt)  # the same torques as servo.step, for a fraction of its checks
    q_out = np.empty((len(t), S))
    i_out = np.empty((len(t), S))
    qd_out = np.empty((len(t), S))
    for s in range(n_steps):
        ev = reads.get(s)
        if ev is not None:  # the driver reads ...
            rows = np.array([e[0] for e in ev])
            idx = (np.array([e[1] for e in ev])[:, None] * S + columns[None, :])
            q_out[rows] = q[idx]
            i_out[rows] = servo.current[idx]
            qd_out[rows] = qd[idx]
        ev = writes.get(s)
        if ev is not None:  # ... and its goal reaches the servo later (at the same step at the least)
            rows = np.array([e[0] for e in ev])
            idx = (np.array([e[1] for e in ev])[:, None] * S + columns[None, :])
            goal[idx] = (run.goal[rows[:, None], slots.joint[None, :]] - off[idx]) * inv_r[idx]
            loop.set_goal(goal)
        tau = loop.step((q - off) * inv_r, qd * inv_r)
        joint_load = load[s].take(flat)
        speed = qd * abs_inv_r  # the shaft's speed, signed as the joint's
        dry = friction_level(p, speed, tau, -joint_load * r) * abs_inv_r
        q, qd = step_joints(q, qd, dt, tau * inv_r - viscous * qd - joint_load, inertia[s].take(flat) + extra,
                            dry, "smooth", speed, lower, upper)
    return q_out, i_out, qd_out
