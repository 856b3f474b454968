"""Sim vs real tracking: joint metrics, log alignment and needle deviation over repeats.

Seed 000 (section 6) explains its placement errors by the joints: the servos
hold position to ±0.29°, the joints that need high torque fall behind the
'S' profile, and the 3D-printed slides have play. This module measures those
effects in trial logs, the same way for every backend:

* per joint and repeat (:func:`joint_tracking`): RMS, max and final tracking
  error (measured − commanded), the lag of the measured motion behind the
  commanded one (cross-correlation of the two velocities, refined to a
  fraction of a sample), the settling time after the joint's last move that
  is followed by a hold (until |error| stays within a band: the servo
  tolerance, widened to the sample noise), and the error at the placement
  (where the needle outcome is measured);
* between two logs (:func:`profile_difference`): the measured profiles on a
  common time base, aligned at the first commanded motion (or by
  cross-correlating the commanded velocities);
* over repeats (:func:`compare_logs`): the needle per repeat as in Table 3,
  mean / max / std of its deviations as in Table 4, a verdict against the
  acceptance limits, and each joint's share of the tip deviation (its
  placement error pushed through the FK Jacobian).

Two logs are only compared when they are of the same plan (robot, joints,
target, entry and insertion poses, segments and plan settings); otherwise
:class:`PlanMismatchError` names what differs.

Logs may come at different rates and with dropped samples (gaps in time, or
NaN rows): metrics of one log use the samples it has; anything that needs a
uniform time base resamples linearly and leaves gaps longer than ``max_gap``
empty (NaN) instead of inventing data across them.

Units: SI inside (s, rad, m); names ending in ``_mm`` / ``_deg`` carry mm and
degrees. The measured velocity used for the lag is the derivative of the
measured position, not the backend's own velocity: a servo reports a
filtered, quantised estimate and PyBullet's stiff position motors report
almost none, so only the position means the same on every backend. Both
velocities are taken over ±50 ms (symmetric: no shift) and the measured one
is clipped to twice the joint's peak commanded speed, so that quantisation
and a brief kick do not decide the peak of a correlation whose information
lies in the accelerations of the whole profile.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Literal, Optional, Sequence

import numpy as np

from bench.core.log import TrialLog
from bench.core.outcome import SETTLED_WINDOW_S, NeedleOutcome, needle_outcome
from bench.kinematics.arc_train import TABLE3_MEASURED, TABLE3_TARGET
from bench.kinematics.needle import NeedleTarget

__all__ = [
    "DEFAULT_MAX_LAG_S",
    "PINION_RADIUS",
    "SERVO_TOL_DEG",
    "TABLE3_MEASURED",
    "TABLE3_TARGET",
    "TABLE4_CURRENT_RESEARCH_MM",
    "Aligned",
    "Comparison",
    "JointContribution",
    "JointTracking",
    "PlanMismatchError",
    "ProfileDiff",
    "Side",
    "acceptance_of",
    "align_logs",
    "check_same_plan",
    "compare_logs",
    "default_band",
    "first_motion_time",
    "joint_contributions",
    "joint_tracking",
    "needle_jacobian",
    "needle_of_log",
    "placement",
    "profile_difference",
    "repeat_statistics",
    "resample",
    "table3_deviations",
    "velocity_lag",
]

SERVO_TOL_DEG = 0.29  #: seed 000 section 6: the Dynamixel servos hold position to ±0.29°
PINION_RADIUS = 0.010  #: the rig's rack-and-pinion radius (m): a slide's share of the servo tolerance
DEFAULT_MAX_LAG_S = 1.0  #: lags searched within ± this (s)
MIN_HOLD_S = 0.1  #: a joint's hold must last this long to time the settling in it
LAG_SMOOTH_S = 0.05  #: half-width of the velocity's central difference for the lag (s)
LAG_CLIP = 2.0  #: measured speeds beyond this × the joint's peak commanded speed are clipped
MOTION_BANDS = 10.0  #: a joint whose command spans less than this many bands has no lag to measure

#: Seed 000 Table 4, "current research": average deviation (mm) in X, Y, Z and depth.
TABLE4_CURRENT_RESEARCH_MM: dict[str, float] = {"x": 2.7, "y": 3.1, "z": 2.7, "insertion": 1.51}


class PlanMismatchError(ValueError):
    """Two logs that are not of the same robot and plan; the message names what differs."""


def table3_deviations() -> dict[str, np.ndarray]:
    """Table 3's five repeats minus Target 1 (mm; the angle in degrees)."""
    return {k: np.asarray(v) - TABLE3_TARGET[k] for k, v in TABLE3_MEASURED.items()}


