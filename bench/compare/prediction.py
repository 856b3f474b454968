"""How well a simulator with a servo model predicts the rig: the prediction figures of a comparison.

* ``tip_error_mm``: per repeat, the distance (mm) between the needle tip the model-driven sim
  placed and the one the rig placed, each where its own readings put it; mean and max over
  repeats. A placement is the mean reading over the insertion's settle (its last
  :data:`SETTLE_FRACTION`), the train's over all its stillness before (:func:`placement_windows`):
  its ultrasonic reading is whole millimetres of arc, 0.7 mm of tip a step, with a millimetre of
  noise on the rig, and the host loop on either side steers the train until its mean reading is
  the goal; only that mean over seconds says where the loop put it.
* ``tracking_gap_ratio``: the gap between the sim's and the rig's measured joint profiles
  with the model, divided by the same gap with PyBullet's ideal motors. A gap is the RMS over
  joints and time of (sim − rig) after alignment, each joint's difference taken relative to
  its commanded excursion (so radians and metres mix fairly; joints that hardly move are left
  out). 1 means the model predicts no better than the ideal sim; 0.2 is an 80 % smaller gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from bench.compare.analysis import Comparison
from bench.core.log import TrialLog
from bench.core.outcome import settle_rows

__all__ = ["Prediction", "completed_repeats", "placement_windows", "prediction", "sensed_joint", "settled_tip_mm",
           "tracking_gap"]

#: Commanded excursion below which a joint counts as still (its gap is left out): 0.5° or 0.5 mm,
#: a few encoder ticks, where a plan's start at the measured pose is all that "moves" it.
STILL_EXCURSION = {"revolute": math.radians(0.5), "prismatic": 0.5e-3}


#: The part of the insertion's settle (its end) over which a placement is averaged.
SETTLE_FRACTION = 0.8
#: A joint read by the ultrasonic sensor is averaged over all its stillness before the placement:
#: from this long (s) after its goal last changed to the end of the insertion's settle.
SENSED_SETTLE_S = 0.5


def _settle(log: TrialLog) -> np.ndarray | None:
    """The rows of the insertion's settle a placement averages over; None when the trial stopped before it."""
    settle_s = float(log.metadata.get("config", {}).get("plan", {}).get("settle_s", 0.0) or 0.0)
    try:
        return settle_rows(log.time, log.segment, log.segment_names, "insert", max(SETTLE_FRACTION * settle_s, 0.1))
    except ValueError:
        return None


def sensed_joint(log: TrialLog) -> str | None:
    """The joint a rig log read through its ultrasonic sensor (None for another backend)."""
    backend = log.metadata.get("config", {}).get("backend", {})
    sensor = backend.get("ultrasonic") if backend.get("kind") == "dynamixel" else None
    return sensor.get("joint") if isinstance(sensor, dict) else None


def placement_windows(log: TrialLog, sensed: str | None = None) -> np.ndarray | None:
    """Per joint, the (start, end) times (s) its placement is averaged over, (n, 2): the insertion's
    settle; for the ``sensed`` joint, all the time its goal was still before the settle's end (the
    ultrasonic reading is whole millimetres of arc, 0.7 mm of tip a step, with a millimetre of
    noise: only its dither over seconds resolves where the train stands). None when the trial
    stopped before the settle."""
    rows = _settle(log)
    if rows is None:
        return None
    windows = np.tile([log.time[rows[0]], log.time[rows[-1]]], (log.q.shape[1], 1))
    if sensed in log.joint_names:
        j = log.joint_names.index(sensed)
        before = log.time <= windows[j, 1]
        changed = np.flatnonzero(np.abs(np.diff(log.q_cmd[before, j])) > 0)
        still_from = log.time[changed[-1] + 1] + SENSED_SETTLE_S if changed.size else log.time[0]
        windows[j, 0] = min(still_from, windows[j, 0])
    return windows


def _mean_in(times: np.ndarray, q: np.ndarray, windows: np.ndarray) -> np.ndarray:
    out = np.full(q.shape[1], np.nan)
    for j, (a, b) in enumerate(windows):
        keep = (times >= a - 1e-9) & (times <= b + 1e-9)
        if keep.any():
            out[j] = np.nanmean(q[keep, j])
    return out


