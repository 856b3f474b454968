"""Configs valid field by field but nonsense together are refused at validation, so by `hilbench
check` too, with one line naming the field, before anything is built or moves."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bench.cli.app import app
from bench.config.models import ConfigError, load_trial_config
from bench.core.result import TrialError
from bench.trial.check import check_config
from bench.trial.plan import prepare

REPO = Path(__file__).resolve().parent.parent
SIM = yaml.safe_load((REPO / "hil_configs" / "sim_target1.yaml").read_text())
SERVO_SIM = yaml.safe_load((REPO / "hil_configs" / "sim_target1_servo.yaml").read_text())
LAB = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())


def _with(base: dict, path: str, value) -> dict:
    data = copy.deepcopy(base)
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return data


def _write(tmp_path: Path, data: dict, name: str = "cfg.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data, allow_unicode=True))
    return p


# (base, field, value, what the one line must say)
NONSENSE = [
    (LAB, "backend.servos.theta4.ratio", 1e-4, "backend.servos.theta4: range [-1.5708, 1.5708] through ratio 0.0001"),
    (LAB, "backend.servos.theta4.ratio", 1e-9, "a servo in position mode takes 0 to 4,095"),
    (LAB, "backend.servos.train.ratio", 1e-4, "a servo in extended_position mode takes -1,048,575 to 1,048,575"),
    (LAB, "backend.servos.d10.ratio", -1e-5, "backend.servos.d10:"),
    (LAB, "backend.servos.theta4.offset", 100, "backend.servos.theta4: range [-1.5708, 1.5708] through ratio 1, offset 100"),
    (LAB, "backend.servos.theta5.offset", 1.7, "needs goals of -84 to 1,964 ticks"),
    (LAB, "backend.ultrasonic.joint", "theta4", "backend.ultrasonic.joint: the sensor reads the train's distance"),
    (LAB, "backend.ultrasonic.joint", "nope", "measures 'train' only, not 'nope'"),
    (LAB, "backend.ultrasonic.port", "/dev/ttyUSB0", "backend.ultrasonic.port: /dev/ttyUSB0 is the servo bus's port"),
    (SIM, "backend.start", {"theta4": 1e300}, "backend.start.theta4: 1e+300 rad is outside its limits"),
    (SIM, "backend.start", {"d10": -0.05}, "backend.start.d10: -0.05 m is outside its limits [0, 0.1]"),
    (SIM, "backend.start", {"nope": 0.0}, "backend.start: unknown joint(s) ['nope']"),
    (SERVO_SIM, "backend.start_effort", {"theta4": 1e300}, "backend.start_effort.theta4: 1e+300 N·m is beyond its effort limit ±4.1 N·m"),
    (SERVO_SIM, "backend.start_effort", {"d9": -41.0}, "backend.start_effort.d9: -41 N is beyond"),
    (SERVO_SIM, "backend.start_effort", {"nope": 1}, "backend.start_effort: unknown joint(s) ['nope']"),
    (_with(SIM, "backend.servo_model", "datasheet"), "backend.ultrasonic", {"port": "/dev/null", "joint": "theta3"},
     "measures 'train' only, not 'theta3'"),
]


@pytest.mark.parametrize("base,field,value,says", NONSENSE, ids=[f"{f}={v!r:.30}" for _, f, v, _ in NONSENSE])
def test_check_refuses_semantic_nonsense_naming_the_field(tmp_path, base, field, value, says):
    path = _write(tmp_path, _with(base, field, value))
    results = check_config(path, emulate=True)
    assert [(r.name, r.ok) for r in results] == [("config", False)], results
    assert says in results[0].detail and "\n" not in results[0].detail
    assert "(top level)" not in results[0].detail  # the field is named, not the file's top
    with pytest.raises(ConfigError):
        load_trial_config(path)


def test_the_lab_config_and_a_sane_start_still_pass(tmp_path):
    assert all(r.ok for r in check_config(REPO / "hil_configs" / "lab_real.yaml", emulate=True))
    sane = _with(_with(SERVO_SIM, "backend.start", {"theta4": -0.2, "d10": -1e-5}),  # a tick past 0
                 "backend.start_effort", {"theta4": -1.5, "d9": 3.0})
    assert load_trial_config(_write(tmp_path, sane)).backend.start["theta4"] == -0.2


def test_a_start_outside_the_limits_is_exit_2_before_anything_is_built(tmp_path):
    path = _write(tmp_path, _with(SIM, "backend.start", {"theta4": 2.0}))
    res = CliRunner().invoke(app, ["trial", str(path), "--out", str(tmp_path / "runs")])
    assert res.exit_code == 2
    assert res.output.strip().count("\n") == 0 and "backend.start.theta4: 2 rad is outside its limits" in res.output
    assert not (tmp_path / "runs").exists()


def test_a_misspelt_required_field_names_the_field_meant(tmp_path):
    data = copy.deepcopy(SIM)
    data["target"]["y_nm"] = data["target"].pop("y_mm")
    path = _write(tmp_path, data)
    res = CliRunner().invoke(app, ["trial", str(path), "--out", str(tmp_path / "runs")])
    assert res.exit_code == 2
    line = res.output.strip()
    assert "\n" not in line
    assert "target.y_nm: unknown field; did you mean 'y_mm'? (a required field, missing)" in line
    assert "and 1 more" not in line  # the missing y_mm is the misspelling, not another problem
    out = CliRunner().invoke(app, ["check", str(path), "--json"])
    report = json.loads(out.stdout.splitlines()[0])
    assert out.exit_code == 2 and "did you mean 'y_mm'?" in report["reason"]
    assert "did you mean 'y_mm'?" in report["checks"][0]["detail"]
    top = copy.deepcopy(LAB)
    top["backend"]["prot"] = top["backend"].pop("port")
    with pytest.raises(ConfigError, match=r"prot: unknown field; did you mean 'port'\?"):
        load_trial_config(_write(tmp_path, top, "lab.yaml"))


@pytest.mark.parametrize("field,value,says", [
    ("y_mm", 450.0, "Y 450 mm being 50.0 mm beyond its right edge"),
    ("y_mm", -30.0, "Y -30 mm being 30.0 mm beyond its left edge"),
    ("x_mm", 950.0, "X 950 mm being 150.0 mm beyond its far end"),
    ("z_mm", -12.5, "the entry point is 12.5 mm below the bed top"),
])
def test_a_target_off_the_bed_says_so_and_by_how_much(tmp_path, field, value, says):
    path = _write(tmp_path, _with(SIM, f"target.{field}", value))
    with pytest.raises(TrialError, match="off the bed|below the bed top") as err:
        prepare(load_trial_config(path))
    assert says in str(err.value) and "gantry" not in str(err.value).split("(")[0]
    out = CliRunner().invoke(app, ["check", str(path), "--json"])
    report = json.loads(out.stdout.splitlines()[0])
    assert out.exit_code == 2 and says in report["reason"]
    assert "gantry_clearance" not in report["reason"]


def test_an_off_bed_target_that_once_read_as_a_gantry_trip(tmp_path):
    """Y 480 mm at Z 20 mm: refused before as d10 being '20.0 mm from the gantry (margin 20.0 mm)'."""
    data = _with(_with(SIM, "target.y_mm", 480.0), "target.z_mm", 20.0)
    with pytest.raises(TrialError) as err:
        prepare(load_trial_config(_write(tmp_path, data)))
    assert "off the bed, Y 480 mm being 80.0 mm beyond its right edge" in str(err.value)


def test_a_calibration_whose_zero_puts_a_joint_beyond_its_servo_is_refused(tmp_path):
    cal = {"config_name": "lab-target1", "robot": "arc-train", "created": "2026-01-01T00:00:00+00:00",
           "servos": {"theta4": {"offset": 2.5, "change": 2.5}}}
    (tmp_path / "cal.yaml").write_text(yaml.safe_dump(cal))
    path = _write(tmp_path, _with(LAB, "calibration", str(tmp_path / "cal.yaml")))
    with pytest.raises(ConfigError, match="theta4: range .* offset 2.5 needs goals"):
        load_trial_config(path)
