"""How each joint of a robot is driven by its servo, and so how far the servo's tolerance lets it stray.

Revolute joints are direct drive (1); prismatic joints a rack and pinion (the pinion radius,
m/rad); the arc-and-train robot's train rides the arc's rack on the same pinion (R_pinion/R_arc).

Seed 000 section 6 (the deviation analysis) puts the tolerance in the actuators: "the
dynamixel servo actuators ... are ±0.29°; deviation in reaching the target position will
occur if an actuator overshoots or undershoots by 0.29°". A joint strays by that servo
error through its transmission: ±0.29° on a direct-drive joint, ±0.0506 mm on a slide, and
±0.0145° of arc angle on the train (10 mm pinion on the 200 mm arc). :func:`servo_tolerances`
is that one derivation; the accuracy budget, the comparison's settling bands and the deadband
fault's defaults all take it from here.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from bench.kinematics.arc_train import PINION_RADIUS, SERVO_TOL_DEG, ArcTrainRobot
from bench.kinematics.needle import NeedleRobot
from bench.kinematics.registry import ROBOTS

__all__ = ["SERVO_TOL_DEG", "servo_tolerances", "servo_transmissions", "slide_tolerance_m",
           "transmissions_for_names"]


def servo_transmissions(robot: NeedleRobot) -> np.ndarray:
    """Joint motion per radian of servo shaft: 1 (direct drive), the pinion radius (m) or R_pinion/R_arc."""
    ratio = np.array([PINION_RADIUS if r.kind == "prismatic" else 1.0 for r in robot.chain.rows])
    if isinstance(robot, ArcTrainRobot):
        ratio[list(robot.joint_names).index("train")] = PINION_RADIUS / robot.params.arc_radius
    return ratio


def servo_tolerances(robot: NeedleRobot, tol_deg: float = SERVO_TOL_DEG) -> np.ndarray:
    """Per joint, how far (rad or m) a servo holding its goal to ±``tol_deg`` lets the joint stray."""
    if not (math.isfinite(tol_deg) and tol_deg >= 0.0):
        raise ValueError(f"servo tolerance must be a non-negative number of degrees, got {tol_deg!r}")
    return math.radians(tol_deg) * servo_transmissions(robot)


def slide_tolerance_m(tol_deg: float = SERVO_TOL_DEG) -> float:
    """A rack-and-pinion slide's tolerance (m) for a servo holding ±``tol_deg``."""
    return math.radians(tol_deg) * PINION_RADIUS


@lru_cache(maxsize=None)
def _known(joint_names: tuple[str, ...]) -> tuple[float, ...] | None:
    for factory in ROBOTS.values():
        robot = factory()
        if tuple(robot.joint_names) == joint_names:
            return tuple(float(r) for r in servo_transmissions(robot))
    return None


def transmissions_for_names(joint_names, kinds) -> np.ndarray:
    """:func:`servo_transmissions` of the known robot with these joints; for joints no robot
    has, direct drive for revolute joints and the pinion for prismatic ones."""
    known = _known(tuple(joint_names))
    if known is not None:
        return np.array(known)
    return np.array([PINION_RADIUS if k == "prismatic" else 1.0 for k in kinds])
