"""Where the robot really was, beside what its sensors said.

A fault such as an encoder bias or backlash changes what the bench *reads*
as well as where the joint *is*; a trial's own outcome is computed from the
reads, as on the real rig. Seed 000 measured its needle with an external
camera (Table 3), so campaigns judge placement on the truth: on the
simulator, :class:`GroundTruth` records the backend's own joint positions
at every read, and :func:`true_outcome` puts the needle where they say. On
a rig (emulated or real) there is no such truth: a campaign judges its trials on
the cameras' tip where the config has cameras (bench.core.seen), else the
measured outcome stands.
"""

from __future__ import annotations

import numpy as np

from bench.core.log import TrialLog
from bench.core.outcome import SETTLED_WINDOW_S, NeedleOutcome, needle_outcome, segment_rows
from drivers import Actuators, ActuatorsWrapper, JointState
from drivers.capabilities import TruePosition, find_capability

__all__ = ["GroundTruth", "settled_truth", "true_outcome"]


class GroundTruth(ActuatorsWrapper):
    """Outermost wrapper (a recorder, not a fault): passes reads through unchanged and records
    the backend's true positions at each."""

    def __init__(self, actuators: Actuators) -> None:
        super().__init__(actuators)
        self._truth = find_capability(actuators.unwrapped, TruePosition)
        self.available = self._truth is not None
        self._t: list[float] = []
        self._q: list[np.ndarray] = []

    def read(self) -> JointState:
        st = self.actuators.read()
        if self._truth is not None:
            self._t.append(self.unwrapped.now())
            self._q.append(self._truth.true_position())
        return st

    @property
    def times(self) -> np.ndarray:
        return np.asarray(self._t)

    @property
    def positions(self) -> np.ndarray:
        return np.asarray(self._q).reshape(len(self._q), -1)


def settled_truth(log: TrialLog, truth: GroundTruth, segment: str = "insert",
                  window: float = SETTLED_WINDOW_S) -> np.ndarray:
    """Median true joint position over the last ``window`` s of ``segment`` (the log's window)."""
    idx = segment_rows(log.segment, log.segment_names, segment)
    if idx.size == 0 or not truth.available or not len(truth.times):
        raise ValueError(f"no true samples for segment {segment!r}")
    t_end = log.time[idx[-1]]
    t = truth.times
    keep = (t >= t_end - window - 1e-9) & (t <= t_end + 1e-9)
    if not keep.any():
        raise ValueError(f"no true samples in the last {window} s of segment {segment!r}")
    return np.median(truth.positions[keep], axis=0)


def true_outcome(log: TrialLog, truth: GroundTruth, robot, target, position_limit_mm: float,
                 angle_limit_deg: float) -> NeedleOutcome:
    """The needle where the true joints put it, judged against the limits."""
    q = settled_truth(log, truth)
    return needle_outcome(robot, q, target, position_limit_mm, angle_limit_deg)
