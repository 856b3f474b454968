"""Faults of the ultrasonic sensor that measures the train's position on the arc.

The train's feedback is the distance d2 (seed 000, section 6), so these act
on the ``train`` joint's measured arc angle ε, in the sensor's own terms:
a dropout holds the last reading and flags it ``stale:train``; a stuck
sensor repeats one reading without any flag (which is what makes it
dangerous); noise is Gaussian in d2 (metres), mapped back to ε through the
arc's geometry (eqs 14/17).
"""

from __future__ import annotations

import math

import numpy as np

from bench.faults.base import FaultWrapper
from bench.kinematics.arc_train import ArcTrainParams, epsilon_from_d2, train_pose
from drivers import Actuators, JointState

__all__ = ["UltrasonicDropout", "UltrasonicNoise", "UltrasonicStuck"]


class _TrainFault(FaultWrapper):
    def __init__(self, actuators: Actuators, joint: str = "train") -> None:
        super().__init__(actuators)
        self.joint = joint
        self._j = int(self._index([joint])[0])

    def _with_train(self, st: JointState, value: float, flags: tuple[str, ...] = ()) -> JointState:
        q = st.position.copy()
        q[self._j] = value
        return JointState(st.time, q, st.velocity, st.effort, st.flags + flags)


class UltrasonicDropout(_TrainFault):
    """A reading missing with probability ``prob``: the last one is held, flagged stale."""

    def __init__(self, actuators: Actuators, prob: float, rng: np.random.Generator,
                 joint: str = "train") -> None:
        super().__init__(actuators, joint)
        self.prob = float(prob)
        self._rng = rng
        self._last: float | None = None
        self.dropouts = 0

    def read(self) -> JointState:
        st = self.actuators.read()
        if self._rng.random() < self.prob and self._last is not None:
            self.dropouts += 1
            return self._with_train(st, self._last, (f"stale:{self.joint}",))
        self._last = float(st.position[self._j])
        return st


class UltrasonicStuck(_TrainFault):
    """From ``at`` s after the first read, for ``duration`` s (forever by default),
    the sensor repeats the reading it had when it stuck."""

    def __init__(self, actuators: Actuators, at: float = 0.0, duration: float = math.inf,
                 joint: str = "train") -> None:
        super().__init__(actuators, joint)
        self.at = float(at)
        self.duration = float(duration)
        self._t0: float | None = None
        self._held: float | None = None

    def read(self) -> JointState:
        st = self.actuators.read()
        if self._t0 is None:
            self._t0 = st.time
        t = st.time - self._t0
        if self.at <= t < self.at + self.duration:
            if self._held is None:
                self._held = float(st.position[self._j])
            return self._with_train(st, self._held)
        return st


class UltrasonicNoise(_TrainFault):
    """Gaussian noise of ``std`` metres on d2, seen as the train's arc angle."""

    def __init__(self, actuators: Actuators, std: float, rng: np.random.Generator,
                 params: ArcTrainParams | None = None, joint: str = "train") -> None:
        super().__init__(actuators, joint)
        self.std = float(std)
        self._rng = rng
        self._params = params or ArcTrainParams()

    def read(self) -> JointState:
        st = self.actuators.read()
        d2 = train_pose(float(st.position[self._j]), self._params).d2
        d2_measured = d2 + self._rng.normal(0.0, self.std)
        return self._with_train(st, float(epsilon_from_d2(d2_measured, self._params)))
