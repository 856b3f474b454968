"""The needle as the cameras saw it (bench.cameras), beside the encoders' (forward kinematics).

The record keeps what was measured (``log.metadata["camera"]``); this turns the capture at the end
of the insertion into the trial's camera figures, the same at the end of a trial and later:
the tip's deviation from the target, the needle's angle, the gap between the encoders' tip and
the cameras', the uncertainty, and the flag: a gap beyond what the uncertainty explains.

Both tips are uncertain: the cameras' by their calibration and detection (the measurement's
covariance), the encoders' by their resolution (a servo reads its shaft to a tick, 0.088°, so
the joint it drives is anywhere within half a step of its reading) and by the scatter of a sensed
joint's readings (the train's ultrasonic sensor) over the settle. The gap is flagged beyond
:data:`COVERAGE` standard deviations of the two together: a clean rig whose encoders place the
tip half a millimetre from the truth is not flagged, an encoder bias of a degree is.
"""

from __future__ import annotations

from typing import Any, Mapping, Optional

import numpy as np

from bench.core.log import TrialLog
from bench.core.outcome import NeedleOutcome, pose_outcome, settle_rows, settled_position
from bench.kinematics.needle import NeedlePose, NeedleTarget, angles_of, pose_from_axis
from drivers.dynamixel.control_table import x_series_table

__all__ = ["COVERAGE", "camera_pose", "camera_summary", "encoder_tip_sigma", "joint_resolution", "log_camera",
           "seen_outcome"]

#: The uncertainty reported is this many standard deviations of the tip (the root of its
#: covariance's trace): a gap beyond it is flagged.
COVERAGE = 3.0


def camera_pose(capture: dict, target: NeedleTarget) -> Optional[NeedlePose]:
    """The needle the cameras measured: its tip and direction; the entry point where that line
    crosses the plane of the target's entry (the skin), the depth from there."""
    if not capture or capture.get("tip_m") is None:
        return None
    tip, axis = np.asarray(capture["tip_m"], dtype=float), np.asarray(capture["direction"], dtype=float)
    entry_z = float(np.asarray(target.entry)[2])
    if abs(axis[2]) < 1e-6:  # a needle lying flat never crosses the skin's plane
        return None
    entry = tip + (entry_z - tip[2]) / axis[2] * axis
    return pose_from_axis(entry, axis, float(np.linalg.norm(tip - entry)))


def joint_resolution(config: Any, names) -> np.ndarray:
    """Each joint's reading step (joint units) on the config's backend: on a servo bus, a tick of
    its servo through the transmission; 0 where the bench reads no quantized encoder (the sensed
    joint, whose readings' scatter counts instead; the simulator's exact joints). ``config``: a
    trial config, or the one a log's record keeps (a mapping), so a saved trial says the same."""
    out = np.zeros(len(names))
    b = config.get("backend") if isinstance(config, Mapping) else config.backend.model_dump()
    if not isinstance(b, Mapping) or b.get("kind") != "dynamixel":
        return out
    sensed = (b.get("ultrasonic") or {}).get("joint")
    servos = b.get("servos") or {}
    tick = x_series_table()["Present Position"].scale  # rad a tick at the shaft
    for i, name in enumerate(names):
        servo = servos.get(name)
        if servo is not None and name != sensed:
            out[i] = abs(float(servo.get("ratio", 1.0))) * tick  # the config's default ratio: 1
    return out


