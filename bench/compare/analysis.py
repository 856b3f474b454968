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

from dataclasses import dataclass, field
from typing import Literal, Optional, Sequence

import numpy as np

from bench.compare.alignment import ProfileDiff, check_same_plan, profile_difference
from bench.compare.needle_error import (
    JointContribution,
    acceptance_of,
    cameras_of_log,
    joint_contributions,
    judged_by_of,
    needle_of_log,
    repeat_statistics,
)
from bench.compare.signals import DEFAULT_MAX_LAG_S, nanmean
from bench.compare.tracking import JointTracking, joint_tracking, placement, robot_of_log
from bench.core.log import TrialLog
from bench.core.outcome import NeedleOutcome
from bench.core.result import status_from_log

__all__ = ["Comparison", "Side", "TABLE4_CURRENT_RESEARCH_MM", "compare_logs"]


#: Seed 000 Table 4, "current research": average deviation (mm) in X, Y, Z and depth.
TABLE4_CURRENT_RESEARCH_MM: dict[str, float] = {"x": 2.7, "y": 3.1, "z": 2.7, "insertion": 1.51}


# ---------------------------------------------------------------------------
# Samples, time bases and resampling
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# Lag
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# One log: per-joint tracking
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# Same plan?
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# Two logs: alignment and the difference of their measured profiles
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# The needle: per repeat, over repeats, and which joints explain it
# ---------------------------------------------------------------------------


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
    #: What the logs say ran them: sim, emulated or real (their record's ``rig``; "?" for older logs).
    rig: str = "?"
    #: Per repeat: the cameras' figures (bench.core.seen.camera_summary; None: the trial had no
    #: cameras) and the placement they measured (None: no measurement), with its statistics.
    cameras: list[Optional[dict]] = field(default_factory=list)
    seen: list[Optional[NeedleOutcome]] = field(default_factory=list)
    seen_stats: dict = field(default_factory=dict)
    #: The tip the trials were judged on (their config's ``acceptance.by``): "encoders" or "camera".
    judged_by: str = "encoders"

    @property
    def placed(self) -> list[NeedleOutcome]:
        return [o for o in self.outcomes if o is not None]

    @property
    def has_cameras(self) -> bool:
        """The trials had cameras: their Table 3 is the cameras' (as seed 000's was)."""
        return any(c is not None for c in self.cameras)

    @property
    def table3(self) -> tuple[list[Optional[NeedleOutcome]], dict]:
        """The placements Table 3 shows and their statistics: the cameras' where the trials had
        cameras, else the encoders'."""
        return (self.seen, self.seen_stats) if self.has_cameras else (self.outcomes, self.stats)

    @property
    def judged(self) -> tuple[list[Optional[NeedleOutcome]], dict]:
        """The placements the verdict is on (the trials' ``acceptance.by``) and their statistics."""
        return (self.seen, self.seen_stats) if self.judged_by == "camera" else (self.outcomes, self.stats)

    @property
    def passed(self) -> bool:
        """Every repeat completed and placed the needle within the limits."""
        return bool(self.logs) and all(self.completed) and all(o is not None and o.passed
                                                               for o in self.judged[0])

    def mean_tracking(self, attr: str) -> np.ndarray:
        """Mean over repeats of one :class:`JointTracking` field, per joint (NaN-aware)."""
        a = np.array([[getattr(jt, attr) for jt in rep] for rep in self.tracking], dtype=float)
        return nanmean(a)

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

    return status_from_log(log)


