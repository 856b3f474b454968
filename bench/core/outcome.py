"""Where the needle ended up, compared with the target (a Table 3 row of seed 000)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from bench.core.log import TrialLog
from bench.kinematics.needle import NeedlePose, NeedleTarget

SETTLED_WINDOW_S = 0.1  # the median over this window of the insertion's settle is "achieved"


@dataclass(frozen=True)
class NeedleOutcome:
    """Achieved needle (mm, degrees) and its deviations from the target; passed per limits."""

    entry_mm: list[float]
    tip_mm: list[float]
    depth_mm: float
    angle_deg: float
    entry_deviation_mm: list[float]
    tip_deviation_mm: list[float]
    depth_deviation_mm: float
    angle_deviation_deg: float
    position_limit_mm: float
    angle_limit_deg: float
    passed: bool

    def as_dict(self) -> dict:
        return asdict(self)

    def failures(self) -> str:
        """What is over its limit, e.g. "tip Y -6.20 mm, angle +1.30° (limits 5 mm, 1°)"."""
        lim_mm, lim_deg = self.position_limit_mm, self.angle_limit_deg
        over = [f"{what} {axis} {v:+.2f} mm"
                for what, dev in (("entry", self.entry_deviation_mm), ("tip", self.tip_deviation_mm))
                for axis, v in zip("XYZ", dev) if abs(v) > lim_mm]
        if abs(self.depth_deviation_mm) > lim_mm:
            over.append(f"depth {self.depth_deviation_mm:+.2f} mm")
        if abs(self.angle_deviation_deg) > lim_deg:
            over.append(f"angle {self.angle_deviation_deg:+.2f}°")
        return f"{', '.join(over) or 'none'} (limits {lim_mm:g} mm, {lim_deg:g}°)"


def segment_rows(seg: np.ndarray, segment_names: Sequence[str], segment: str) -> np.ndarray:
    """Indices of the samples of ``segment``; KeyError listing the log's segments if it has none such."""
    try:
        si = list(segment_names).index(segment)
    except ValueError:
        raise KeyError(f"no segment {segment!r} in the log; it has {list(segment_names)}") from None
    return np.flatnonzero(seg == si)


def settle_rows(t: np.ndarray, seg: np.ndarray, segment_names: Sequence[str], segment: str,
                window: float = SETTLED_WINDOW_S) -> np.ndarray:
    """Indices of the last ``window`` s of ``segment``: where a placement is read (the settle)."""
    idx = segment_rows(seg, segment_names, segment)
    if idx.size == 0:
        raise ValueError(f"segment {segment!r} has no samples (the trial stopped before it)")
    return idx[t[idx] >= t[idx[-1]] - window]


def settled_position(log: TrialLog, segment: str, window: float = SETTLED_WINDOW_S) -> np.ndarray:
    """Median measured joint position over the last ``window`` s of ``segment``."""
    return np.median(log.q[settle_rows(log.time, log.segment, log.segment_names, segment, window)], axis=0)


def needle_outcome(robot, q: np.ndarray, target: NeedleTarget, position_limit_mm: float = 5.0,
                   angle_limit_deg: float = 1.0) -> NeedleOutcome:
    """Forward kinematics of the achieved joints, against the target and the limits."""
    return pose_outcome(robot.needle(q), target, position_limit_mm, angle_limit_deg)


def pose_outcome(pose: NeedlePose, target: NeedleTarget, position_limit_mm: float = 5.0,
                 angle_limit_deg: float = 1.0) -> NeedleOutcome:
    """A needle (the encoders' or the cameras'), against the target and the limits."""
    entry_dev = (pose.entry - np.asarray(target.entry)) * 1e3
    tip_dev = (pose.tip - target.tip) * 1e3
    depth_dev = (pose.depth - target.depth) * 1e3
    angle_dev = float(np.degrees(pose.angle - target.angle))
    tilt_dev = float(np.degrees(pose.out_of_plane - target.tilt))
    worst_angle = max(abs(angle_dev), abs(tilt_dev))
    passed = bool(np.all(np.abs(entry_dev) <= position_limit_mm)
                  and np.all(np.abs(tip_dev) <= position_limit_mm)
                  and abs(depth_dev) <= position_limit_mm and worst_angle <= angle_limit_deg)
    r = lambda v: [round(float(x), 6) + 0.0 for x in v]  # noqa: E731
    return NeedleOutcome(
        entry_mm=r(pose.entry * 1e3), tip_mm=r(pose.tip * 1e3),
        depth_mm=round(pose.depth * 1e3, 6), angle_deg=round(float(np.degrees(pose.angle)), 6),
        entry_deviation_mm=r(entry_dev), tip_deviation_mm=r(tip_dev),
        depth_deviation_mm=round(float(depth_dev), 6) + 0.0,
        angle_deviation_deg=round(angle_dev if abs(angle_dev) >= abs(tilt_dev) else tilt_dev, 6) + 0.0,
        position_limit_mm=position_limit_mm, angle_limit_deg=angle_limit_deg, passed=passed)