# ---------------------------------------------------------------------------
# Samples, time bases and resampling
# ---------------------------------------------------------------------------


def _samples(log: TrialLog) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(time, segment, q_cmd, q, effort) in time order, rows without a finite time dropped."""
    t = np.asarray(log.time, dtype=float)
    keep = np.isfinite(t)
    order = np.argsort(t[keep], kind="stable")
    idx = np.flatnonzero(keep)[order]
    t = t[idx]
    # repeated time stamps carry no new information about timing: keep the first
    if t.size > 1:
        first = np.concatenate([[True], np.diff(t) > 0])
        idx, t = idx[first], t[first]
    return (t, np.asarray(log.segment)[idx], np.asarray(log.q_cmd, dtype=float)[idx],
            np.asarray(log.q, dtype=float)[idx], np.asarray(log.effort, dtype=float)[idx])


def _period(t: np.ndarray) -> float:
    """The log's sampling period: the median step (robust to dropped samples)."""
    if t.size < 2:
        raise ValueError(f"a log needs at least two samples to have a rate, it has {t.size}")
    return float(np.median(np.diff(t)))


def resample(t: np.ndarray, y: np.ndarray, grid: np.ndarray, max_gap: float) -> np.ndarray:
    """Linear interpolation of ``y`` (N,) or (N, n) onto ``grid``, per column over its finite
    samples; grid points outside the samples or inside a gap longer than ``max_gap`` are NaN."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    grid = np.asarray(grid, dtype=float)
    cols = y.reshape(len(t), -1)
    out = np.full((grid.size, cols.shape[1]), np.nan)
    for j in range(cols.shape[1]):
        ok = np.isfinite(cols[:, j])
        tf, yf = t[ok], cols[ok, j]
        if tf.size < 2:
            continue
        v = np.interp(grid, tf, yf)
        k = np.clip(np.searchsorted(tf, grid), 1, tf.size - 1)
        gap = tf[k] - tf[k - 1]
        exact = np.isin(grid, tf)
        bad = (grid < tf[0]) | (grid > tf[-1]) | ((gap > max_gap + 1e-12) & ~exact)
        v[bad] = np.nan
        out[:, j] = v
    return out.reshape((grid.size,) + y.shape[1:])


def first_motion_time(t: np.ndarray, q_cmd: np.ndarray, rtol: float = 1e-9) -> float:
    """Time of the last commanded sample before the command first changes.

    The runner commands the start pose at a segment's first sample and the
    profile leaves it at the next, so this is the instant the plan started.
    """
    q = np.asarray(q_cmd, dtype=float)
    ok = np.all(np.isfinite(q), axis=1)
    t, q = np.asarray(t)[ok], q[ok]
    if t.size < 2:
        raise ValueError("the log has fewer than two commanded samples: no motion to align on")
    tol = 1e-12 + rtol * np.maximum(1.0, np.abs(q[0]))
    moved = np.flatnonzero(np.any(np.abs(q[1:] - q[0]) > tol, axis=1))
    if moved.size == 0:
        raise ValueError("the commanded profile never moves: no first motion to align on")
    return float(t[moved[0]])


def _max_gap(dt: float) -> float:
    """The longest gap bridged by interpolation: a few periods, never under 50 ms."""
    return max(5.0 * dt, 0.05)


# ---------------------------------------------------------------------------
# Lag
# ---------------------------------------------------------------------------


def velocity_lag(v_cmd: np.ndarray, v_meas: np.ndarray, dt: float,
                 max_lag_s: float = DEFAULT_MAX_LAG_S) -> float:
    """Delay (s) of ``v_meas`` behind ``v_cmd`` (uniformly sampled, NaN = no data).

    The peak of their cross-correlation within ±``max_lag_s``, refined by a
    parabola through the peak and its neighbours. Positive: measured is late.
    NaN when either velocity is zero throughout.
    """
    a = np.asarray(v_cmd, dtype=float).copy()
    b = np.asarray(v_meas, dtype=float).copy()
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"velocities must be 1-D of equal length, got {a.shape} and {b.shape}")
    gone = ~np.isfinite(a) | ~np.isfinite(b)
    a[gone] = 0.0
    b[gone] = 0.0
    if not np.any(a) or not np.any(b):
        return math.nan
    n = a.size
    kmax = int(min(n - 1, max(1, round(max_lag_s / dt))))
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    c = np.fft.irfft(np.fft.rfft(b, nfft) * np.conj(np.fft.rfft(a, nfft)), nfft)
    lags = np.arange(-kmax, kmax + 1)
    cc = c[lags % nfft]  # cc[k] = sum_i b[i + k] a[i]
    i = int(np.argmax(cc))
    frac = 0.0
    if 0 < i < cc.size - 1:
        y0, y1, y2 = cc[i - 1], cc[i], cc[i + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0:
            frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    return float((lags[i] + frac) * dt)


def _velocity(y: np.ndarray, dt: float, half_width_s: float = 0.0) -> np.ndarray:
    """Central difference over ±``half_width_s`` (at least one sample) on a uniform grid.

    Symmetric, so it shifts nothing in time; the wider baseline averages out the
    servos' 4096-tick quantisation, which at a slow joint's speed is a few ticks
    per second and would otherwise make the velocity mostly spikes. Before its
    first and after its last finite sample a column is taken to rest where it
    was (a log starts as its first motion does: cutting the ends would cut the
    command's start but not a late measurement's, and bias the lag). NaN where
    a neighbour inside the series is missing.
    """
    y = np.asarray(y, dtype=float)
    m = max(1, int(round(half_width_s / dt)))
    cols = y.reshape(y.shape[0], -1)
    v = np.full(cols.shape, np.nan)
    for j in range(cols.shape[1]):
        c = cols[:, j]
        fin = np.flatnonzero(np.isfinite(c))
        if fin.size < 2:
            continue
        padded = np.concatenate([np.full(m, c[fin[0]]), c, np.full(m, c[fin[-1]])])
        padded[m:m + fin[0]] = c[fin[0]]
        padded[m + fin[-1] + 1:m + c.size] = c[fin[-1]]
        v[:, j] = (padded[2 * m:] - padded[:-2 * m]) / (2 * m * dt)
    return v.reshape(y.shape)


# ---------------------------------------------------------------------------
# One log: per-joint tracking
# ---------------------------------------------------------------------------


def default_band(robot) -> np.ndarray:
    """Settling band per joint (SI): the servo tolerance ±0.29°, through a 10 mm pinion for slides."""
    tol = math.radians(SERVO_TOL_DEG)
    return np.array([tol if r.kind == "revolute" else tol * PINION_RADIUS for r in robot.chain.rows])


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


def _segment_rows(seg: np.ndarray, segment_names: Sequence[str], name: str) -> np.ndarray:
    try:
        si = list(segment_names).index(name)
    except ValueError:
        raise KeyError(f"no segment {name!r} in the log; it has {list(segment_names)}") from None
    return np.flatnonzero(seg == si)


def placement(log: TrialLog, segment: str = "insert",
              window: float = SETTLED_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """(measured, commanded) joint positions at the placement: medians over the last
    ``window`` s of ``segment`` (as :func:`bench.core.outcome.settled_position`, NaN-tolerant)."""
    t, seg, q_cmd, q, _ = _samples(log)
    keep = _placement_rows(t, seg, log.segment_names, segment, window)
    return _nanmedian(q[keep]), _nanmedian(q_cmd[keep])


def _placement_rows(t: np.ndarray, seg: np.ndarray, segment_names: Sequence[str], segment: str,
                    window: float = SETTLED_WINDOW_S) -> np.ndarray:
    idx = _segment_rows(seg, segment_names, segment)
    if idx.size == 0:
        raise ValueError(f"segment {segment!r} has no samples (the trial stopped before it)")
    return idx[t[idx] >= t[idx[-1]] - window]


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
    robot = robot or _robot_of(log)
    names = list(log.joint_names)
    kinds = {r.name: r.kind for r in robot.chain.rows}
    t, seg, q_cmd, q, eff = _samples(log)
    if t.size < 2:
        raise ValueError(f"the log has {t.size} sample(s): nothing to measure")
    base = default_band(robot) if band is None else np.asarray(band, dtype=float)
    if base.shape != (len(names),) or np.any(base <= 0) or not np.all(np.isfinite(base)):
        raise ValueError(f"band must be {len(names)} positive values (SI), got {band!r}")
    err = q - q_cmd
    dt = _period(t)
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    # For the lag only, gaps are bridged linearly: a hole left empty in both velocities
    # would be an edge at the same time in both, and correlate at zero lag.
    v_cmd = _velocity(resample(t, q_cmd, grid, math.inf), dt, LAG_SMOOTH_S)
    v_meas = _velocity(resample(t, q, grid, math.inf), dt, LAG_SMOOTH_S)
    try:
        rows = _placement_rows(t, seg, log.segment_names, placement_segment)
        place_err = _nanmedian(q[rows]) - _nanmedian(q_cmd[rows])
        effort = _nanmedian(np.abs(eff[rows]))
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


def _nanmedian(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """Median ignoring NaN; all-NaN columns give NaN without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(a, axis=axis)


