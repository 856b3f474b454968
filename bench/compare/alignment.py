"""Two logs side by side: only of the same plan, on a common time base from their first commanded
motion (or cross-correlated commanded velocities), and the difference of their measured profiles."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

import numpy as np

from bench.compare.signals import (
    LAG_SMOOTH_S,
    PlanMismatchError,
    first_motion_time,
    log_samples,
    max_gap_for,
    resample,
    sample_period,
    smoothed_velocity,
    velocity_lag,
)
from bench.core.log import TrialLog
from bench.core.rundir import RECORD, RunDirError, load_run, read_log_file

def load_saved_trial(path: Path) -> TrialLog:
    """The log of a saved trial (``compare RUN_A RUN_B``), every file checked (bench.core.rundir):
    a run directory, or a log file (checked against its run directory's record when it has one;
    a log with no record, as a bare ``trial.npz``, has its contents checked alone).
    :class:`RunDirError` names the run and what is wrong with it."""
    path = Path(path)
    if path.is_dir():
        if (path / RECORD).exists() or (path / RECORD).is_symlink():
            return load_run(path).log
        return read_log_file(path / "trial.npz", path)  # a bare log: its contents checked alone
    parent = path.parent
    if (parent / RECORD).is_file():
        saved = load_run(parent)
        if saved.log_path.name != path.name:
            raise RunDirError(f"{path}: not the log {parent / RECORD} names ({saved.record.log})")
        return saved.log
    return read_log_file(path, path)


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
    ta, _, ca, _, _ = log_samples(a)
    tb, _, cb, _, _ = log_samples(b)
    n = int(max(ta[-1] - ta[0], tb[-1] - tb[0]) / dt) + 1
    ga, gb = ta[0] + np.arange(n) * dt, tb[0] + np.arange(n) * dt
    va = np.nan_to_num(smoothed_velocity(resample(ta, ca, ga, math.inf), dt, LAG_SMOOTH_S))
    vb = np.nan_to_num(smoothed_velocity(resample(tb, cb, gb, math.inf), dt, LAG_SMOOTH_S))
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
    ta, _, ca, qa, _ = log_samples(a)
    tb, sb, cb, qb, _ = log_samples(b)
    da, db = sample_period(ta), sample_period(tb)
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
    return Aligned(grid, resample(ta, qa, ga, max_gap_for(da)), resample(tb, qb, gb, max_gap_for(db)),
                   resample(ta, ca, ga, max_gap_for(da)), resample(tb, cb, gb, max_gap_for(db)),
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
