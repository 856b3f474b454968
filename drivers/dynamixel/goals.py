"""The goal positions a servo may be sent, in ticks: its operating mode's range and its joint's limits.

A transmission typo (a ``ratio`` of 1e-4 for 1, an ``offset`` of 100 for 1.0) turns a
small joint move into hundreds of shaft turns. In Position mode the firmware drops such a
goal without a word (a Sync Write gets no status) and the joint simply stays put; in the
extended modes the motor spins into its end stop; past ±2³¹ the packet cannot even be
built. So a transmission is checked against the servo's range before anything moves
(:func:`transmission_problem`, used by the config and at start-up), and every goal is
checked where it is computed from the transmission (:class:`GoalBounds`): one outside the
band is refused, naming the joint and the value, never clamped silently.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from drivers import BackendSetupError
from drivers.dynamixel.control_table import x_series_table
from drivers.errors import GoalOutOfRange

__all__ = ["GoalBounds", "GoalOutOfRange", "joint_ticks", "mode_ticks", "outside_limits",
           "transmission_problem"]


#: Goal Position: its unit (rad of shaft per tick) and centre tick convert every goal here.
_GOAL = x_series_table()["Goal Position"]
_CENTER = _GOAL.zero


def mode_ticks(mode: str) -> tuple[int, int]:
    """The goal positions (ticks) a servo accepts in ``mode``: one turn in Position mode (the
    Min/Max Position Limit registers' widest), ±256 turns (Goal Position's range) otherwise."""
    table = x_series_table()
    if mode == "position":
        return table["Min Position Limit"].minimum, table["Max Position Limit"].maximum
    goal = table["Goal Position"]
    return goal.minimum, goal.maximum


def joint_ticks(q: float | np.ndarray, ratio: float, offset: float,
                zero_tick: float = _CENTER) -> float | np.ndarray:
    """The shaft position (ticks, unrounded) at joint value ``q``: ``q = offset + ratio · shaft``."""
    return zero_tick + (np.asarray(q, dtype=float) - offset) / (ratio * _GOAL.scale)


def transmission_problem(joint: str, mode: str, ratio: float, offset: float, lower: float,
                         upper: float, zero_tick: float = _CENTER,
                         allowed: tuple[int, int] | None = None) -> str | None:
    """Why the joint's range [lower, upper] does not fit in the servo's range for ``mode``
    through this transmission (one line), or None. ``allowed``: the servo's own range, when
    read from it (default: the mode's widest)."""
    lo, hi = allowed if allowed is not None else mode_ticks(mode)
    if not (math.isfinite(ratio) and math.isfinite(offset)) or ratio == 0:
        return f"{joint}: ratio {ratio:g} and offset {offset:g} must be finite, the ratio non-zero"
    a, b = sorted(float(t) for t in joint_ticks(np.array([lower, upper]), ratio, offset, zero_tick))
    if lo <= a and b <= hi:
        return None
    span = f" ({(b - a) * _GOAL.scale / (2 * math.pi):,.1f} turns)" if b - a > hi - lo else ""
    return (f"{joint}: range [{lower:g}, {upper:g}] through ratio {ratio:g}, offset {offset:g} needs "
            f"goals of {a:,.0f} to {b:,.0f} ticks{span}; a servo in {mode} mode takes {lo:,} to {hi:,}")


class GoalBounds:
    """Per servo, the goal ticks allowed: a commanded goal within its joint's limits (plus
    ``slack`` joint units, e.g. the train loop's correction) and its mode's range; a hold goal
    (where the shaft already is) within its mode's range."""

    def __init__(self, joints: Sequence[str], ratio: np.ndarray, offset: np.ndarray,
                 zero: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 mode_range: Sequence[tuple[int, int]], slack: np.ndarray) -> None:
        self.joints = list(joints)
        self._ratio, self._offset, self._zero = ratio, offset, zero
        self.mode_lo = np.array([r[0] for r in mode_range], dtype=float)
        self.mode_hi = np.array([r[1] for r in mode_range], dtype=float)
        ends = np.sort(np.array([joint_ticks(lower - slack, ratio, offset, zero),
                                 joint_ticks(upper + slack, ratio, offset, zero)]), axis=0)
        # Half a tick each side: a goal exactly at a limit rounds to its nearest tick.
        self.lo = np.maximum(self.mode_lo, np.floor(ends[0] - 0.5))
        self.hi = np.minimum(self.mode_hi, np.ceil(ends[1] + 0.5))

    @classmethod
    def of(cls, servos: Sequence, lower: np.ndarray, upper: np.ndarray,
           position_limits: Callable[[int], tuple[int, int]], slack: Sequence[float]) -> "GoalBounds":
        """The bounds of a bus's servos (``ServoSettings``, with their joints' limits in servo
        order); ``position_limits(id)``: a Position-mode servo's Min/Max Position Limit as read.
        A transmission that cannot fit its joint's range in the servo's is refused
        (:class:`~drivers.BackendSetupError`) before torque is enabled."""
        allowed = []
        for k, sv in enumerate(servos):
            lo, hi = mode_ticks(sv.mode)
            if sv.mode == "position":
                low, high = position_limits(sv.id)
                lo, hi = max(lo, low), min(hi, high)
            problem = transmission_problem(sv.joint, sv.mode, sv.ratio, sv.offset, float(lower[k]),
                                           float(upper[k]), sv.zero_tick, (lo, hi))
            if problem:
                raise BackendSetupError(f"servo ID {sv.id}, {problem}; torque not enabled")
            allowed.append((lo, hi))
        return cls([sv.joint for sv in servos], np.array([sv.ratio for sv in servos], dtype=float),
                   np.array([sv.offset for sv in servos], dtype=float),
                   np.array([sv.zero_tick for sv in servos], dtype=float), np.asarray(lower, float),
                   np.asarray(upper, float), allowed, np.asarray(slack, dtype=float))

    def check(self, ticks: np.ndarray, hold: bool = False, q: np.ndarray | None = None) -> np.ndarray:
        """``ticks`` (whole numbers as floats, servo order) as int64 if every goal is allowed,
        else :class:`GoalOutOfRange` (checked before the cast: a NaN or 1e30 fails, never wraps).
        ``q``: the joint values they came from, for the message."""
        lo, hi = (self.mode_lo, self.mode_hi) if hold else (self.lo, self.hi)
        bad = np.flatnonzero(~((ticks >= lo) & (ticks <= hi)))
        if bad.size:
            i = int(bad[0])
            value = (float(q[i]) if q is not None else
                     self._offset[i] + self._ratio[i] * _GOAL.scale * (float(ticks[i]) - self._zero[i]))
            what = "its operating mode allows" if hold else "its joint's limits and its mode allow"
            raise GoalOutOfRange(
                f"{self.joints[i]}: goal {value:.6g} is {ticks[i]:,.0f} ticks, outside the "
                f"{lo[i]:,.0f} to {hi[i]:,.0f} {what}; not sent")
        return ticks.astype(np.int64)


def outside_limits(names: Sequence[str], q: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                   tolerance: float) -> str | None:
    """The first joint read beyond its limits by more than ``tolerance`` (one line), or None."""
    out = np.flatnonzero(~((q >= lower - tolerance) & (q <= upper + tolerance)))
    if not out.size:
        return None
    j = int(out[0])
    return f"{names[j]} reads {q[j]:.6g}, outside its limits [{lower[j]:g}, {upper[j]:g}]"