def settled_tip_mm(log: TrialLog, robot, sensed: str | None = None) -> np.ndarray | None:
    """The needle tip (mm) at the mean measured position over each joint's placement window
    (:func:`placement_windows`); None when the trial stopped before the settle."""
    windows = placement_windows(log, sensed)
    if windows is None:
        return None
    q = _mean_in(log.time, log.q, windows)
    return robot.needle(q).tip * 1e3 if np.all(np.isfinite(q)) else None


def _excursions(cmp: Comparison) -> np.ndarray:
    q = np.concatenate([log.q_cmd for log in cmp.subject.logs])
    return np.nanmax(q, axis=0) - np.nanmin(q, axis=0)


def completed_repeats(*cmps: Comparison) -> list[bool]:
    """Per repeat, whether both sides of every comparison completed it."""
    sides = [c for cmp in cmps for c in (cmp.reference.completed, cmp.subject.completed)]
    return [all(bool(flags[i]) if i < len(flags) else False for flags in sides)
            for i in range(min(len(flags) for flags in sides))]


def tracking_gap(cmp: Comparison, repeats: Optional[list[bool]] = None) -> float:
    """RMS over the moving joints and the repeats of (sim − rig) / excursion (unit-free), over the
    repeats both sides completed (a run stopped early by an interlock is compared over its first
    rows only, and would pass for a close one), or those ``repeats`` says; NaN when none."""
    exc = _excursions(cmp)
    still = [STILL_EXCURSION[row.kind] for row in cmp.robot.chain.rows]
    done = completed_repeats(cmp) if repeats is None else repeats
    rel = [[d.rms / e for d, e, s in zip(pair, exc, still) if e > s and math.isfinite(d.rms)]
           for pair, ok in zip(cmp.profile, done) if ok]
    values = np.array([v for pair in rel for v in pair])
    return float(np.sqrt(np.mean(values ** 2))) if values.size else math.nan


@dataclass(frozen=True)
class Prediction:
    """The model's prediction of the rig, beside the ideal sim's (see the module's docstring)."""

    tip_error_mm: list[float]
    gap_model: float
    gap_ideal: float
    #: The same distance with each tip placed as its trial placed it for its verdict and as the
    #: repeat tables show it (median over the last SETTLED_WINDOW_S of the settle), per repeat.
    trial_tip_error_mm: list[float] = field(default_factory=list)

    @property
    def tracking_gap_ratio(self) -> float:
        return self.gap_model / self.gap_ideal if self.gap_ideal > 0 else math.nan

    def as_dict(self) -> dict:
        clean = lambda v: None if not math.isfinite(v) else round(float(v), 6)  # noqa: E731
        tips = np.array(self.tip_error_mm, dtype=float)
        return {"tip_error_mm": {"mean": clean(tips.mean()) if tips.size else None,
                                 "max": clean(tips.max()) if tips.size else None,
                                 "per_repeat": [clean(v) for v in tips]},
                "trial_tip_error_mm": [clean(v) for v in self.trial_tip_error_mm],
                "tracking_gap_ratio": clean(self.tracking_gap_ratio),
                "tracking_gap": {"model": clean(self.gap_model), "ideal": clean(self.gap_ideal)}}


def prediction(model_vs_rig: Comparison, ideal_vs_rig: Comparison) -> Prediction:
    """The prediction figures of a model-driven sim (reference side of ``model_vs_rig``)."""
    robot = model_vs_rig.robot
    sensed = next((j for j in map(sensed_joint, model_vs_rig.subject.logs) if j), None)
    sim = [settled_tip_mm(log, robot, sensed) for log in model_vs_rig.reference.logs]
    rig = [settled_tip_mm(log, robot, sensed) for log in model_vs_rig.subject.logs]
    tips = [float(np.linalg.norm(r - sim[min(i, len(sim) - 1)]))
            for i, r in enumerate(rig) if r is not None and sim[min(i, len(sim) - 1)] is not None]
    placed = [(np.array(r.tip_mm), np.array(s.tip_mm)) for r, s in
              zip(model_vs_rig.subject.outcomes, model_vs_rig.reference.outcomes) if r and s]
    # both gaps over the same repeats: those the rig and both sims completed
    done = completed_repeats(model_vs_rig, ideal_vs_rig)
    return Prediction(tips, tracking_gap(model_vs_rig, done), tracking_gap(ideal_vs_rig, done),
                      [float(np.linalg.norm(r - s)) for r, s in placed])
