"""Checks made before anything moves, on the plan alone: what `hilbench check` reports.

A config can be valid and its target reachable and still be a mistake a
technician would only see once the robot moves: a needle pointing up, away
from the bed (``angle_deg: 147`` for 47), or a planned path that would run into
an interlock (the gantry margin, a joint limit). These checks replay the plan
as a perfectly tracking robot would follow it through the trial's own
interlocks, so a trial that would be stopped by them is refused before
``enable()`` instead.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from drivers import JointLimits



@dataclass(frozen=True)
class PathTrip:
    """Where the planned path trips an interlock: segment, time into the plan (s), cause."""

    segment: str
    time: float
    interlock: str
    cause: str

    def message(self) -> str:
        return (f"the planned path trips the {self.interlock} interlock during {self.segment} "
                f"({self.time:.2f} s into the plan): {self.cause}; nothing moved")


def needle_direction_problem(robot, q_insert: np.ndarray, angle_deg: float) -> str | None:
    """Why the needle at the insertion pose cannot be inserted into the patient, or None.

    The bed frame's z points up, away from the bed: an insertion that goes up is a
    typo (an angle measured from the wrong side), not a trial.
    """
    direction = np.asarray(robot.needle(q_insert).direction, dtype=float)
    if direction[2] >= 0.0:
        tilt = float(np.degrees(np.arccos(np.clip(-direction[2], -1.0, 1.0))))
        return (f"target: angle_deg {angle_deg:g}° does not point the needle down into the bed "
                f"({tilt:.0f}° from straight down); insertion angles lie strictly between -90° "
                f"and 90°")
    return None


def planned_path_trip(segments: Sequence, interlocks, control_period: float) -> PathTrip | None:
    """The first interlock trip along the planned segments followed perfectly, cycle by cycle, or None."""
    if interlocks is None:
        return None
    dt = control_period
    start = 0.0
    for seg in segments:
        duration = float(seg.trajectory.duration)
        times = np.append(np.arange(0.0, duration, dt), duration)
        position, velocity, _ = seg.trajectory.sample(times)
        position = np.atleast_2d(position)
        velocity = np.atleast_2d(velocity)
        hit = interlocks.scan(start + times, position, velocity, np.zeros_like(position), position)
        if hit is not None:
            k, trip = hit
            return PathTrip(seg.name, float(start + times[k]), trip.interlock, trip.cause)
        start += duration + seg.settle
    return None


def port_problems(config) -> list[str]:
    """What is wrong with a real backend's serial ports (missing, no permission)."""
    b = config.backend
    if b.kind != "dynamixel":
        return []
    ports = [("servo", b.port)] + ([("ultrasonic", b.ultrasonic.port)] if b.ultrasonic else [])
    problems = []
    for what, port in ports:
        if not os.path.exists(port):
            problems.append(f"{what} port {port} not found (is the adapter plugged in? rehearse "
                            f"without hardware with --emulate)")
        elif not os.access(port, os.R_OK | os.W_OK):
            problems.append(f"no read/write permission on the {what} port {port}: "
                            f"`sudo usermod -aG dialout $USER`, then log in again")
    return problems


def limits_of(rows, overrides=None) -> JointLimits:
    """Joint limits from the robot's rows, with a backend's per-joint velocity/effort overrides."""
    overrides = overrides or {}

    def pick(row, name: str) -> float:
        o = overrides.get(row.name)
        value = getattr(o, name, None) if o is not None else None
        return float(value) if value else float(getattr(row, name))

    return JointLimits(np.array([r.lower for r in rows]), np.array([r.upper for r in rows]),
                       np.array([pick(r, "velocity") for r in rows]),
                       np.array([pick(r, "effort") for r in rows]))


@dataclass(frozen=True)
class CheckResult:
    """One named check of `hilbench check`: passed or not, and what it found."""

    name: str
    ok: bool
    detail: str


def check_config(path, emulate: bool = False) -> list[CheckResult]:
    """Every check a trial makes before moving, on a config file; stops at the first failure.

    ``emulate``: the ports will be the emulated rig's, so the configured ones are not checked.
    """
    from bench.config.models import ConfigError, load_trial_config
    from bench.trial.run import TrialError, prepare

    try:
        config = load_trial_config(path)
    except ConfigError as e:
        return [CheckResult("config", False, str(e))]
    results = [CheckResult("config", True, f"{config.name}: {config.robot}, {config.backend.kind} "
                                           f"backend, {config.control_hz:g} Hz")]
    try:
        prep = prepare(config)
    except TrialError as e:
        return results + [CheckResult("target and plan", False, str(e))]
    entry = prep.robot.needle(prep.q_insert)
    results.append(CheckResult(
        "target and plan", True,
        f"reachable; needle {np.degrees(entry.angle):.1f}° into the bed; the planned path "
        f"clears every interlock" + ("" if config.safety.enabled else " (interlocks disabled)")))
    if config.backend.kind == "dynamixel" and not emulate:
        problems = port_problems(config)
        results.append(CheckResult("ports", not problems, "; ".join(problems) or "present and "
                                                                                 "writable"))
    return results
