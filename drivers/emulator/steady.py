"""The bus's physics steps while every servo runs its position loop undisturbed, for all servos at
once: one pass over the encoders, the servo array's fused loop, the drive's torque and the overload
timers, instead of each servo's own step.

Between two instructions nothing a servo's firmware reads can change but the shaft, so each step of
such a stretch is the same arithmetic for every servo: read the encoder, run the servo array's loop,
turn current into torque, watch for an overload. Each servo's own step (its supervision, its loop
inputs, its reports) cost more than the loop and the plant together; here the constants are taken
once per stretch and the reports once at its end. The result is the same bit for bit (the same
IEEE operations in the same order: a test holds it), and what the step leaves to report is handed
back to each servo as its own step would have left it.

A stretch is steady while every servo has its torque on in a position mode, nothing forced and no
supervision fault due. Otherwise, and from the step where an overload trips, the servos take their
own path (:meth:`~drivers.emulator.firmware.ServoFirmware.begin_step`)."""

from __future__ import annotations

import math

import numpy as np

from drivers.emulator.plant import Plant
from drivers.emulator.servo import ServoModel
from drivers.servo.fast import PositionLoop

__all__ = ["run_steady"]


def run_steady(servos: list[tuple[ServoModel, int]], loop: PositionLoop, plant: Plant, steps: int) -> int:
    """Run up to ``steps`` physics steps on the steady path: ``servos`` (each with its plant joint)
    on ``loop`` (their array's position loop, fused where its plain case holds), driving ``plant``.
    Return how many ran (0: the stretch is not steady, the servos take their own path from the first
    step)."""
    constants = []
    for servo, _ in servos:
        c = servo.steady()
        if c is None:
            return 0
        constants.append(c)
    (sign, from_si, turn_offset, homing, torque_per_amp, overload_at, overload_time,
     timer, times) = (list(column) for column in zip(*constants))
    joints = [joint for _, joint in servos]
    dt = loop.dt
    n = plant.joint_count
    slots = range(len(joints))
    floor = math.floor
    done = 0
    while done < steps:
        q_all, v_all = plant.position().tolist(), plant.velocity().tolist()
        q = [q_all[j] for j in joints]
        v = [v_all[j] for j in joints]
        raw = [0.0] * len(joints)
        present = [0.0] * len(joints)
        for k in slots:
            times[k] += dt
            r = from_si[k](sign[k] * q[k]) + turn_offset[k]  # as each servo's encoder reads it
            raw[k] = r
            present[k] = float(floor(r + 0.5) + homing[k])
        current = loop.step_present(np.array(present), np.array([sign[k] * v[k] for k in slots])).tolist()
        new_timer = [timer[k] + dt if abs(current[k]) >= overload_at[k] else 0.0 for k in slots]
        if any(new_timer[k] > overload_time[k] for k in slots):  # an overload trips: the servos end this step
            _settle(servos, q, v, raw, times, timer, sign, drive=False)
            torque = [0.0] * n
            for servo, joint in servos:
                torque[joint] += servo.end_step(dt)
            plant.step(dt, np.array(torque))
            return done + 1
        timer = new_timer
        torque = [0.0] * n
        for k in slots:
            torque[joints[k]] += torque_per_amp[k] * current[k]
        plant.step(dt, np.array(torque))
        done += 1
    _settle(servos, q, v, raw, times, timer, sign, drive=True)
    return done


def _settle(servos: list[tuple[ServoModel, int]], q: list[float], v: list[float], raw: list[float],
            times: list[float], timer: list[float], sign: list[float], *, drive: bool) -> None:
    """Hand each servo the state the last step left it: its shaft as sensed, and with ``drive`` the
    array's drive (without, the servo ends the step itself)."""
    for slot, (servo, _) in enumerate(servos):
        servo.settle(q[slot], v[slot], raw[slot], times[slot], timer[slot], sign[slot], drive=drive)
