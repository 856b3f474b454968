"""The robots, poses and joint tolerances the accuracy study works on (SI; tolerances ± per joint)."""

from __future__ import annotations

from typing import Literal, Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.arc_train import SERVO_TOL_DEG, TARGET_1
from bench.kinematics.needle import UnreachableError
from bench.kinematics.para_brachy import ParaBrachyRobot
from bench.kinematics.transmission import servo_tolerances

Distribution = Literal["uniform", "normal", "endpoints"]
DISTRIBUTIONS: tuple[str, ...] = ("uniform", "normal", "endpoints")
Tolerances = Union[None, Mapping[str, float], Sequence[float], np.ndarray]

DEG = np.pi / 180.0
PAPER_EPS_LINEAR = 0.05e-3  #: seed 003's ε for a sliding joint (m)
PAPER_EPS_ANGULAR = 0.05 * DEG  #: seed 003's ε for a rotating joint (rad)


# ---------------------------------------------------------------------------
# Robots, poses and tolerances
# ---------------------------------------------------------------------------

def robot_label(robot) -> str:
    return str(getattr(robot, "name", type(robot).__name__))


def _rows(robot) -> tuple:
    return tuple(robot.chain.rows)


def _kinds(robot) -> tuple[str, ...]:
    return tuple(r.kind for r in _rows(robot))


def _names(robot) -> tuple[str, ...]:
    return tuple(robot.joint_names)


def default_pose(robot) -> np.ndarray:
    """Where the budget is taken when no pose is given (see the module notes)."""
    home = np.array([r.home for r in _rows(robot)], dtype=float)
    if isinstance(robot, ParaBrachyRobot):
        return home
    try:
        return np.asarray(robot.ik(TARGET_1), dtype=float)
    except UnreachableError:
        return home


def pose_from_joints(robot, values: Mapping[str, float], base: Optional[ArrayLike] = None) -> np.ndarray:
    """Joint dict (SI) → vector; missing joints from ``base`` (default pose); checked against limits."""
    names = _names(robot)
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"unknown joint(s) {unknown}; {robot_label(robot)} joints are {list(names)}")
    q = default_pose(robot) if base is None else np.array(base, dtype=float)
    for i, n in enumerate(names):
        if n in values:
            v = values[n]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"joint {n} must be a finite number (rad or m), got {v!r}")
            q[i] = float(v)
    _check_limits(robot, q)
    return q


def _check_limits(robot, q: np.ndarray) -> None:
    for n, v, r in zip(_names(robot), q, _rows(robot)):
        if not r.lower - 1e-12 <= v <= r.upper + 1e-12:
            raise ValueError(f"joint {n} = {v:.6g} is outside its limits [{r.lower:.6g}, {r.upper:.6g}]")


def default_tolerances(robot, tol_deg: float = SERVO_TOL_DEG) -> np.ndarray:
    """±tolerance per joint (rad or m) for servos holding ±``tol_deg`` through their transmissions
    (:func:`bench.kinematics.transmission.servo_tolerances`, the one derivation)."""
    return servo_tolerances(robot, tol_deg)


def per_joint(names: Sequence[str], defaults: np.ndarray, given, what: str, *, positive: bool = False) -> np.ndarray:
    """Per-joint values (SI): ``defaults``, overridden by a {joint: value} mapping or replaced by a
    full vector; ValueError naming ``what`` and the joint when a value is unknown or out of range."""
    out = np.array(defaults, dtype=float)
    if given is None:
        return out
    if isinstance(given, Mapping):
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise ValueError(f"{what} for unknown joint(s) {unknown}; joints are {list(names)}")
        for i, n in enumerate(names):
            if n in given:
                out[i] = float(given[n])
    else:
        arr = np.asarray(given, dtype=float)
        if arr.shape != (len(names),):
            raise ValueError(f"expected {len(names)} {what} values ({', '.join(names)}), got shape {arr.shape}")
        out = arr.copy()
    for n, v in zip(names, out):
        if not (np.isfinite(v) and (v > 0.0 if positive else v >= 0.0)):
            raise ValueError(f"{what} of joint {n} must be {'positive' if positive else 'finite and >= 0'}, "
                             f"got {float(v)!r}")
    return out


def resolve_tolerances(robot, tolerances: Tolerances = None, tol_deg: float = SERVO_TOL_DEG) -> np.ndarray:
    """Per-joint tolerances (SI): defaults, a {joint: tol} override, or a full vector."""
    return per_joint(_names(robot), default_tolerances(robot, tol_deg), tolerances, "tolerance")


def _sigma(tol: np.ndarray, distribution: str) -> np.ndarray:
    """1σ of each joint's error under ``distribution``."""
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution must be one of {DISTRIBUTIONS}, got {distribution!r}")
    return tol if distribution == "endpoints" else tol / np.sqrt(3.0)


def _joint_index(robot, joint: Union[str, int]) -> int:
    names = _names(robot)
    if isinstance(joint, str):
        if joint not in names:
            raise ValueError(f"unknown joint {joint!r}; {robot_label(robot)} joints are {list(names)}")
        return names.index(joint)
    if isinstance(joint, (int, np.integer)) and 0 <= joint < len(names):
        return int(joint)
    raise ValueError(f"joint must be a name in {list(names)} or an index 0..{len(names) - 1}, got {joint!r}")


# ---------------------------------------------------------------------------
# Forward kinematics in batches
# ---------------------------------------------------------------------------


def _psi_theta(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seed 003's ψ (azimuth) and θ (from the downward vertical) of unit directions (…, 3)."""
    return np.arctan2(d[..., 1], d[..., 0]), np.arctan2(np.hypot(d[..., 0], d[..., 1]), -d[..., 2])


def _axis_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors, accurate for tiny angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
