"""Stand-ins for a backend in the fault tests: the arc-and-train robot's joints, kinematic."""

from __future__ import annotations

import numpy as np

from bench.kinematics.arc_train import JOINTS
from drivers import ActuatorsBase, JointLimits, JointState


class Kinematic(ActuatorsBase):
    """A perfect arc-train stand-in: joints are wherever they were last commanded."""

    def __init__(self, q0=None, **extras) -> None:
        n = len(JOINTS)
        self.q = np.zeros(n) if q0 is None else np.array(q0, float)
        self.t = 0.0
        self._limits = JointLimits(np.full(n, -10.0), np.full(n, 10.0), np.ones(n), np.ones(n))
        for k, v in extras.items():
            setattr(self, k, v)

    joint_names = property(lambda self: list(JOINTS))
    limits = property(lambda self: self._limits)

    def read(self) -> JointState:
        return JointState(self.t, self.q.copy(), np.zeros(len(self.q)), np.zeros(len(self.q)))

    def now(self) -> float:
        return self.t

    def wait_until(self, t: float) -> None:
        self.t = max(self.t, t)

    def _enable(self) -> None:
        pass

    def _disable(self) -> None:
        pass

    def _command(self, position, velocity) -> None:
        self.q = position.copy()

    def _close(self) -> None:
        pass
