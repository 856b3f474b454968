"""How each joint of a robot is driven by its servo: joint motion per shaft radian.

Revolute joints are direct drive (1); prismatic joints a rack and pinion (the pinion radius,
m/rad); the arc-and-train robot's train rides the arc's rack on the same pinion (R_pinion/R_arc).
The accuracy study turns servo tolerances into joint tolerances with it; the simulator's
default servo table drives the joints with it.
"""

from __future__ import annotations

import numpy as np

from bench.kinematics.arc_train import PINION_RADIUS, ArcTrainRobot
from bench.kinematics.needle import NeedleRobot

__all__ = ["servo_transmissions"]


def servo_transmissions(robot: NeedleRobot) -> np.ndarray:
    """Joint motion per radian of servo shaft: 1 (direct drive), the pinion radius (m) or R_pinion/R_arc."""
    ratio = np.array([PINION_RADIUS if r.kind == "prismatic" else 1.0 for r in robot.chain.rows])
    if isinstance(robot, ArcTrainRobot):
        ratio[list(robot.joint_names).index("train")] = PINION_RADIUS / robot.params.arc_radius
    return ratio
