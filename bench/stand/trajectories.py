"""BAM's four test-stand trajectories (``bam/trajectory.py``, Rhoban, Apache-2.0): the goal
(rad) and torque enable at time t, 6 s each — the excitation of a stand recording."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from bench.stand.errors import StandError

__all__ = ["DURATION_S", "TRAJECTORIES", "trajectory"]

DURATION_S = 6.0


def _cubic(keyframes: list[tuple[float, float, float]], t: float) -> float:
    """Cubic Hermite through (t, x, x') keyframes; held outside them."""
    if t <= keyframes[0][0]:
        return keyframes[0][1]
    if t >= keyframes[-1][0]:
        return keyframes[-1][1]
    for (t0, x0, v0), (t1, x1, v1) in zip(keyframes, keyframes[1:]):
        if t0 <= t <= t1:
            A = np.array([[1, t0, t0 ** 2, t0 ** 3], [0, 1, 2 * t0, 3 * t0 ** 2],
                          [1, t1, t1 ** 2, t1 ** 3], [0, 1, 2 * t1, 3 * t1 ** 2]], dtype=float)
            w = np.linalg.solve(A, [x0, v0, x1, v1])
            return float(w[0] + w[1] * t + w[2] * t ** 2 + w[3] * t ** 3)
    return keyframes[-1][1]


def _lift_and_drop(t: float) -> tuple[float, bool]:
    # up to −π/2 in 2 s, then torque off: the mass falls and swings freely
    return _cubic([(0.0, 0.0, 0.0), (2.0, -math.pi / 2, 0.0)], t), t < 2.0


def _sin_time_square(t: float) -> tuple[float, bool]:
    return math.sin(t * t), True


def _up_and_down(t: float) -> tuple[float, bool]:
    return _cubic([(0.0, 0.0, 0.0), (3.0, math.pi / 2, 0.0), (6.0, 0.8 * math.pi / 2, 0.0)], t), True


def _sin_sin(t: float) -> tuple[float, bool]:
    return math.sin(t) * math.pi / 2 + math.sin(5.0 * t) * 0.5 * math.sin(2.0 * t), True


TRAJECTORIES: dict[str, Callable[[float], tuple[float, bool]]] = {
    "sin_sin": _sin_sin, "lift_and_drop": _lift_and_drop, "up_and_down": _up_and_down,
    "sin_time_square": _sin_time_square,
}


def trajectory(name: str) -> Callable[[float], tuple[float, bool]]:
    """The trajectory ``name``; StandError naming the known ones otherwise."""
    try:
        return TRAJECTORIES[name]
    except KeyError:
        raise StandError(f"unknown trajectory {name!r}; known: {', '.join(TRAJECTORIES)}") from None
