"""Weak joints: a joint's available torque or force scaled down.

Seed 000 saw its torque-heavy joints lag the trajectory; with less torque
than the gravity load a joint stalls. The backend does the limiting —
PyBullet through the motor's maximum force, a Dynamixel through Goal Current
— behind one extra method, ``set_effort_limit(joint_index, effort)``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from bench.faults.base import FaultWrapper
from drivers import Actuators, BackendSetupError
from drivers.capabilities import EffortLimited, require_capability

__all__ = ["TorqueLimit", "check_effort_limit"]


def check_effort_limit(actuators: Actuators) -> None:
    """Refuse, naming the backend, when it cannot limit a joint's effort."""
    require_capability(actuators, EffortLimited, "torque_limit")


class TorqueLimit(FaultWrapper):
    """Scales the effort limit of ``joints`` by ``scale`` when the stack is built."""

    def __init__(self, actuators: Actuators, joints: Sequence[str], scale: float) -> None:
        super().__init__(actuators)
        check_effort_limit(actuators)
        if not 0 < scale <= 1:
            raise BackendSetupError(f"torque_limit scale must be in (0, 1], got {scale}")
        self.scale = float(scale)
        backend = require_capability(actuators, EffortLimited, "torque_limit")
        effort = np.asarray(self.unwrapped.limits.effort, dtype=float)
        self.joints = list(joints)
        self.effort = {}
        for j in self._index(joints):
            backend.set_effort_limit(int(j), float(effort[j] * scale))
            self.effort[self.joint_names[j]] = float(effort[j] * scale)
