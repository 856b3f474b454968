"""The spread a servo model leaves: its twin run over clean logs of the rig, and per joint the σ its
detector needs there.

``hilbench identify`` writes it into the model file (``twin_sigma``): the monitor then divides each
joint's residual by what that model, on that rig, leaves on clean logs, not by a datasheet default.
A residual is not Gaussian: a worn joint's stick-slip leaves bursts of several encoder ticks
between stretches of quantisation noise, so its standard deviation says little of what the detector
will meet. The σ written is the detector's own calibration: the smallest with which the CUSUM, run
over the clean logs, rises to at most :data:`CLEAN_SHARE` of its threshold on every joint.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from bench.monitor.detector import Cusum, CusumParams, DEFAULT_CUSUM
from bench.monitor.twin import ServoTwin, TwinSetup

__all__ = ["CLEAN_SHARE", "calibrated_sigma", "twin_residuals", "twin_spread"]

#: The share of the alarm threshold the detector may reach on the clean logs a σ is calibrated on:
#: the other half is the margin for a trial's motion, which the excitation never covers whole.
CLEAN_SHARE = 0.5


def twin_residuals(setup: TwinSetup, logs: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The twin's residual over ``logs`` (each: time, the goals sent, the measured positions and
    speeds, rows per control cycle), rows of joints, joint units, at the readings it predicted (the
    rows its detector meets), and beside it the twin's timing spread (0 where the loop was on time,
    its period each log's median interval); the logs one after another."""
    twin = ServoTwin(setup)
    residuals, timing = [], []
    try:
        for time, goal, q, qd in logs:
            if len(time) < 2:
                continue
            twin.start(q[0], qd[0], float(np.median(np.diff(time))))
            for k in range(len(time) - 1):
                r = twin.advance(goal[k], q[k + 1], qd[k + 1], time[k + 1] - time[k])
                if r is not None:
                    residuals.append(r)
                    timing.append(0.0 * r if twin.timing is None else twin.timing)
    finally:
        twin.close()
    n = len(setup.joint_names)
    return np.array(residuals).reshape(-1, n), np.array(timing).reshape(-1, n)


def _peak(residuals: np.ndarray, sigma: np.ndarray, params: CusumParams,
          timing: np.ndarray | None = None) -> np.ndarray:
    scale = sigma if timing is None else np.sqrt(sigma ** 2 + timing ** 2)
    return Cusum(residuals.shape[1], params).sums(residuals / scale).max(axis=0, initial=0.0)


def calibrated_sigma(residuals: np.ndarray, floor: np.ndarray, params: CusumParams = DEFAULT_CUSUM,
                     share: float = CLEAN_SHARE, timing: np.ndarray | None = None) -> np.ndarray:
    """Per joint the smallest σ (≥ ``floor``) with which the detector over ``residuals`` (with the
    twin's ``timing`` spread beside σ, as the monitor adds it) stays at or under ``share`` of its
    threshold: bisection, the peak falling as σ grows."""
    lo = np.asarray(floor, dtype=float).copy()
    hi = np.maximum(lo, np.abs(residuals).max(axis=0, initial=0.0))  # z ≤ 1 < κ: the sums never rise
    ok = _peak(residuals, lo, params, timing) <= share * params.threshold
    for _ in range(24):
        mid = np.where(ok, lo, 0.5 * (lo + hi))
        fine = _peak(residuals, mid, params, timing) <= share * params.threshold
        hi = np.where(fine & ~ok, mid, hi)
        lo = np.where(~fine & ~ok, mid, lo)
    return np.where(ok, lo, hi)


def twin_spread(setup: TwinSetup, logs: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                floor: np.ndarray) -> np.ndarray:
    """Per joint the σ the monitor divides by, calibrated on clean ``logs`` (:func:`calibrated_sigma`)."""
    residuals, timing = twin_residuals(setup, logs)
    if not len(residuals):
        return np.asarray(floor, dtype=float)
    return calibrated_sigma(residuals, floor, timing=timing)
