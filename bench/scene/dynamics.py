"""Static robot dynamics from the URDF: the gravity load each joint carries at a pose.

One place for what the compare report (the paper's torque requirement) and the
calibration (a zero read under load sags by it) both need.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from bench.paths import robot_urdf
from drivers.quiet import quiet_pybullet

__all__ = ["gravity_torques"]


def gravity_torques(robot: str, q: Sequence[float], urdf_dir: Optional[Path | str] = None,
                    gravity: float = 9.81) -> np.ndarray:
    """Signed torque (N·m) or force (N) each joint must exert to hold pose ``q`` still,
    from PyBullet's inverse dynamics on the robot's URDF (masses and inertias from the file)."""

    q = np.asarray(q, dtype=float)
    pb = quiet_pybullet()
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(robot_urdf(robot, urdf_dir)), useFixedBase=True,
                           flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        pb.setGravity(0, 0, -gravity, physicsClientId=c)
        zeros = [0.0] * q.size
        tau = pb.calculateInverseDynamics(body, q.tolist(), zeros, zeros, physicsClientId=c)
    finally:
        pb.disconnect(c)
    return np.asarray(tau, dtype=float)
