"""The needle as the cameras saw it (bench.cameras), beside the encoders' (forward kinematics).

The record keeps what was measured (``log.metadata["camera"]``); this turns the capture at the end
of the insertion into the trial's camera figures, the same at the end of a trial and later:
the tip's deviation from the target, the needle's angle, the gap between the encoders' tip and
the cameras', the uncertainty, and the flag: a gap beyond what the uncertainty explains.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from bench.kinematics.needle import NeedlePose, NeedleTarget, angles_of, pose_from_axis

__all__ = ["COVERAGE", "camera_pose", "camera_summary"]

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


def camera_summary(camera: Optional[dict], encoders: Optional[NeedlePose],
                   target: NeedleTarget) -> Optional[dict]:
    """``trial --json``'s "camera" (mm, degrees), from the record's camera measurement and the
    encoders' settled needle; None when the trial had no cameras."""
    if not camera:
        return None
    capture = camera.get("captures", {}).get("insert")
    out = {"tip_deviation_mm": None, "angle_deviation_deg": None, "encoder_gap_mm": None,
           "uncertainty_mm": None, "flag": None, "tip_mm": None,
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
        out["flag"] = bool(gap > COVERAGE * sigma)
    return out
