"""Enable's last step: wait until every servo holds still at its goal, so a plan starts from servos
at rest rather than from one still taking up its load.

A servo switched on under a load (gravity on the wrist) sags until its proportional term carries
it, overshooting on the way; one found holding comes back to its goal as its integrator charges.
A plan that started from such a reading would command where the joint happened to be, and the
load it carried would drop again: Target 1's wrist swung 9° that way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Optional, Sequence

import numpy as np

from drivers.clock import WALL, Clock

if TYPE_CHECKING:
    from drivers.dynamixel.settings import DynamixelSettings

__all__ = ["SETTLE_POLL_S", "settle", "settle_all"]

#: How often the servos are read while they settle (s).
SETTLE_POLL_S = 0.01


def settle(read_state: Callable[[], Optional[np.ndarray]], goals: np.ndarray, integrating: np.ndarray,
           joints: Sequence[str], *, ticks: int, still_s: float, timeout_s: float,
           clock: Clock = WALL) -> Optional[str]:
    """Read the servos (``read_state``: raw rows, Present Position in ticks first, servo order) until
    every servo with an integrator is within ``ticks`` of its goal and none has moved over a tick for
    ``still_s``; a servo without one (it cannot reach its goal under a load) need only be still.
    None once settled, else after ``timeout_s`` what had not settled, in one line."""
    goals = np.asarray(goals, dtype=float)
    start = clock.now()
    anchor, since, unsettled = None, start, np.ones(len(goals), bool)
    while True:
        raw = read_state()
        now = clock.now()
        if raw is not None:
            present = np.array(raw[0], dtype=float)
            moved = np.zeros(len(goals), bool) if anchor is None else np.abs(present - anchor) > 1
            unsettled = (integrating & (np.abs(present - goals) > ticks)) | moved
            if anchor is None or unsettled.any():
                anchor, since = present, now  # the still window starts again
            elif now - since >= still_s:
                return None
        if now - start > timeout_s:
            far = [f"{j} {anchor[k] - goals[k]:+.0f} ticks" for k, j in enumerate(joints)
                   if anchor is not None and unsettled[k]]
            return (f"the servos had not settled {timeout_s:g} s after torque on"
                    + (f": {', '.join(far)} from their goals" if far else " (no reading)"))
        clock.sleep(SETTLE_POLL_S)


def settle_all(settings: "DynamixelSettings", read_i_gain: Callable[[int], int],
               read_state: Callable[[], Optional[np.ndarray]], goals: np.ndarray,
               clock: Clock = WALL) -> Optional[str]:
    """:func:`settle` for a backend's servos as ``settings`` lists them (nothing when its timeout is
    0): a servo integrates when its configured I gain, or the one it holds (``read_i_gain(id)``), is
    over 0."""
    if settings.settle_timeout_s <= 0:
        return None
    i_gains = [sv.gains[1] if sv.gains[1] is not None else read_i_gain(sv.id) for sv in settings.servos]
    return settle(read_state, goals, np.array(i_gains) > 0, [sv.joint for sv in settings.servos],
                  ticks=settings.settle_ticks, still_s=settings.settle_still_s,
                  timeout_s=settings.settle_timeout_s, clock=clock)
