"""A test-stand recording, written in BAM's raw log format so ``predict`` and ``identify`` (and
BAM's own tools) read it as they read the real XL330's.

Each cycle the host writes the trajectory's goal (and torque enable when it changes), then
reads position, velocity, supply and temperature; ``wait`` paces the cycles (real time on a
real stand, the emulator's physics advanced by one period on an emulated one)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from bench.stand.trajectories import DURATION_S, trajectory
from drivers.dynamixel.stand import StandServo

__all__ = ["record_stand_log", "write_stand_log"]


def record_stand_log(servo: StandServo, name: str, *, kp: int, mass: float, length: float, vin: float,
                     wait: Callable[[float], float], period_s: float = 0.005, duration_s: float = DURATION_S,
                     settle_s: float = 1.0, motor: str = "xl330") -> dict:
    """One run of trajectory ``name`` at P gain ``kp``: the log as BAM records it, after
    ``settle_s`` holding the trajectory's start (as BAM's recorder does). ``wait(dt)`` lets ``dt``
    s pass and returns a clock (s)."""
    goal_of = trajectory(name)
    goal, on = goal_of(0.0)
    servo.set_p_gain(kp)
    servo.goal(goal)
    servo.torque(on)
    log = {"mass": mass, "length": length, "arm_mass": 0.0, "kp": kp, "vin": vin, "motor": motor,
           "trajectory": name, "entries": []}
    start = wait(settle_s)
    t = 0.0
    while t < duration_s:
        goal, now_on = goal_of(t)
        if now_on != on:
            servo.torque(now_on)
            on = now_on
        if on:
            servo.goal(goal)
        s = servo.sample()
        log["entries"].append({"position": s.position, "speed": s.velocity, "load": 0, "input_volts": s.volts,
                               "temp": s.temperature, "timestamp": t, "goal_position": goal,
                               "torque_enable": on})
        t = wait(period_s) - start
    return log


def write_stand_log(log: dict, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(log), encoding="utf-8")
    return path