def encoder_tip_sigma(robot, readings: np.ndarray, resolution: np.ndarray, step: float = 1e-6) -> float:
    """The standard deviation (m, the root of the covariance's trace) of the tip the encoders place
    from the settle's ``readings`` (rows of joint values): each joint's median within half a step
    of ``resolution`` (uniform: step/√12; 0 for a joint read exactly) and scattered as its readings
    are (the median's variance, π/2·σ²/n), through the needle's forward kinematics."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    q = np.median(readings, axis=0)
    n = len(readings)
    var = np.asarray(resolution, dtype=float) ** 2 / 12.0 + (np.pi / 2) * readings.var(axis=0) / max(n, 1)
    tip = robot.needle(q).tip
    total = 0.0
    for j in np.flatnonzero(var > 0):
        dq = np.zeros_like(q)
        dq[j] = step
        column = (robot.needle(q + dq).tip - tip) / step  # ∂tip/∂q_j
        total += float(column @ column) * float(var[j])
    return float(np.sqrt(total))


def camera_summary(camera: Optional[dict], encoders: Optional[NeedlePose],
                   target: NeedleTarget, encoder_sigma: float = 0.0) -> Optional[dict]:
    """``trial --json``'s "camera" (mm, degrees), from the record's camera measurement and the
    encoders' settled needle (``encoder_sigma``: its tip's standard deviation, m, from
    :func:`encoder_tip_sigma`); None when the trial had no cameras."""
    if not camera:
        return None
    capture = camera.get("captures", {}).get("insert")
    out = {"tip_deviation_mm": None, "angle_deviation_deg": None, "encoder_gap_mm": None,
           "uncertainty_mm": None, "encoder_uncertainty_mm": None, "flag": None, "tip_mm": None,
           "problem": "no capture at the end of the insertion (the trial stopped before it)"}
    if capture is None:
        return out
    pose = camera_pose(capture, target)
    if pose is None:
        out["problem"] = capture.get("problem") or "the cameras' needle does not cross the skin's plane"
        return out
    sigma = float(np.sqrt(np.trace(np.asarray(capture["covariance_m2"], dtype=float))))
    angle, tilt = angles_of(pose.direction)
    da, dt = np.degrees(angle - target.angle), np.degrees(tilt - target.tilt)
    r = lambda v: round(float(v), 4) + 0.0  # noqa: E731
    out.update({"tip_mm": [r(v * 1e3) for v in pose.tip],
                "tip_deviation_mm": [r(v * 1e3) for v in pose.tip - target.tip],
                "angle_deviation_deg": r(da if abs(da) >= abs(dt) else dt),
                "uncertainty_mm": r(COVERAGE * sigma * 1e3), "problem": ""})
    if encoders is not None:
        gap = float(np.linalg.norm(encoders.tip - pose.tip))
        out["encoder_gap_mm"] = r(gap * 1e3)
        out["encoder_uncertainty_mm"] = r(COVERAGE * encoder_sigma * 1e3)
        out["flag"] = bool(gap > COVERAGE * np.hypot(sigma, encoder_sigma))
    return out


def log_camera(log: TrialLog, robot, target: NeedleTarget, resolution: np.ndarray) -> Optional[dict]:
    """:func:`camera_summary` of a trial from its log alone (the record's measurement, the encoders'
    settled needle and its uncertainty from ``resolution``, :func:`joint_resolution`); None when the
    trial had no cameras. The same figures at the end of a trial, in a comparison and in a campaign."""
    measured = log.metadata.get("camera")
    if not measured:
        return None
    encoders, sigma = None, 0.0
    try:
        q = settled_position(log, "insert")
        rows = log.q[settle_rows(log.time, log.segment, log.segment_names, "insert")]
    except (KeyError, ValueError):  # stopped before the insertion settled: no encoders' needle
        q = None
    if q is not None and np.all(np.isfinite(q)):
        encoders = robot.needle(q)
        sigma = encoder_tip_sigma(robot, rows, resolution)
    return camera_summary(measured, encoders, target, sigma)


def seen_outcome(log: TrialLog, target: NeedleTarget, position_limit_mm: float,
                 angle_limit_deg: float) -> Optional[NeedleOutcome]:
    """The placement the cameras measured at the end of the insertion, against the limits; None
    without a measurement (no cameras, a capture that failed, a trial stopped before it)."""
    capture = (log.metadata.get("camera") or {}).get("captures", {}).get("insert")
    pose = camera_pose(capture, target)
    return None if pose is None else pose_outcome(pose, target, position_limit_mm, angle_limit_deg)
