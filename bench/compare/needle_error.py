"""The needle of a logged trial: where it ended per repeat (the encoders' and, with cameras, the
cameras'), each joint's share of the tip deviation (its placement error through the FK Jacobian) and
the repeat statistics of Tables 3 and 4."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from bench.compare.signals import PlanMismatchError
from bench.compare.tracking import placement, robot_of_log
from bench.core.log import TrialLog
from bench.core.outcome import NeedleOutcome, needle_outcome
from bench.core.seen import joint_resolution, log_camera, seen_outcome
from bench.kinematics.batch import needle_jacobian
from bench.kinematics.needle import NeedleTarget


def target_of_log(log: TrialLog) -> NeedleTarget:
    t = log.metadata.get("target")
    if not t:
        raise PlanMismatchError("the log has no 'target' in its metadata: not a trial log of this bench")
    return NeedleTarget(np.asarray(t["entry_m"], dtype=float), float(t["depth_m"]),
                        float(t["angle_rad"]), float(t.get("tilt_rad", 0.0)))


def acceptance_of(log: TrialLog) -> tuple[float, float]:
    """(position mm, angle deg) from the log's config, else seed 000's 5 mm and 1°."""
    acc = (log.metadata.get("config") or {}).get("acceptance") or {}
    return float(acc.get("position_mm", 5.0)), float(acc.get("angle_deg", 1.0))


def judged_by_of(log: TrialLog) -> str:
    """The tip the log's trial was judged on: "encoders" or "camera" (its config's ``acceptance.by``)."""
    acc = (log.metadata.get("config") or {}).get("acceptance") or {}
    return "camera" if acc.get("by") == "camera" else "encoders"


def cameras_of_log(log: TrialLog, robot, acceptance: tuple[float, float]
                   ) -> tuple[Optional[dict], Optional[NeedleOutcome]]:
    """The cameras' figures of a logged trial (as ``trial --json`` gives them; None without cameras)
    and the placement they measured against the limits (None without a measurement)."""
    target = target_of_log(log)
    config = log.metadata.get("config") or {}
    figures = log_camera(log, robot, target, joint_resolution(config, log.joint_names))
    return figures, (seen_outcome(log, target, *acceptance) if figures is not None else None)


def needle_of_log(log: TrialLog, robot=None, acceptance: Optional[tuple[float, float]] = None,
                  segment: str = "insert") -> Optional[NeedleOutcome]:
    """The achieved needle at the placement, against the log's target (None: never placed)."""
    robot = robot or robot_of_log(log)
    try:
        q, _ = placement(log, segment)
    except (KeyError, ValueError):
        return None
    if not np.all(np.isfinite(q)):
        return None
    pos, ang = acceptance or acceptance_of(log)
    return needle_outcome(robot, q, target_of_log(log), pos, ang)


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
