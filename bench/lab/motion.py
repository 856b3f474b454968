"""Moving joints gently from a lab tool: commands that follow a target at a limited speed.

A trial streams a planned trajectory; a tool only knows where a joint should
end up. :class:`Ramp` turns that into a command stream the servos can follow
(the host streams goals with the servos' profiles off, so a jump in the goal
would be a jump at full speed).
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from drivers import Actuators, JointState

__all__ = ["Ramp", "move", "wait_still"]


class Ramp:
    """Commanded positions moving towards ``target`` at no more than ``speed`` per joint (SI)."""

    def __init__(self, start: np.ndarray, speed: np.ndarray) -> None:
        self.command = np.asarray(start, dtype=float).copy()
        self.target = self.command.copy()
        self.speed = np.asarray(speed, dtype=float)

    @property
    def done(self) -> bool:
        return bool(np.all(self.command == self.target))

    def step(self, dt: float) -> np.ndarray:
        """The next command, one period ``dt`` (s) later."""
        limit = self.speed * dt
        self.command = self.command + np.clip(self.target - self.command, -limit, limit)
        return self.command


def move(act: Actuators, ramp: Ramp, target: np.ndarray, period: float = 0.02,
         on_cycle: Optional[Callable[[JointState], None]] = None) -> JointState:
    """Stream the ramp to ``target`` through enabled actuators; the last state read."""
    ramp.target = act.limits.clip(np.asarray(target, dtype=float))
    t = act.now()
    st = act.read()
    while not ramp.done:
        act.command(ramp.step(period))
        t += period
        act.wait_until(t)
        st = act.read()
        if on_cycle is not None:
            on_cycle(st)
    return st


def wait_still(act: Actuators, joint: int, tolerance: float, window_s: float = 0.25,
               timeout_s: float = 5.0) -> bool:
    """Wait until a joint has moved less than ``tolerance`` over ``window_s``; False on timeout."""
    t0 = act.now()
    history: list[tuple[float, float]] = []
    while act.now() - t0 < timeout_s:
        st = act.read()
        history.append((st.time, float(st.position[joint])))
        history = [h for h in history if st.time - h[0] <= window_s]
        span = max(h[1] for h in history) - min(h[1] for h in history)
        if st.time - t0 >= window_s and history[0][0] <= st.time - 0.8 * window_s and span <= tolerance:
            return True
        act.wait_until(act.now() + 0.02)
    return False
