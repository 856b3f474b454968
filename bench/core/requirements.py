"""Each requirement's robustness over a trial's log: rtamt's discrete-time STL, in the formula's units.

The signals (:mod:`bench.config.requirements`) are built from the log, and from the backend's truth
where a :class:`bench.core.truth.GroundTruth` recorder saw it (the simulators): the placement at the
end of the insertion, held over the whole trace, and per sample the gantry clearance, each joint's
tracking error, effort and twin residual. The trace's samples are one control period apart
(rtamt's discrete time: a bounded operator's interval is in seconds). A requirement is evaluated at
the trace's first sample; its robustness is the signed margin by which the trace satisfies it (mm
or degrees as its signals), ``holds`` when it is not negative. A requirement that reads the
placement of a trial stopped before its insertion, or a signal the trial did not log (a twin
residual in an unmonitored trial), has no robustness (None) and does not hold.
"""

from __future__ import annotations

import logging
import math
import re
from typing import Any, Optional, Sequence

import numpy as np

from bench.config.requirements import (PLACEMENT_SIGNALS, Requirement, default_requirements, formula_signals,
                                      formula_unit, is_temporal, rtamt_module)
from bench.core.log import TrialLog
from bench.core.outcome import NeedleOutcome
from bench.scene.contact import GantryClearance

__all__ = ["evaluate_requirements", "lowest", "placement_signals", "trial_requirements", "trial_signals"]


def trial_requirements(config: Any) -> list[Requirement]:
    """The requirements a trial config is judged by: its own, else the acceptance limits at the end
    of the insertion and the gantry clearance at all times (:func:`default_requirements`)."""
    if config.requirements is not None:
        return list(config.requirements)
    return default_requirements(config.acceptance.position_mm, config.acceptance.angle_deg)


def placement_signals(outcome: Optional[NeedleOutcome]) -> dict[str, float]:
    """The placement at the end of the insertion as the signals name it (mm, degrees)."""
    if outcome is None:
        return {}
    tip, entry = outcome.tip_deviation_mm, outcome.entry_deviation_mm
    values = [*tip, *entry, outcome.depth_deviation_mm, outcome.angle_deviation_deg]
    return dict(zip(PLACEMENT_SIGNALS, (float(v) for v in values)))


def _true_q(log: TrialLog, truth: Any) -> np.ndarray:
    """The true joint positions at the log's samples (the recorder's read nearest before each)."""
    t, q = truth.times, truth.positions
    idx = np.clip(np.searchsorted(t, log.time, side="right") - 1, 0, len(t) - 1)
    return q[idx]


def trial_signals(log: TrialLog, robot: Any, needed: Sequence[str], outcome: Optional[NeedleOutcome],
                  measured: Optional[NeedleOutcome], truth: Any = None) -> dict[str, np.ndarray]:
    """The series of the ``needed`` signals, one value per logged sample (absent: not logged)."""
    n = len(log)
    out: dict[str, np.ndarray] = {}
    placed = placement_signals(outcome)
    placed.update({f"measured_{k}": v for k, v in placement_signals(measured).items()})
    kinds = [r.kind for r in robot.chain.rows]
    q = log.q
    if truth is not None and getattr(truth, "available", False) and len(truth.times):
        q = _true_q(log, truth)
    for name in needed:
        if name in placed:
            out[name] = np.full(n, placed[name])
        elif name == "gantry_clearance_mm" and n:
            out[name] = GantryClearance(robot, 0.02).distances_batch(q).min(axis=1) * 1e3
        elif name.startswith("track_"):
            j = log.joint(name[len("track_"):].rsplit("_", 1)[0])
            err = np.abs(log.q[:, j] - log.q_cmd[:, j])
            out[name] = err * 1e3 if kinds[j] == "prismatic" else np.degrees(err)
        elif name.startswith("effort_"):
            out[name] = np.asarray(log.effort[:, log.joint(name[len("effort_"):])], dtype=float)
        elif name.startswith("twin_z_") and log.twin_z is not None:  # NaN: a cycle not watched
            out[name] = np.nan_to_num(np.asarray(log.twin_z[:, log.joint(name[len("twin_z_"):])], dtype=float))
    return out


def _robustness(formula: str, signals: dict[str, np.ndarray], names: list[str], period: float) -> float:
    spec = rtamt_module().StlDiscreteTimeOfflineSpecification()
    spec.set_sampling_period(period, "s", 0.1)
    for name in names:
        spec.declare_var(name, "float")
    spec.spec = formula
    spec.parse()
    n = len(next(iter(signals.values())))
    if not is_temporal(formula):  # its value at the first sample reads that sample alone: rtamt is
        n = min(n, 2)             # given two (the fewest it takes to know the period), not thousands
    data: dict[str, list] = {"time": [i * period for i in range(n)]}
    for name in names:
        data[name] = signals[name][:n].tolist()
    rob = spec.evaluate(data)
    return float(rob[0][1])


def evaluate_requirements(reqs: Sequence[Requirement], log: TrialLog, robot: Any, period: float,
                          outcome: Optional[NeedleOutcome], measured: Optional[NeedleOutcome],
                          truth: Any = None, basis: str = "measured") -> list[dict]:
    """Each requirement's robustness: ``{name, formula, robustness, holds, basis, scale}`` and, where
    the placement is judged on the truth, ``measured_robustness`` (the same formula on the readings)."""
    needed = sorted({s for r in reqs for s in formula_signals(r.formula)})
    measured_names = {s: f"measured_{s}" for s in PLACEMENT_SIGNALS}
    extra = [measured_names[s] for s in needed if s in measured_names] if basis != "measured" else []
    signals = trial_signals(log, robot, needed + extra, outcome, measured, truth)
    out = []
    for r in reqs:
        names = formula_signals(r.formula)
        value = _evaluate(r.formula, names, signals, period)
        row: dict[str, Any] = {"name": r.name, "formula": r.formula, "robustness": value,
                               "holds": value is not None and value >= 0, "unit": formula_unit(r.formula),
                               "basis": basis, "scale": r.scale}
        if basis != "measured" and any(s in measured_names for s in names):
            swapped = r.formula
            for s in sorted((s for s in names if s in measured_names), key=len, reverse=True):
                swapped = _rename(swapped, s, measured_names[s])
            row["measured_robustness"] = _evaluate(swapped, formula_signals(swapped), signals, period)
        out.append(row)
    return out


def _rename(formula: str, old: str, new: str) -> str:
    return re.sub(rf"(?<![\w.]){re.escape(old)}(?!\w)", new, formula)


def _evaluate(formula: str, names: list[str], signals: dict[str, np.ndarray], period: float) -> Optional[float]:
    if not names or any(s not in signals or not len(signals[s]) or not np.all(np.isfinite(signals[s]))
                        for s in names):
        return None
    quiet = logging.getLogger()
    level = quiet.level
    try:
        quiet.setLevel(logging.ERROR)  # rtamt warns on the root logger of what it infers
        value = _robustness(formula, signals, names, period)
    finally:
        quiet.setLevel(level)
    return round(value, 9) + 0.0 if math.isfinite(value) else None


def lowest(rows: Sequence[dict]) -> tuple[Optional[dict], float]:
    """The requirement with the lowest scaled robustness (robustness / scale) and that value;
    a requirement with no robustness is the lowest, at −inf."""
    worst, score = None, math.inf
    for r in rows:
        v = r.get("robustness")
        s = -math.inf if v is None else v / float(r.get("scale") or 1.0)
        if worst is None or s < score:
            worst, score = r, s
    return worst, score
