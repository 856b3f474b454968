"""What a trial is before it runs and what it came to: the prepared trial, its result, result.json.

Below the report and the trial runner, so both speak of the same objects: a report is
drawn from a :class:`TrialResult` and a :class:`PreparedTrial` and nothing else.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench.config.models import TrialConfig
from bench.core.log import TrialLog
from bench.core.looptiming import LoopTiming, loop_timing
from bench.core.outcome import NeedleOutcome, needle_outcome, settled_position
from bench.core.requirements import evaluate_requirements, trial_requirements
from bench.core.seen import joint_resolution, log_camera, seen_outcome
from bench.core.truth import true_outcome
from bench.kinematics.needle import NeedleTarget
from drivers.errors import TrialError, safe_stop_unconfirmed

__all__ = ["PreparedTrial", "TrialError", "TrialResult", "judge_requirements", "measured_outcome",
           "result_from_log", "status_from_log", "write_result_json"]


@dataclass
class PreparedTrial:
    """A trial that passed every check that can be made before anything moves, loaded once:
    what the backend will apply (calibration, faults, limits), the interlocks, and the plan
    from ``start`` that was checked through them. The run and the record take it from here."""

    config: TrialConfig
    robot: object
    target: NeedleTarget
    q_entry: np.ndarray
    q_insert: np.ndarray
    #: The calibration file as read (once) and applied, and its path; None when none applies.
    calibration: Optional[Any] = None
    calibration_path: Optional[Path] = None
    faults: list = field(default_factory=list)  #: the config's faults, parsed (FaultSpec)
    limits: Optional[Any] = None  #: the joint limits the backend will have (JointLimits)
    interlocks: Optional[Any] = None  #: the configured interlocks (None when disabled)
    monitor: Optional[Any] = None  #: the twin's set-up (bench.monitor.build.MonitorSetup), if monitored
    start: Optional[np.ndarray] = None  #: the pose the prepared plan starts from
    #: False when the plan's start was given (a comparison runs the rig's very plan on the sim):
    #: the run keeps it; True: the plan's moves from the start are re-aimed at the first reading.
    aim_at_reading: bool = True
    segments: list = field(default_factory=list)  #: the checked plan from ``start``

    def with_config(self, config: TrialConfig) -> "PreparedTrial":
        """The same trial on a config that differs only in how the backend is reached or stops
        (ports, timeouts, retries, safe stop): nothing prepared depends on those."""
        return replace(self, config=config)


@dataclass
class TrialResult:
    run_dir: Path
    log_path: Path
    completed: bool
    reason: str
    outcome: Optional[NeedleOutcome]
    extra: dict = field(default_factory=dict)
    #: An excitation run (identification): it passes by completing; there is no needle to place.
    excitation: bool = False
    #: How the actuators were left, in the backend's words (its read-back where it has one).
    safe_stop: str = ""
    #: Whether the control loop kept time (paced trials), or why there is nothing to say.
    timing: LoopTiming = field(default_factory=lambda: LoopTiming("not recorded"))
    #: What the twin beside the trial said (bench.monitor): its model, joints and alarms; None unmonitored.
    monitor: Optional[dict] = None
    #: The needle as the cameras measured it (bench.core.seen.camera_summary); None without cameras.
    camera: Optional[dict] = None
    #: What the verdict judged: the encoders' tip or the cameras' (``acceptance.by``).
    judged_by: str = "encoders"
    #: Each requirement's robustness (bench.core.requirements): {name, formula, robustness, holds,
    #: basis, scale[, measured_robustness]}, in the formula's units; empty for an excitation run.
    requirements: list = field(default_factory=list)
    #: Where the placement was judged: "sim" (the backend's truth) or "measured".
    basis: str = "measured"
    #: The placement where the backend's truth puts the needle (the simulators); None elsewhere.
    true_outcome: Optional[NeedleOutcome] = None
    #: The placement the cameras measured (bench.core.seen.seen_outcome); None without a measurement.
    seen: Optional[NeedleOutcome] = None
    #: The placement the encoders give (forward kinematics of the settled reading), whatever was judged.
    encoders: Optional[NeedleOutcome] = None

    @property
    def failing(self) -> list[dict]:
        """The requirements that do not hold."""
        return [r for r in self.requirements if not r["holds"]]

    @property
    def stop_confirmed(self) -> bool:
        """False when the backend could not confirm its safe stop: the rig may still be powered."""
        return not safe_stop_unconfirmed(self.safe_stop)

    @property
    def passed(self) -> bool:
        if self.excitation:
            return self.completed
        return (self.completed and self.outcome is not None and self.outcome.passed
                and not self.failing)

    @property
    def why_not(self) -> str:
        """Why the trial did not pass, in one line ("" when it passed); a safe stop that was not
        confirmed comes first, whatever the verdict: it is what the technician must see."""
        first = [self.safe_stop] if not self.stop_confirmed else []
        if self.passed:
            why = ""
        elif not self.completed:
            why = f"stopped early: {self.reason}"
        elif self.outcome is None:
            why = ("the cameras did not measure the tip: " + ((self.camera or {}).get("problem") or "?")
                   if self.judged_by == "camera" else "no settled insertion to measure")
        elif not self.outcome.passed:
            why = f"outside the acceptance limits: {self.outcome.failures()}"
        else:
            why = "requirement(s) not met: " + ", ".join(
                f"{r['name']} ({'no value' if r['robustness'] is None else format(r['robustness'], '+.3f')}"
                f"{', on the ' + PLACEMENT_BASES.get(r['basis'], 'readings') if r['basis'] else ''})"
                for r in self.failing)
        return "; ".join(first + ([why] if why else []))

    def summary(self) -> dict:
        o = self.outcome
        return {
            "run_dir": str(self.run_dir),
            "tip_deviation_mm": o.tip_deviation_mm if o else None,
            "depth_deviation_mm": o.depth_deviation_mm if o else None,
            "angle_deviation_deg": o.angle_deviation_deg if o else None,
            "passed": self.passed,
            "completed": self.completed,
            "reason": self.why_not,
            "safe_stop": self.safe_stop or None,
            "loop_timing": self.timing.as_dict(),
            "requirements": [{k: r[k] for k in ("name", "formula", "robustness", "holds")}
                             | ({"measured_robustness": r["measured_robustness"]}
                                if "measured_robustness" in r else {}) for r in self.requirements],
            "placement_basis": self.basis,
        } | ({"monitor": self.monitor} if self.monitor is not None else {}) | (
            {"camera": self.camera, "judged_by": self.judged_by} if self.camera is not None else {})


#: What each placement basis a requirement was judged on is called in one line.
PLACEMENT_BASES = {"sim": "true placement", "camera": "cameras' placement", "measured": "readings"}


def status_from_log(log: TrialLog) -> tuple[bool, str]:
    """(completed, why it stopped early) from the log's events alone."""
    kinds = [e.kind for e in log.events]
    if "done" in kinds:
        return True, ""
    for e in reversed(log.events):
        if e.kind == "abort":
            return False, e.message
        if e.kind == "interlock":
            return False, f"interlock {e.message}"
    return False, "the log ends before the plan did"


