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

from bench.kinematics.arc_train import ArcTrainParams
from bench.scene.room import SceneParams


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


def off_bed_problem(robot, x_mm: float, y_mm: float, z_mm: float) -> str | None:
    """Where the entry point lies off the bed, and by how much (mm), or None.

    The robot stands on the bed and the patient lies on it: an entry point beside the bed,
    beyond its ends or below its top is a typo, and said as such rather than as whatever
    interlock or reach limit it would meet first."""
    scene = SceneParams()
    width = getattr(getattr(robot, "params", None), "bed_width", ArcTrainParams().bed_width) * 1e3
    x0, x1 = scene.bed_x_min * 1e3, (scene.bed_x_min + scene.bed_length) * 1e3
    bed = f"the {width / 10:g} cm bed spans Y 0 to {width:g} mm and X {x0:g} to {x1:g} mm"
    edges = {"Y": ("left edge", "right edge"), "X": ("end away from the gantry", "far end, in the bore")}
    for axis, value, low, high in (("Y", y_mm, 0.0, width), ("X", x_mm, x0, x1)):
        if not low <= value <= high:
            below = value < low
            return (f"target: the entry point is off the bed, {axis} {value:g} mm being "
                    f"{(low - value) if below else (value - high):.1f} mm beyond its "
                    f"{edges[axis][0 if below else 1]} ({bed})")
    if z_mm < 0.0:
        return (f"target: the entry point is {-z_mm:.1f} mm below the bed top (Z {z_mm:g} mm; the "
                f"bed top is Z 0)")
    return None


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


