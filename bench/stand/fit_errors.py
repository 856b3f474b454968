"""How far each fitted value of a test-stand fit can move, the others held, before the fit's cost
rises 5 %: a ladder of steps each way along each value (all rolled out in one batch), the
smallest step that reaches the rise, interpolated between rungs. The others held, this is a lower
bound on the error with the others free to make up for it (the rig's identification's measure);
the open-loop MAE is no quadratic bowl for a curvature to tell more. A value whose error is over
5 % of it, or that no rung of the ladder moves 5 %, the logs could not tell."""

from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["RISE", "STEPS", "stand_errors"]

#: The cost rise that defines a standard error (as the rig's identification).
RISE = 0.05
#: The ladder: steps as fractions of the value (of its range where the value is near zero).
STEPS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)


def stand_errors(cost: Callable[[np.ndarray], np.ndarray], best: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(standard error per value, whether the logs told it) around ``best``; ``cost(values)``
    gives the fit's cost of each row of ``values``."""
    k, steps = len(best), np.array(STEPS)
    unit = np.where(np.abs(best) > 0.01 * (upper - lower), np.abs(best), 0.01 * (upper - lower))
    rows = []
    for i in range(k):
        for sign in (-1.0, 1.0):
            for s in steps:
                x = best.copy()
                x[i] = np.clip(best[i] + sign * s * unit[i], lower[i], upper[i])
                rows.append(x)
    c = cost(np.vstack([best[None, :]] + rows))
    rise = (c[1:] / c[0] - 1.0).reshape(k, 2, len(steps))
    err = np.full(k, np.inf)
    for i in range(k):
        for side in rise[i]:
            hit = np.flatnonzero(side >= RISE)
            if hit.size == 0:
                continue
            j = int(hit[0])
            lo_s, lo_r = (0.0, 0.0) if j == 0 else (steps[j - 1], max(side[j - 1], 0.0))
            frac = (RISE - lo_r) / max(side[j] - lo_r, 1e-12)
            err[i] = min(err[i], (lo_s + frac * (steps[j] - lo_s)) * unit[i])
    told = np.isfinite(err) & (err <= RISE * np.abs(best))
    return err, told
