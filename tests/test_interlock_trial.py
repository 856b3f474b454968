"""Interlocks in a running trial: a plan aimed through the CT gantry halts outside the margin."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.core.log import TrialLog
from bench.kinematics.arc_train import ArcTrainRobot
from bench.scene.contact import GantryContact

HILBENCH = str(Path(sys.executable).with_name("hilbench"))

# An entry point off the bed's left edge, low: the IK solution puts the needle
# carriage into the lower-left part of the gantry's bore (exact distance < 0).
INTO_GANTRY = {"name": "into-gantry", "robot": "arc-train", "control_hz": 500,
               "target": {"x_mm": -57.6, "y_mm": -166.9, "z_mm": -64.2, "depth_mm": 20.0,
                          "angle_deg": -3.8},
               # the run-time interlock is what is tested here: no refusal before moving
               "safety": {"refuse_planned_trips": False}}


def test_target_really_is_inside_the_gantry():
    robot = ArcTrainRobot()
    from bench.config.models import TrialConfig
    from bench.core.result import TrialError
    from bench.trial.plan import prepare

    prep = prepare(TrialConfig.model_validate(INTO_GANTRY))
    report = GantryContact(robot, 0.020).check(prep.q_entry)
    assert report.contact and report.distance <= 0.0  # touching or through the gantry
    refused = {**INTO_GANTRY, "safety": {}}
    # by default it never starts: its entry point lies off the bed, and the refusal says so
    with pytest.raises(TrialError, match="off the bed, Y -166.9 mm being 166.9 mm beyond its left edge"):
        prepare(TrialConfig.model_validate(refused))


def test_plan_through_the_gantry_halts_outside_the_margin_and_holds(tmp_path):
    cfg = tmp_path / "into_gantry.yaml"
    cfg.write_text(yaml.safe_dump(INTO_GANTRY))
    out = subprocess.run([HILBENCH, "trial", str(cfg), "--out", str(tmp_path / "runs")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 1, out.stderr  # the trial fails, and says why in one line ...
    assert out.stderr.strip().startswith("trial failed: stopped early: interlock gantry_clearance:")
    assert out.stderr.strip().count("\n") == 0
    run = next((tmp_path / "runs").iterdir())
    log = TrialLog.load(run / "trial.npz")  # ... and nothing is lost
    trips = [e for e in log.events if e.kind == "interlock"]
    assert len(trips) == 1 and trips[0].message.startswith("gantry_clearance:")
    assert any(e.kind == "hold" for e in log.events)
    md = (run / "report.md").read_text()
    assert "stopped early: interlock gantry_clearance" in md and "| interlock |" in md

    robot = ArcTrainRobot()
    exact = GantryContact(robot, 0.020)
    distance = np.array([exact.check(q).distance for q in log.q])
    one_period = np.max(np.abs(np.diff(distance)))  # the most one control period moved it
    assert distance.min() >= 0.020 - one_period
    # it holds: after the trip the robot comes to rest where it stopped
    after = log.time >= trips[0].time
    assert np.max(np.abs(log.qd[-1])) < 1e-3
    assert np.max(np.abs(log.q[after][-1] - log.q[after][0])) < 2e-3
