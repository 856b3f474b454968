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
from bench.core.outcome import NeedleOutcome, needle_outcome, pose_outcome, settled_position
from bench.core.seen import camera_pose, camera_summary
from bench.kinematics.needle import NeedleTarget
from drivers.errors import TrialError, safe_stop_unconfirmed

__all__ = ["PreparedTrial", "TrialError", "TrialResult", "result_from_log", "status_from_log",
           "write_result_json"]


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

    @property
    def stop_confirmed(self) -> bool:
        """False when the backend could not confirm its safe stop: the rig may still be powered."""
        return not safe_stop_unconfirmed(self.safe_stop)

    @property
    def passed(self) -> bool:
        if self.excitation:
            return self.completed
        return self.completed and self.outcome is not None and self.outcome.passed

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
        else:
            why = f"outside the acceptance limits: {self.outcome.failures()}"
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
        } | ({"monitor": self.monitor} if self.monitor is not None else {}) | (
            {"camera": self.camera, "judged_by": self.judged_by} if self.camera is not None else {})


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


def result_from_log(run_dir: Path, log: TrialLog, prep: PreparedTrial) -> TrialResult:
    """The trial's result computed from its log, identically at the end of a trial and later."""
    cfg = prep.config
    outcome = None
    try:
        q_final = settled_position(log, "insert")
        outcome = needle_outcome(prep.robot, q_final, prep.target,
                                 cfg.acceptance.position_mm, cfg.acceptance.angle_deg)
    except (KeyError, ValueError):
        pass
    measured = log.metadata.get("camera")
    camera = camera_summary(measured, None if outcome is None else prep.robot.needle(q_final), prep.target)
    if cfg.acceptance.by == "camera":  # judged on the cameras' tip, or not at all
        seen = camera_pose((measured or {}).get("captures", {}).get("insert"), prep.target)
        outcome = None if seen is None else pose_outcome(seen, prep.target, cfg.acceptance.position_mm,
                                                         cfg.acceptance.angle_deg)
    completed, reason = status_from_log(log)
    stops = [e.message for e in log.events if e.kind == "safe-stop"]
    return TrialResult(Path(run_dir), Path(run_dir) / "trial.npz", completed, reason, outcome,
                       excitation=cfg.excitation is not None, safe_stop=stops[-1] if stops else "",
                       timing=loop_timing(log, cfg.control_period), monitor=log.metadata.get("monitor"),
                       camera=camera, judged_by=cfg.acceptance.by)


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
