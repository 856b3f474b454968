"""A trial config's cross-references, checked at validation: what one field says about another.

Each field can be valid on its own and the file still nonsense: a sensor said to
measure a joint it cannot see, two devices on one port, a start pose outside the
joints' limits, a transmission that maps a joint's range beyond its servo's. These are
refused here, at validation (so by ``hilbench check`` too), with one line naming the
field, before anything is built or moves.
"""

from __future__ import annotations

import os
from typing import Any, Protocol

from bench.faults import parse_faults
from bench.kinematics.registry import get_robot
from drivers.dynamixel.goals import transmission_problem

__all__ = ["SENSED_JOINTS", "check_cross_references", "transmission_refusal"]

#: The joint a robot's ultrasonic sensor measures (arc-train: the train's d2 on the arc).
SENSED_JOINTS = {"arc-train": "train"}


class CrossReferenced(Protocol):
    """What the cross-references read of a trial config (``bench.config.models.TrialConfig``):
    written here so this module does not import the models, which call it."""

    robot: str
    backend: Any
    emulator: Any
    excitation: Any
    faults: Any
    safety: Any
    acceptance: Any
    cameras: Any


def check_cross_references(config: CrossReferenced) -> list:
    """Raise ValueError (one line, naming the field) for the first reference that does not hold;
    the faults as parsed (checked against the robot's joints), for the trial to keep."""
    robot = get_robot(config.robot)
    names = list(robot.joint_names)
    _joint_names(config, names)
    _backend(config, robot, names)
    if config.acceptance.by == "camera" and config.cameras is None:
        raise ValueError("acceptance.by: camera needs a cameras: section (the two views)")
    return parse_faults(config.faults, names) if config.faults else []  # ValueError names a bad one


def _unknown(where: str, keys, names: list[str], config: CrossReferenced, extra: frozenset = frozenset()):
    unknown = sorted(set(keys) - set(names) - extra)
    if unknown:
        raise ValueError(f"{where}: unknown joint(s) {unknown}; {config.robot} has {names}"
                         + (" (or all)" if extra else ""))


def _joint_names(config: CrossReferenced, names: list[str]) -> None:
    b = config.backend
    for key in ("joints", "start", "start_effort"):
        _unknown(f"backend.{key}", getattr(b, key, {}), names, config)
    ex = config.excitation
    if ex is not None and ex.joints != "all":
        _unknown("excitation.joints", ex.joints, names, config)
        if not ex.joints:
            raise ValueError(f"excitation.joints: no joint named; {config.robot} has {names}")
    if ex is not None and ex.f1_hz <= ex.f0_hz:
        raise ValueError(f"excitation.f1_hz ({ex.f1_hz:g}) must be above f0_hz ({ex.f0_hz:g})")
    for key, physics in (("emulator", config.emulator.servo_physics),
                         ("backend", getattr(b, "servo_physics", {}))):
        _unknown(f"{key}.servo_physics", physics, names, config, frozenset({"all"}))
    _unknown("emulator.joint_friction", config.emulator.joint_friction, names, config)
    if b.kind == "dynamixel" or b.servos:
        servos = set(b.servos)
        if servos != set(names):
            raise ValueError(f"backend.servos: missing {sorted(set(names) - servos)}, "
                             f"unknown {sorted(servos - set(names))}; {config.robot} has {names}")


def _backend(config: CrossReferenced, robot, names: list[str]) -> None:
    b = config.backend
    rows = {r.name: r for r in robot.chain.rows}
    u = b.ultrasonic
    if u is not None:
        sensed = SENSED_JOINTS.get(config.robot)
        if u.joint != sensed:
            raise ValueError(f"backend.ultrasonic.joint: the sensor reads the train's distance d2 on "
                             f"the arc, so it measures {sensed!r} only, not {u.joint!r}")
        if b.kind == "dynamixel" and _same_port(u.port, b.port):
            raise ValueError(f"backend.ultrasonic.port: {u.port} is the servo bus's port "
                             f"(backend.port) too; the sensor needs a port of its own")
    for name, servo in b.servos.items():
        problem = transmission_refusal(name, servo.mode, servo.ratio, servo.offset, rows[name])
        if problem:
            raise ValueError(f"backend.servos.{problem}")
    if b.kind != "pybullet":
        return
    tol = config.safety.joint_limit_tolerance  # a rig's reading a tick past a limit: clipped
    for name, value in b.start.items():
        row = rows[name]
        if not row.lower - tol <= value <= row.upper + tol:
            raise ValueError(f"backend.start.{name}: {value:g} {_unit(row)} is outside its limits "
                             f"[{row.lower:g}, {row.upper:g}] (± {tol:g}, safety.joint_limit_tolerance)")
    for name, value in b.start_effort.items():
        row, override = rows[name], b.joints.get(name)
        limit = override.effort if override is not None and override.effort else row.effort
        if not abs(value) <= limit:
            raise ValueError(f"backend.start_effort.{name}: {value:g} {_effort_unit(row)} is beyond "
                             f"its effort limit ±{limit:g} {_effort_unit(row)}")


def transmission_refusal(name: str, mode: str, ratio: float, offset: float, row) -> str | None:
    """Why a servo of ``mode`` cannot drive joint ``row``'s range through ratio and offset, or None."""
    return transmission_problem(name, mode, ratio, offset, float(row.lower), float(row.upper))


def _same_port(a: str, b: str) -> bool:
    return a == b or os.path.realpath(a) == os.path.realpath(b)


def _unit(row) -> str:
    return "rad" if row.kind == "revolute" else "m"


def _effort_unit(row) -> str:
    return "N·m" if row.kind == "revolute" else "N"

