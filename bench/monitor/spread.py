"""The spread a servo model leaves: its twin run over clean logs of the rig, and per joint the σ its
detector needs there.

``hilbench identify`` writes it into the model file (``twin_sigma``, and the current's
``twin_sigma_current``): the monitor then divides each
joint's residual by what that model, on that rig, leaves on clean logs, not by a datasheet default.
A residual is not Gaussian: a worn joint's stick-slip leaves bursts of several encoder ticks
between stretches of quantisation noise, so its standard deviation says little of what the detector
will meet. The σ written is the detector's own calibration: the smallest with which the CUSUM, run
over the clean logs, rises to at most :data:`CLEAN_SHARE` of its threshold on every joint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from bench.monitor.detector import Cusum, CusumParams, DEFAULT_CUSUM
from bench.monitor.twin import ServoTwin, TwinSetup

__all__ = ["CLEAN_SHARE", "TwinResiduals", "calibrated_sigma", "twin_residuals", "twin_spread"]

#: The share of the alarm threshold the detector may reach on the clean logs a σ is calibrated on:
#: the other half is the margin for a trial's motion, which the excitation never covers whole.
CLEAN_SHARE = 0.5


@dataclass(frozen=True)
class TwinResiduals:
    """The twin's residuals over clean logs, rows of joints at the readings it predicted (the rows
    its detector meets), the logs one after another: position (joint units) and its timing spread
    (0 where the loop was on time), current (A; NaN where a log has none) and its spread (the
    twin's ``current_spread``)."""

    position: np.ndarray
    timing: np.ndarray
    current: np.ndarray
    current_spread: np.ndarray


def twin_residuals(setup: TwinSetup, logs: Iterable[tuple[np.ndarray, ...]]) -> TwinResiduals:
    """The twin run over ``logs`` (each: time, the goals sent, the measured positions and speeds,
    and the motor currents in A or None, rows per control cycle), as the monitor runs it."""
    twin = ServoTwin(setup)
    n = len(setup.joint_names)
    position, timing, current, current_spread = [], [], [], []
    try:
        for time, goal, q, qd, amps in logs:
            if amps is None:
                amps = np.full(q.shape, np.nan)
            if len(time) < 2:
                continue
            twin.start(q[0], qd[0], float(np.median(np.diff(time))))
            for k in range(len(time) - 1):
                r = twin.advance(goal[k], q[k + 1], qd[k + 1], time[k + 1] - time[k])
                if r is not None:
                    position.append(r)
                    timing.append(0.0 * r if twin.timing is None else twin.timing)
                    current.append(twin.current_residual(amps[k + 1]))
                    current_spread.append(twin.current_spread)
    finally:
        twin.close()
    rows = [np.array(a).reshape(-1, n) for a in (position, timing, current, current_spread)]
    return TwinResiduals(*rows)


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


def twin_spread(setup: TwinSetup, logs: Iterable[tuple[np.ndarray, ...]], floor: np.ndarray,
                current_floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per joint the σ the monitor divides by, calibrated on clean ``logs`` (:func:`calibrated_sigma`):
    of the position (joint units) and of the current (A; the floor where the logs hold none)."""
    r = twin_residuals(setup, logs)
    if not len(r.position):
        return np.asarray(floor, dtype=float), np.asarray(current_floor, dtype=float)
    sigma = calibrated_sigma(r.position, floor, timing=r.timing)
    told = ~np.isnan(r.current).all(axis=1)
    current = (calibrated_sigma(np.nan_to_num(r.current[told]), current_floor, timing=r.current_spread[told])
               if told.any() else np.asarray(current_floor, dtype=float))
    return sigma, current