def _side(label: str, logs: Sequence[TrialLog], sources: Sequence[str], robot,
          acceptance: Optional[tuple[float, float]], band, max_lag_s: float) -> Side:
    tracking, outcomes, completed, reasons, contribs, cameras, seen = [], [], [], [], [], [], []
    for log in logs:
        tracking.append(joint_tracking(log, robot, band, max_lag_s))
        o = needle_of_log(log, robot, acceptance)
        outcomes.append(o)
        figures, measured = cameras_of_log(log, robot, acceptance or acceptance_of(log))
        cameras.append(figures)
        seen.append(measured)
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
                contribs, cameras=cameras, seen=seen,
                judged_by=judged_by_of(logs[0]) if logs else "encoders")
    side.stats = repeat_statistics(side.placed)
    side.seen_stats = repeat_statistics([o for o in seen if o is not None])
    side.rig = ", ".join(sorted({str(log.metadata.get("rig") or "?") for log in logs})) or "?"
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
        return nanmean(np.array([[getattr(p, attr) for p in pair] for pair in self.profile],
                                 dtype=float))

    def summary(self) -> dict:
        """The one-line JSON of ``hilbench compare --json``, over the subject's placed repeats, on
        the tip its trials were judged on (:func:`_deviations`); with cameras, the encoders' and the
        cameras' beside (:func:`_camera_block`)."""
        sub = self.subject
        judged = _deviations(sub.judged[1])
        out = {"repeats": len(sub.logs), **judged, "rig": sub.rig, "passed": self.passed,
               "completed": sum(bool(c) for c in sub.completed), "reason": self.why_not(),
               "worst_joint": self.worst_joint}
        if sub.has_cameras:  # the cameras' beside the encoders', whichever was judged
            out.update(judged_by=sub.judged_by, encoders=_deviations(sub.stats), camera=_camera_block(sub))
        return out

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
        judged = sub.judged[0]
        unseen = [i + 1 for i, o in enumerate(judged) if o is None]
        if sub.judged_by == "camera" and unseen:
            why = (sub.cameras[unseen[0] - 1] or {}).get("problem") or "?"
            return (f"the cameras did not measure the tip of {sub.label} repeat(s) "
                    f"{', '.join(map(str, unseen))}: {why}")
        out = [i + 1 for i, o in enumerate(judged) if o is None or not o.passed]
        by = " (by the cameras)" if sub.judged_by == "camera" else ""
        return (f"{sub.label} repeat(s) {', '.join(map(str, out))} of {len(sub.logs)} placed the "
                f"needle outside {pos:g} mm / {ang:g}°{by}")

    def as_dict(self) -> dict:
        """A full machine-readable record (SI per joint, mm and degrees for the needle)."""

        def stats(d: dict) -> dict:
            return {k: {m: _clean_list(np.atleast_1d(v)) for m, v in row.items()} for k, row in d.items()}

        def side(sd: Side) -> dict:
            return {"label": sd.label, "backend": sd.backend, "rig": sd.rig, "sources": sd.sources,
                    "completed": sd.completed, "reasons": sd.reasons, "passed": sd.passed,
                    "outcomes": [o.as_dict() if o else None for o in sd.outcomes],
                    "tracking": [[jt.as_dict() for jt in rep] for rep in sd.tracking],
                    "mean_tracking": {a: _clean_list(sd.mean_tracking(a))
                                      for a in ("rms", "max_abs", "final", "placement", "lag_s",
                                                "settling_s", "hold_effort")},
                    "contributions": [[c.as_dict() for c in rep] if rep else None
                                      for rep in sd.contributions],
                    "ranking": [{"joint": n, "tip_mm": v} for n, v in sd.contribution_ranking()],
                    "stats": stats(sd.stats),
                    "judged_by": sd.judged_by, "table3_by": "cameras" if sd.has_cameras else "encoders",
                    "cameras": sd.cameras, "seen": [o.as_dict() if o else None for o in sd.seen],
                    "seen_stats": stats(sd.seen_stats)}

        return {"robot": getattr(self.robot, "name", "?"), "joints": self.joint_names,
                "kinds": [r.kind for r in self.robot.chain.rows],
                "acceptance": {"position_mm": self.acceptance[0], "angle_deg": self.acceptance[1]},
                "align": self.align, "reference": side(self.reference), "subject": side(self.subject),
                "profile": [[p.as_dict() for p in pair] for pair in self.profile],
                "profile_mean": {"rms": _clean_list(self.profile_mean("rms")),
                                 "max_abs": _clean_list(self.profile_mean("max_abs")),
                                 "cmd_rms": _clean_list(self.profile_mean("cmd_rms"))},
                "summary": self.summary()}


def _deviations(s: dict) -> dict:
    """The needle's deviations over repeats as ``compare --json`` gives them: ``mean`` signed,
    ``max`` the largest |deviation|, ``std`` the sample standard deviation (mm; the angle in
    degrees; null when no repeat placed the needle)."""
    one = lambda v: None if not np.isfinite(v) else round(float(v), 6) + 0.0  # noqa: E731
    r = lambda v: [one(x) for x in np.atleast_1d(v)]  # noqa: E731

    def block(k: str, vector: bool) -> dict:
        if vector:
            return {"mean": r(s[k]["mean"]), "max": r(s[k]["max_abs"]), "std": r(s[k]["std"])}
        return {"mean": one(s[k]["mean"]), "max": one(s[k]["max_abs"]), "std": one(s[k]["std"])}

    return {"tip_deviation_mm": block("tip_mm", True), "depth_deviation_mm": block("depth_mm", False),
            "angle_deviation_deg": block("angle_deg", False)}


def _camera_block(side: Side) -> dict:
    """``compare --json``'s "camera": the cameras' deviations over the repeats they measured, and per
    repeat the gap between the encoders' tip and the cameras', its flag and why a repeat has none."""
    figures = [c or {} for c in side.cameras]
    return {"measured": sum(o is not None for o in side.seen), **_deviations(side.seen_stats),
            "within_limits": sum(1 for o in side.seen if o is not None and o.passed),
            "encoder_gap_mm": [c.get("encoder_gap_mm") for c in figures],
            "uncertainty_mm": [c.get("uncertainty_mm") for c in figures],
            "flag": [c.get("flag") for c in figures],
            "problem": [c.get("problem", "the trial had no cameras") for c in figures]}


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
    robot = robot_of_log(first)
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
