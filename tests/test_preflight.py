"""Checks before anything moves: `hilbench check`, and the same checks at the start of `trial`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_in_process import invoke as _invoke
from bench.config.models import load_trial_config
from bench.core.result import TrialError
from bench.kinematics.registry import get_robot
from bench.trial.plan import prepare
from bench.trial.preflight import needle_direction_problem

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "hil_configs" / "sim_target1.yaml"
LAB = REPO / "hil_configs" / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def hilbench(*args: str) -> subprocess.CompletedProcess:
    """``hilbench ARGS`` in its own process: the installed command, start-up and exit code included."""
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=120)


def variant(tmp_path: Path, section: str, **values) -> Path:
    """Target 1's sim config with some values of one section changed."""
    data = yaml.safe_load(SIM.read_text())
    data.setdefault(section, {}).update(values)
    p = tmp_path / "variant.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_check_passes_the_target1_config_and_names_what_it_checked():
    out = hilbench("check", str(SIM), "--json")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["ok"] and report["reason"] == ""
    assert [c["name"] for c in report["checks"]] == ["config", "target and plan"]
    assert "47.0°" in report["checks"][1]["detail"]  # seed 000's Target 1 angle
    assert out.stderr == ""


def test_check_of_a_real_rig_config_names_the_missing_ports():
    out = _invoke("check", str(LAB))
    assert out.exit_code == 2
    assert "servo port /dev/ttyUSB0 not found" in out.stdout
    assert len(out.stderr.strip().splitlines()) == 1
    rehearsal = _invoke("check", str(LAB), "--emulate", "--json")  # checks only: no rig is started
    assert rehearsal.exit_code == 0 and json.loads(rehearsal.stdout)["ok"]


def test_a_planned_path_into_the_gantry_margin_is_refused_by_check_and_by_trial(tmp_path):
    """A 300 mm margin (a typo for 30) puts the gantry within reach of the planned path."""
    cfg = variant(tmp_path, "safety", gantry_margin_mm=300)
    out = _invoke("check", str(cfg), "--json")
    assert out.exit_code == 2
    reason = json.loads(out.stdout)["reason"]
    assert "planned path trips the gantry_clearance interlock" in reason and "nothing moved" in reason
    runs = tmp_path / "runs"
    trial = _invoke("trial", str(cfg), "--out", str(runs))
    assert trial.exit_code == 2
    assert len(trial.stderr.strip().splitlines()) == 1 and "gantry_clearance" in trial.stderr
    assert "Traceback" not in trial.stderr
    assert not runs.exists() or not any(runs.iterdir()), "a refused trial writes no run"


def test_the_planned_path_is_replayed_through_the_trials_own_interlocks():
    cfg = load_trial_config(SIM)
    prepare(cfg)  # 20 mm: the seed's margin clears Target 1's path
    tight = cfg.model_copy(update={"safety": cfg.safety.model_copy(update={"gantry_margin_mm": 300.0})})
    with pytest.raises(TrialError, match="gantry_clearance"):
        prepare(tight)
    off = tight.model_copy(update={"safety": tight.safety.model_copy(update={"enabled": False})})
    prepare(off)  # interlocks disabled: nothing to replay the path through


@pytest.mark.parametrize("joint,value", [("train", -2.0), ("theta3", 2.0), ("theta6", -2.0)])
def test_a_needle_pointing_up_from_the_bed_is_refused(joint, value):
    robot = get_robot("arc-train")
    q = robot.chain.home.copy()
    assert needle_direction_problem(robot, q, 0.0) is None  # home: straight down
    q[robot.joint_names.index(joint)] = value
    assert robot.needle(q).direction[2] > 0
    problem = needle_direction_problem(robot, q, 147.0)
    assert problem is not None and "147°" in problem and "down into the bed" in problem


def test_check_refuses_what_the_schema_refuses_with_one_line(tmp_path):
    cfg = variant(tmp_path, "target", angle_deg=147.0)
    out = _invoke("check", str(cfg))
    assert out.exit_code == 2
    assert "angle_deg" in out.stdout and "FAIL" in out.stdout
    assert len(out.stderr.strip().splitlines()) == 1


def test_preflight_is_cheap_once_the_geometry_is_built():
    import time

    cfg = load_trial_config(SIM)
    prepare(cfg)
    t0 = time.process_time()  # processor time: what preparing costs, whatever else the machine runs
    for _ in range(5):
        prepare(cfg)
    assert (time.process_time() - t0) / 5 < 0.1  # a campaign pays this per trial
    assert np.isfinite(cfg.control_period)