def measured_outcome(log: TrialLog, prep: PreparedTrial) -> Optional[NeedleOutcome]:
    """The placement the readings give (the insertion's settled joints); None without one."""
    cfg = prep.config
    try:
        q_final = settled_position(log, "insert")
        return needle_outcome(prep.robot, q_final, prep.target,
                              cfg.acceptance.position_mm, cfg.acceptance.angle_deg)
    except (KeyError, ValueError):
        return None


def judge_requirements(log: TrialLog, prep: PreparedTrial, truth: Any = None) -> None:
    """Each requirement's robustness into the log's metadata (``requirements``, and the true
    placement where ``truth``, a GroundTruth recorder, saw the backend's joints), before the log
    is saved: the record keeps what the truth said, which the log alone cannot give again. Without
    a truth, a trial judged by the cameras (``acceptance.by: camera``) has its placement's
    requirements on the cameras' placement (basis ``camera``), the readings' beside."""
    cfg = prep.config
    if cfg.excitation is not None:
        return
    measured = measured_outcome(log, prep)
    outcome, basis = measured, "measured"
    if cfg.acceptance.by == "camera":
        outcome, basis = seen_outcome(log, prep.target, cfg.acceptance.position_mm,
                                      cfg.acceptance.angle_deg), "camera"
    if truth is not None and getattr(truth, "available", False):
        basis = "sim"
        try:
            outcome = true_outcome(log, truth, prep.robot, prep.target, cfg.acceptance.position_mm,
                                   cfg.acceptance.angle_deg)
        except (KeyError, ValueError):  # stopped before the insertion: no placement
            outcome = None
        log.metadata["true_outcome"] = outcome.as_dict() if outcome is not None else None
    log.metadata["placement_basis"] = basis
    reqs = trial_requirements(cfg)
    try:
        log.metadata["requirements"] = evaluate_requirements(
            reqs, log, prep.robot, cfg.control_period, outcome, measured, truth, basis)
    except Exception as e:  # the record is saved whatever a requirement's evaluation does
        why = f"not evaluated: {type(e).__name__}: {e}"[:200]
        log.metadata["requirements"] = [{"name": r.name, "formula": r.formula, "robustness": None, "holds": False,
                                         "basis": basis, "scale": r.scale, "error": why} for r in reqs]


