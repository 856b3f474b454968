"""Per joint and repeat: RMS, max and final tracking error, lag, settling time and the error at the
placement (seed 000 section 6: the servos hold ±0.29°, heavy joints fall behind the 'S' profile)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from bench.compare.signals import (
    DEFAULT_MAX_LAG_S,
    LAG_CLIP,
    LAG_SMOOTH_S,
    PlanMismatchError,
    log_samples,
    nanmedian,
    resample,
    sample_period,
    smoothed_velocity,
    velocity_lag,
)
from bench.core.log import TrialLog
from bench.core.outcome import SETTLED_WINDOW_S, settle_rows
from bench.kinematics.registry import get_robot
from bench.kinematics.transmission import servo_tolerances

MIN_HOLD_S = 0.1  #: a joint's hold must last this long to time the settling in it


MOTION_BANDS = 10.0  #: a joint whose command spans less than this many bands has no lag to measure



def robot_of_log(log: TrialLog):

    name = log.metadata.get("robot")
    if not name:
        raise PlanMismatchError("the log has no 'robot' in its metadata: not a trial log of this bench")
    return get_robot(name)


def default_band(robot) -> np.ndarray:
    """Settling band per joint (SI): the servo tolerance ±0.29° through each joint's transmission
    (:func:`bench.kinematics.transmission.servo_tolerances`: the train ±0.0145° of arc)."""
    return servo_tolerances(robot)


@dataclass(frozen=True)
class JointTracking:
    """One joint in one log (SI: rad or m, s). ``placement`` is the error where the needle is measured."""

    name: str
    kind: str
    rms: float
    max_abs: float
    final: float
    placement: float
    lag_s: float
    settling_s: float
    settle_segment: str  # the segment whose move the settling follows ("" if the joint never holds)
    band: float
    excursion: float
    hold_effort: float  # median |effort| over the placement window (N·m or N, joint side)

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in self.__dict__.items()}


def placement(log: TrialLog, segment: str = "insert",
              window: float = SETTLED_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """(measured, commanded) joint positions at the placement: medians over the last
    ``window`` s of ``segment`` (as :func:`bench.core.outcome.settled_position`, NaN-tolerant)."""
    t, seg, q_cmd, q, _ = log_samples(log)
    keep = settle_rows(t, seg, log.segment_names, segment, window)
    return nanmedian(q[keep]), nanmedian(q_cmd[keep])


def _last_hold(t: np.ndarray, c: np.ndarray) -> Optional[tuple[int, int]]:
    """The joint's last hold after a move: (first index at the held command, last index
    before the command changes again or the log ends); None if it never moves and holds
    for MIN_HOLD_S."""
    ok = np.flatnonzero(np.isfinite(c))
    if ok.size < 3:
        return None
    cf = c[ok]
    tol = 1e-12 + 1e-9 * np.maximum(1.0, np.abs(cf[1:]))
    change = np.flatnonzero(np.abs(np.diff(cf)) > tol)  # the command changes between k and k+1
    if change.size == 0:
        return None
    ends = np.append(change[1:], ok.size - 1)  # each hold runs to the next change (or the end)
    for k, stop in zip(change[::-1], ends[::-1]):
        start = k + 1
        if stop > start and t[ok[stop]] - t[ok[start]] >= MIN_HOLD_S - 1e-9:
            return int(ok[start]), int(ok[stop])
    return None


def _noise_floor(e: np.ndarray) -> float:
    """3σ of sample-to-sample noise (robust: MAD of the first differences)."""
    e = e[np.isfinite(e)]
    if e.size < 5:
        return 0.0
    d = np.diff(e)
    sigma = 1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0)
    return 3.0 * float(sigma)


def _settling(t: np.ndarray, e: np.ndarray, t_end: float, band: float) -> float:
    """Time after ``t_end`` until |e| stays within ``band`` to the end (NaN: it never does)."""
    ok = np.isfinite(e)
    t, e = t[ok], e[ok]
    if t.size == 0:
        return math.nan
    out = np.flatnonzero(np.abs(e) > band)
    if out.size == 0:
        return 0.0
    if out[-1] == t.size - 1:
        return math.nan
    return max(0.0, float(t[out[-1] + 1] - t_end))


def joint_tracking(log: TrialLog, robot=None, band: Optional[Sequence[float]] = None,
                   max_lag_s: float = DEFAULT_MAX_LAG_S,
                   placement_segment: str = "insert") -> list[JointTracking]:
    """Per-joint tracking of one log (see the module notes); ``band`` in SI per joint."""
    robot = robot or robot_of_log(log)
    names = list(log.joint_names)
    kinds = {r.name: r.kind for r in robot.chain.rows}
    t, seg, q_cmd, q, eff = log_samples(log)
    if t.size < 2:
        raise ValueError(f"the log has {t.size} sample(s): nothing to measure")
    base = default_band(robot) if band is None else np.asarray(band, dtype=float)
    if base.shape != (len(names),) or np.any(base <= 0) or not np.all(np.isfinite(base)):
        raise ValueError(f"band must be {len(names)} positive values (SI), got {band!r}")
    err = q - q_cmd
    dt = sample_period(t)
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    # For the lag only, gaps are bridged linearly: a hole left empty in both velocities
    # would be an edge at the same time in both, and correlate at zero lag.
    v_cmd = smoothed_velocity(resample(t, q_cmd, grid, math.inf), dt, LAG_SMOOTH_S)
    v_meas = smoothed_velocity(resample(t, q, grid, math.inf), dt, LAG_SMOOTH_S)
    try:
        rows = settle_rows(t, seg, log.segment_names, placement_segment)
        place_err = nanmedian(q[rows]) - nanmedian(q_cmd[rows])
        effort = nanmedian(np.abs(eff[rows]))
    except (KeyError, ValueError):
        place_err = np.full(len(names), np.nan)
        effort = np.full(len(names), np.nan)
    out = []
    for j, name in enumerate(names):
        e = err[:, j]
        fin = np.isfinite(e)
        rms = float(np.sqrt(np.mean(e[fin] ** 2))) if fin.any() else math.nan
        mx = float(np.max(np.abs(e[fin]))) if fin.any() else math.nan
        final = float(e[fin][-1]) if fin.any() else math.nan
        cj = q_cmd[:, j]
        exc = float(np.nanmax(cj) - np.nanmin(cj)) if np.isfinite(cj).any() else 0.0
        moved = exc >= MOTION_BANDS * base[j]  # too small a move has no timing to measure
        lag = math.nan
        if moved:
            # a short disturbance (a servo snapping to a new goal) must not outweigh the profile
            lim = LAG_CLIP * np.nanmax(np.abs(v_cmd[:, j]))
            lag = velocity_lag(v_cmd[:, j], np.clip(v_meas[:, j], -lim, lim), dt, max_lag_s)
        hold = _last_hold(t, cj) if moved else None
        if hold is not None:
            h = np.arange(hold[0], hold[1] + 1)
            b = max(float(base[j]), _noise_floor(e[h]))
            settle = _settling(t[h], e[h], float(t[hold[0]]), b)
            where = _segment_name(log.segment_names, seg[hold[0] - 1] if hold[0] > 0 else seg[0])
        else:
            b, settle, where = float(base[j]), math.nan, ""
        out.append(JointTracking(name, kinds.get(name, "revolute"), rms, mx, final, float(place_err[j]),
                                 lag, settle, where, b, exc, float(effort[j])))
    return out


def _segment_name(names: Sequence[str], index: int) -> str:
    return names[int(index)] if 0 <= int(index) < len(names) else ""