def _nanmean(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """Mean ignoring NaN; all-NaN columns give NaN without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(a, axis=axis)


# ---------------------------------------------------------------------------
# Same plan?
# ---------------------------------------------------------------------------

_PLAN_FIELDS = ("trajectory", "velocity_scale", "acceleration_scale", "jerk_scale", "settle_s", "retract")


def _fmt(v: object) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.6g}"
    return repr(v) if isinstance(v, str) else str(v)


def _required(log: TrialLog, label: str, key: str) -> object:
    if key not in log.metadata:
        raise PlanMismatchError(f"{label} has no {key!r} in its metadata: not a trial log of this bench")
    return log.metadata[key]


def _close(a: object, b: object, tol: float = 1e-9) -> bool:
    try:
        x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    except (TypeError, ValueError):
        return a == b
    return x.shape == y.shape and bool(np.all(np.abs(x - y) <= tol))


def check_same_plan(a: TrialLog, b: TrialLog, labels: tuple[str, str] = ("A", "B")) -> None:
    """Raise :class:`PlanMismatchError` naming every difference in robot, joints, target,
    entry/insertion poses, segments or plan settings (the control rate may differ)."""
    la, lb = labels
    diffs: list[str] = []
    ra, rb = _required(a, la, "robot"), _required(b, lb, "robot")
    if ra != rb:
        diffs.append(f"robot ({la}: {ra}, {lb}: {rb})")
    if list(a.joint_names) != list(b.joint_names):
        diffs.append(f"joint names ({la}: {_fmt(list(a.joint_names))}, {lb}: {_fmt(list(b.joint_names))})")
    if list(a.segment_names) != list(b.segment_names):
        diffs.append(f"segments ({la}: {_fmt(list(a.segment_names))}, {lb}: {_fmt(list(b.segment_names))})")
    ta, tb = _required(a, la, "target"), _required(b, lb, "target")
    for k in sorted(set(ta) | set(tb)):
        if not _close(ta.get(k), tb.get(k)):
            diffs.append(f"target.{k} ({la}: {_fmt(ta.get(k))}, {lb}: {_fmt(tb.get(k))})")
    for k in ("q_entry", "q_insert"):
        va, vb = _required(a, la, k), _required(b, lb, k)
        if not _close(va, vb):
            diffs.append(f"{k} ({la}: {_fmt(va)}, {lb}: {_fmt(vb)})")
    pa = (a.metadata.get("config") or {}).get("plan")
    pb = (b.metadata.get("config") or {}).get("plan")
    if pa is not None and pb is not None:
        for k in _PLAN_FIELDS:
            if not _close(pa.get(k), pb.get(k)):
                diffs.append(f"plan.{k} ({la}: {_fmt(pa.get(k))}, {lb}: {_fmt(pb.get(k))})")
    if diffs:
        raise PlanMismatchError(f"{la} and {lb} are not the same robot and plan: " + "; ".join(diffs))


# ---------------------------------------------------------------------------
# Two logs: alignment and the difference of their measured profiles
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Aligned:
    """Two logs on one uniform time base (t = 0 at the aligned start of motion)."""

    time: np.ndarray
    a_q: np.ndarray
    b_q: np.ndarray
    a_cmd: np.ndarray
    b_cmd: np.ndarray
    b_segment: np.ndarray  # B's segment index at each grid time (-1 outside B)
    offset_s: float  # B's zero minus A's zero, in their own clocks
    dt: float


def _zero_by_xcorr(a: TrialLog, b: TrialLog, dt: float, max_lag_s: float) -> tuple[float, float]:
    """Each log's zero such that their commanded velocities line up best."""
    ta, _, ca, _, _ = _samples(a)
    tb, _, cb, _, _ = _samples(b)
    n = int(max(ta[-1] - ta[0], tb[-1] - tb[0]) / dt) + 1
    ga, gb = ta[0] + np.arange(n) * dt, tb[0] + np.arange(n) * dt
    va = np.nan_to_num(_velocity(resample(ta, ca, ga, math.inf), dt, LAG_SMOOTH_S))
    vb = np.nan_to_num(_velocity(resample(tb, cb, gb, math.inf), dt, LAG_SMOOTH_S))
    scale = np.sqrt(np.sum(va ** 2, axis=0) * np.sum(vb ** 2, axis=0))
    use = scale > 0
    if not np.any(use):
        raise ValueError("neither log's command moves: nothing to cross-correlate")
    # one correlation over all joints: each joint weighted by its energy so none dominates
    wa = (va[:, use] / np.sqrt(np.sum(va[:, use] ** 2, axis=0))).ravel(order="F")
    wb = (vb[:, use] / np.sqrt(np.sum(vb[:, use] ** 2, axis=0))).ravel(order="F")
    lag = velocity_lag(wa, wb, dt, max_lag_s)
    return float(ta[0]), float(tb[0] + lag)


def align_logs(a: TrialLog, b: TrialLog, method: Literal["motion", "xcorr"] = "motion",
               dt: Optional[float] = None, max_lag_s: float = 2.0) -> Aligned:
    """Both logs resampled onto one time base over the time they share.

    ``motion``: t = 0 at each log's first commanded motion; ``xcorr``: B shifted to
    where its commanded velocities best match A's. The step is the coarser of the
    two rates unless given.
    """
    ta, _, ca, qa, _ = _samples(a)
    tb, sb, cb, qb, _ = _samples(b)
    da, db = _period(ta), _period(tb)
    step = float(dt) if dt is not None else max(da, db)
    if not step > 0:
        raise ValueError(f"the common time step must be positive, got {dt}")
    if method == "motion":
        za, zb = first_motion_time(ta, ca), first_motion_time(tb, cb)
    elif method == "xcorr":
        za, zb = _zero_by_xcorr(a, b, min(da, db), max_lag_s)
    else:
        raise ValueError(f"alignment must be 'motion' or 'xcorr', got {method!r}")
    lo = max(ta[0] - za, tb[0] - zb)
    hi = min(ta[-1] - za, tb[-1] - zb)
    if hi <= lo:
        raise ValueError("the two logs do not overlap in time once aligned")
    k0 = math.ceil(lo / step - 1e-9)
    grid = np.arange(k0, math.floor(hi / step + 1e-9) + 1) * step
    ga, gb = grid + za, grid + zb
    seg_idx = np.clip(np.searchsorted(tb, gb, side="right") - 1, 0, tb.size - 1)
    return Aligned(grid, resample(ta, qa, ga, _max_gap(da)), resample(tb, qb, gb, _max_gap(db)),
                   resample(ta, ca, ga, _max_gap(da)), resample(tb, cb, gb, _max_gap(db)),
                   np.asarray(sb)[seg_idx].astype(int), zb - za, step)


@dataclass(frozen=True)
class ProfileDiff:
    """B's measured profile minus A's for one joint (SI), over the shared time."""

    name: str
    rms: float
    max_abs: float
    rms_by_segment: dict[str, float]
    cmd_rms: float  # the same for the commanded profiles: how much the plans themselves differ

    def as_dict(self) -> dict:
        clean = lambda v: None if not math.isfinite(v) else v  # noqa: E731
        return {"name": self.name, "rms": clean(self.rms), "max_abs": clean(self.max_abs),
                "rms_by_segment": {k: clean(v) for k, v in self.rms_by_segment.items()},
                "cmd_rms": clean(self.cmd_rms)}


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan


def profile_difference(a: TrialLog, b: TrialLog, method: Literal["motion", "xcorr"] = "motion",
                       dt: Optional[float] = None, labels: tuple[str, str] = ("A", "B"),
                       check: bool = True) -> tuple[list[ProfileDiff], Aligned]:
    """Per joint: RMS and max of B's measured profile minus A's, after :func:`align_logs`."""
    if check:
        check_same_plan(a, b, labels)
    al = align_logs(a, b, method, dt)
    d = al.b_q - al.a_q
    dc = al.b_cmd - al.a_cmd
    out = []
    for j, name in enumerate(a.joint_names):
        col = d[:, j]
        by_seg = {s: _rms(col[al.b_segment == i]) for i, s in enumerate(b.segment_names)}
        fin = col[np.isfinite(col)]
        out.append(ProfileDiff(name, _rms(col), float(np.max(np.abs(fin))) if fin.size else math.nan,
                               by_seg, _rms(dc[:, j])))
    return out, al


# ---------------------------------------------------------------------------
# The needle: per repeat, over repeats, and which joints explain it
# ---------------------------------------------------------------------------


def _robot_of(log: TrialLog):
    from bench.kinematics.registry import get_robot

    name = log.metadata.get("robot")
    if not name:
        raise PlanMismatchError("the log has no 'robot' in its metadata: not a trial log of this bench")
    return get_robot(name)


def _target_of(log: TrialLog) -> NeedleTarget:
    t = log.metadata.get("target")
    if not t:
        raise PlanMismatchError("the log has no 'target' in its metadata: not a trial log of this bench")
    return NeedleTarget(np.asarray(t["entry_m"], dtype=float), float(t["depth_m"]),
                        float(t["angle_rad"]), float(t.get("tilt_rad", 0.0)))


def acceptance_of(log: TrialLog) -> tuple[float, float]:
    """(position mm, angle deg) from the log's config, else seed 000's 5 mm and 1°."""
    acc = (log.metadata.get("config") or {}).get("acceptance") or {}
    return float(acc.get("position_mm", 5.0)), float(acc.get("angle_deg", 1.0))


def needle_of_log(log: TrialLog, robot=None, acceptance: Optional[tuple[float, float]] = None,
                  segment: str = "insert") -> Optional[NeedleOutcome]:
    """The achieved needle at the placement, against the log's target (None: never placed)."""
    robot = robot or _robot_of(log)
    try:
        q, _ = placement(log, segment)
    except (KeyError, ValueError):
        return None
    if not np.all(np.isfinite(q)):
        return None
    pos, ang = acceptance or acceptance_of(log)
    return needle_outcome(robot, q, _target_of(log), pos, ang)


def needle_jacobian(robot, q: np.ndarray, step: float = 1e-6) -> dict[str, np.ndarray]:
    """Central-difference Jacobians at ``q``: tip and entry (3, n) in m per unit joint,
    insertion angle (n,) in rad and depth (n,) in m."""
    q = np.asarray(q, dtype=float)
    n = q.size
    tip = np.empty((3, n))
    entry = np.empty((3, n))
    angle = np.empty(n)
    depth = np.empty(n)
    for j in range(n):
        h = np.zeros(n)
        h[j] = step
        p, m = robot.needle(q + h), robot.needle(q - h)
        tip[:, j] = (p.tip - m.tip) / (2 * step)
        entry[:, j] = (p.entry - m.entry) / (2 * step)
        da = (p.angle - m.angle + math.pi) % (2 * math.pi) - math.pi
        angle[j] = da / (2 * step)
        depth[j] = (p.depth - m.depth) / (2 * step)
    return {"tip": tip, "entry": entry, "angle": angle, "depth": depth}


@dataclass(frozen=True)
class JointContribution:
    """One joint's placement error pushed through the FK Jacobian (mm, degrees)."""

    name: str
    error: float  # SI
    tip_mm: tuple[float, float, float]
    tip_norm_mm: float
    angle_deg: float
    depth_mm: float

    def as_dict(self) -> dict:
        return {"name": self.name, "error": self.error, "tip_mm": list(self.tip_mm),
                "tip_norm_mm": self.tip_norm_mm, "angle_deg": self.angle_deg, "depth_mm": self.depth_mm}


def joint_contributions(robot, q_commanded: np.ndarray, error: np.ndarray) -> list[JointContribution]:
    """Each joint's share of the needle deviation to first order: J[:, j]·e_j at the commanded pose."""
    J = needle_jacobian(robot, q_commanded)
    e = np.nan_to_num(np.asarray(error, dtype=float))
    out = []
    for j, name in enumerate(robot.joint_names):
        tip = J["tip"][:, j] * e[j] * 1e3
        out.append(JointContribution(name, float(e[j]), tuple(float(x) for x in tip),
                                     float(np.linalg.norm(tip)), float(np.degrees(J["angle"][j] * e[j])),
                                     float(J["depth"][j] * e[j] * 1e3)))
    return out


def _stats(x: np.ndarray) -> dict[str, object]:
    """mean (signed), mean |·|, max |·| and std (n − 1) over repeats, per column."""
    x = np.asarray(x, dtype=float)
    if x.shape[0] == 0:
        nan = np.full(x.shape[1:], np.nan)
        return {"mean": nan, "mean_abs": nan, "max_abs": nan, "std": nan}
    std = x.std(axis=0, ddof=1) if x.shape[0] > 1 else np.zeros(x.shape[1:])
    return {"mean": x.mean(axis=0), "mean_abs": np.abs(x).mean(axis=0),
            "max_abs": np.abs(x).max(axis=0), "std": std}


def repeat_statistics(outcomes: Sequence[NeedleOutcome]) -> dict[str, dict[str, np.ndarray]]:
    """Deviations over repeats: entry (Table 3's X, Y, Z), tip, depth and angle."""
    o = list(outcomes)
    return {"entry_mm": _stats(np.array([x.entry_deviation_mm for x in o]).reshape(len(o), 3)),
            "tip_mm": _stats(np.array([x.tip_deviation_mm for x in o]).reshape(len(o), 3)),
            "depth_mm": _stats(np.array([x.depth_deviation_mm for x in o])),
            "angle_deg": _stats(np.array([x.angle_deviation_deg for x in o]))}


# ---------------------------------------------------------------------------
# Repeats on two backends
# ---------------------------------------------------------------------------


@dataclass
class Side:
    """The repeats of one backend: logs, tracking, needle outcomes and joint contributions."""

    label: str
    backend: str
    logs: list[TrialLog]
    sources: list[str]
    tracking: list[list[JointTracking]]
    outcomes: list[Optional[NeedleOutcome]]
    completed: list[bool]
    reasons: list[str]
    contributions: list[Optional[list[JointContribution]]]
    stats: dict = field(default_factory=dict)

    @property
    def placed(self) -> list[NeedleOutcome]:
        return [o for o in self.outcomes if o is not None]

    @property
    def passed(self) -> bool:
        """Every repeat completed and placed the needle within the limits."""
        return bool(self.logs) and all(self.completed) and all(o is not None and o.passed
                                                               for o in self.outcomes)

    def mean_tracking(self, attr: str) -> np.ndarray:
        """Mean over repeats of one :class:`JointTracking` field, per joint (NaN-aware)."""
        a = np.array([[getattr(jt, attr) for jt in rep] for rep in self.tracking], dtype=float)
        return _nanmean(a)

    def contribution_ranking(self) -> list[tuple[str, float]]:
        """Joints by mean |tip contribution| (mm) over the placed repeats, largest first."""
        reps = [c for c in self.contributions if c is not None]
        if not reps:
            return []
        names = [c.name for c in reps[0]]
        mean = np.mean([[c.tip_norm_mm for c in rep] for rep in reps], axis=0)
        order = np.argsort(-mean, kind="stable")
        return [(names[i], float(mean[i])) for i in order]


def _status(log: TrialLog) -> tuple[bool, str]:
    """(completed, why it stopped early), as the trial record reads them."""
    from bench.core.result import status_from_log

    return status_from_log(log)


def _side(label: str, logs: Sequence[TrialLog], sources: Sequence[str], robot,
          acceptance: Optional[tuple[float, float]], band, max_lag_s: float) -> Side:
    tracking, outcomes, completed, reasons, contribs = [], [], [], [], []
    for log in logs:
        tracking.append(joint_tracking(log, robot, band, max_lag_s))
        o = needle_of_log(log, robot, acceptance)
        outcomes.append(o)
        done, why = _status(log)
        completed.append(done)
        reasons.append(why)
        if o is not None:
            qm, qc = placement(log)
            contribs.append(joint_contributions(robot, qc, qm - qc))
        else:
            contribs.append(None)
    backend = str(logs[0].metadata.get("backend", "?")) if logs else "?"
    side = Side(label, backend, list(logs), list(sources), tracking, outcomes, completed, reasons,
                contribs)
    side.stats = repeat_statistics(side.placed)
    return side


@dataclass
class Comparison:
    """Everything the report shows: both sides, their profile differences and the verdict."""

    reference: Side
    subject: Side
    profile: list[list[ProfileDiff]]  # per pair of repeats (subject i vs reference i)
    robot: object
    acceptance: tuple[float, float]
    align: str

    @property
    def joint_names(self) -> list[str]:
        return list(self.robot.joint_names)

    @property
    def passed(self) -> bool:
        return self.subject.passed

    @property
    def worst_joint(self) -> Optional[str]:
        r = self.subject.contribution_ranking()
        return r[0][0] if r else None

    def profile_mean(self, attr: str = "rms") -> np.ndarray:
        """Mean over pairs of a :class:`ProfileDiff` field, per joint."""
        if not self.profile:
            return np.full(len(self.joint_names), np.nan)
        return _nanmean(np.array([[getattr(p, attr) for p in pair] for pair in self.profile],
                                 dtype=float))

    def summary(self) -> dict:
        """The one-line JSON of ``hilbench compare --json``, over the subject's placed repeats:
        ``mean`` signed, ``max`` the largest |deviation|, ``std`` the sample standard deviation
        (mm; the angle in degrees; null when no repeat placed the needle)."""
        s = self.subject.stats
        one = lambda v: None if not np.isfinite(v) else round(float(v), 6) + 0.0  # noqa: E731
        r = lambda v: [one(x) for x in np.atleast_1d(v)]  # noqa: E731

        def block(k: str, vector: bool) -> dict:
            if vector:
                return {"mean": r(s[k]["mean"]), "max": r(s[k]["max_abs"]), "std": r(s[k]["std"])}
            return {"mean": one(s[k]["mean"]), "max": one(s[k]["max_abs"]), "std": one(s[k]["std"])}

        sub = self.subject
        return {"repeats": len(sub.logs), "tip_deviation_mm": block("tip_mm", True),
                "depth_deviation_mm": block("depth_mm", False),
                "angle_deviation_deg": block("angle_deg", False), "passed": self.passed,
                "completed": sum(bool(c) for c in sub.completed), "reason": self.why_not(),
                "worst_joint": self.worst_joint}

    def why_not(self) -> str:
        """Why the subject did not pass, in one line ("" when it did): the first repeat that
        stopped early, else the repeats placed outside the acceptance limits."""
        sub = self.subject
        if self.passed:
            return ""
        if not sub.logs:
            return f"no {sub.label} repeat to compare"
        for i, (done, why) in enumerate(zip(sub.completed, sub.reasons)):
            if not done:
                return f"{sub.label} repeat {i + 1} stopped early: {why}"
        pos, ang = self.acceptance
        out = [i + 1 for i, o in enumerate(sub.outcomes) if o is None or not o.passed]
        return (f"{sub.label} repeat(s) {', '.join(map(str, out))} of {len(sub.logs)} placed the "
                f"needle outside {pos:g} mm / {ang:g}°")

    def as_dict(self) -> dict:
        """A full machine-readable record (SI per joint, mm and degrees for the needle)."""

        def side(sd: Side) -> dict:
            return {"label": sd.label, "backend": sd.backend, "sources": sd.sources,
                    "completed": sd.completed, "reasons": sd.reasons, "passed": sd.passed,
                    "outcomes": [o.as_dict() if o else None for o in sd.outcomes],
                    "tracking": [[jt.as_dict() for jt in rep] for rep in sd.tracking],
                    "mean_tracking": {a: _clean_list(sd.mean_tracking(a))
                                      for a in ("rms", "max_abs", "final", "placement", "lag_s",
                                                "settling_s", "hold_effort")},
                    "contributions": [[c.as_dict() for c in rep] if rep else None
                                      for rep in sd.contributions],
                    "ranking": [{"joint": n, "tip_mm": v} for n, v in sd.contribution_ranking()],
                    "stats": {k: {m: _clean_list(np.atleast_1d(v)) for m, v in d.items()}
                              for k, d in sd.stats.items()}}

        return {"robot": getattr(self.robot, "name", "?"), "joints": self.joint_names,
                "kinds": [r.kind for r in self.robot.chain.rows],
                "acceptance": {"position_mm": self.acceptance[0], "angle_deg": self.acceptance[1]},
                "align": self.align, "reference": side(self.reference), "subject": side(self.subject),
                "profile": [[p.as_dict() for p in pair] for pair in self.profile],
                "profile_mean": {"rms": _clean_list(self.profile_mean("rms")),
                                 "max_abs": _clean_list(self.profile_mean("max_abs")),
                                 "cmd_rms": _clean_list(self.profile_mean("cmd_rms"))},
                "summary": self.summary()}


def _clean_list(v: np.ndarray) -> list:
    return [None if not np.isfinite(x) else float(x) for x in np.atleast_1d(np.asarray(v, dtype=float))]


def compare_logs(reference: Sequence[TrialLog], subject: Sequence[TrialLog],
                 labels: tuple[str, str] = ("sim", "real"),
                 sources: Optional[tuple[Sequence[str], Sequence[str]]] = None,
                 acceptance: Optional[tuple[float, float]] = None,
                 band: Optional[Sequence[float]] = None, align: Literal["motion", "xcorr"] = "motion",
                 max_lag_s: float = DEFAULT_MAX_LAG_S) -> Comparison:
    """Compare the repeats of two backends (each a non-empty list of logs of one plan).

    Every log is checked against the first reference log (:func:`check_same_plan`);
    ``acceptance`` (mm, degrees) defaults to the first subject log's config.
    """
    reference, subject = list(reference), list(subject)
    if not reference or not subject:
        raise ValueError(f"need at least one log on each side, got {len(reference)} {labels[0]} "
                         f"and {len(subject)} {labels[1]}")
    src = sources or ([f"{labels[0]} {i + 1}" for i in range(len(reference))],
                      [f"{labels[1]} {i + 1}" for i in range(len(subject))])
    first = reference[0]
    for lab, log in list(zip(src[0], reference))[1:] + list(zip(src[1], subject)):
        check_same_plan(first, log, (src[0][0], lab))
    robot = _robot_of(first)
    acc = acceptance or acceptance_of(subject[0])
    ref = _side(labels[0], reference, src[0], robot, acc, band, max_lag_s)
    sub = _side(labels[1], subject, src[1], robot, acc, band, max_lag_s)
    pairs = []
    for i, log in enumerate(subject):
        other = reference[min(i, len(reference) - 1)]
        try:
            diffs, _ = profile_difference(other, log, align, check=False)
        except ValueError:  # a repeat that never moved: nothing to set side by side
            continue
        pairs.append(diffs)
    return Comparison(ref, sub, pairs, robot, acc, align)