def result_from_log(run_dir: Path, log: TrialLog, prep: PreparedTrial) -> TrialResult:
    """The trial's result computed from its log, identically at the end of a trial and later."""
    cfg = prep.config
    encoders = outcome = measured_outcome(log, prep)
    camera = log_camera(log, prep.robot, prep.target, joint_resolution(cfg, log.joint_names))
    seen = seen_outcome(log, prep.target, cfg.acceptance.position_mm, cfg.acceptance.angle_deg)
    if cfg.acceptance.by == "camera":  # judged on the cameras' tip, or not at all
        outcome = seen
    completed, reason = status_from_log(log)
    stops = [e.message for e in log.events if e.kind == "safe-stop"]
    if cfg.excitation is None and "requirements" not in log.metadata:  # an older record, or no truth
        judge_requirements(log, prep)
    true = log.metadata.get("true_outcome")
    try:
        true = NeedleOutcome(**true) if isinstance(true, dict) else None
    except TypeError:  # a record that was edited: the truth it claims is not read
        true = None
    return TrialResult(Path(run_dir), Path(run_dir) / "trial.npz", completed, reason, outcome,
                       excitation=cfg.excitation is not None, safe_stop=stops[-1] if stops else "",
                       timing=loop_timing(log, cfg.control_period), monitor=log.metadata.get("monitor"),
                       camera=camera, judged_by=cfg.acceptance.by,
                       requirements=_requirement_rows(log.metadata.get("requirements")),
                       basis=str(log.metadata.get("placement_basis", "measured")), true_outcome=true,
                       seen=seen, encoders=encoders)


def _requirement_rows(rows: object) -> list[dict]:
    """The requirements a log's metadata holds, the rows of the shape the bench writes only."""
    out = []
    for r in rows if isinstance(rows, list) else []:
        if (isinstance(r, dict) and isinstance(r.get("name"), str) and isinstance(r.get("formula"), str)
                and isinstance(r.get("holds"), bool)
                and (r.get("robustness") is None or isinstance(r.get("robustness"), (int, float)))):
            out.append({"basis": "measured", "scale": 1.0, **r})
    return out


def write_result_json(res: TrialResult) -> None:
    """result.json: strict JSON, a value that is not a finite number written as null (never NaN)."""
    summary = res.summary()
    summary.update({"completed": res.completed, "reason": res.reason,
                    "outcome": res.outcome.as_dict() if res.outcome else None})
    text = json.dumps(_finite_or_null(summary), indent=2, allow_nan=False)
    (res.run_dir / "result.json").write_text(text + "\n")


def _finite_or_null(v: object) -> object:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite_or_null(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite_or_null(x) for x in v]
    return v
