"""Hostile configs are refused by `hilbench trial` before anything is built: exit 2, one line
on stderr, no traceback, no run directory, well inside a second of processor time (what the
config costs, not what the machine's other work does to the wall clock); the shipped configs
still load."""

from __future__ import annotations

import copy
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bench.cli.app import app
from cli_in_process import invoke
from bench.config.models import load_trial_config, read_yaml_mapping

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
SIM = yaml.safe_load((REPO / "hil_configs" / "sim_target1.yaml").read_text())
LAB = yaml.safe_load((REPO / "hil_configs" / "lab_real.yaml").read_text())


def _set(base: dict, path: str, value) -> dict:
    data = copy.deepcopy(base)
    keys = path.split(".")
    node = data
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    node[keys[-1]] = value
    return data


INF, NAN = float("inf"), float("nan")
SIM_MUTATIONS = [
    ("plan.settle_s", 1.0e9), ("plan.settle_s", -1.0), ("plan.settle_s", INF),
    ("plan.velocity_scale", 1.0e-9), ("plan.velocity_scale", 0.0), ("plan.velocity_scale", 2.0),
    ("plan.velocity_scale", NAN), ("plan.acceleration_scale", INF), ("plan.acceleration_scale", 0.0),
    ("plan.acceleration_scale", 1e12), ("plan.jerk_scale", -5.0), ("plan.jerk_scale", NAN),
    ("plan.trajectory", "teleport"), ("plan.retract", "maybe"), ("plan", [1, 2, 3]),
    ("name", "../../../x"), ("name", "a/b"), ("name", ".hidden"), ("name", "x" * 200),
    ("name", "nul\x00byte"), ("name", ""), ("name", 12),
    ("seed", -1), ("seed", 2**64), ("seed", 10**40), ("seed", 1.5),
    ("control_hz", 0), ("control_hz", -500), ("control_hz", 1e9), ("control_hz", 300),
    ("control_hz", INF),
    ("target.x_mm", NAN), ("target.y_mm", INF), ("target.z_mm", -1e30), ("target.depth_mm", -3.0),
    ("target.depth_mm", 5000.0), ("target.angle_deg", 147.0), ("target.angle_deg", NAN),
    ("target.tilt_deg", 400.0), ("target.angle_deg", "forty-seven"),
    ("acceptance.position_mm", 0.0), ("acceptance.angle_deg", INF),
    ("safety.gantry_margin_mm", -20.0), ("safety.tracking_error_deg", 0.0),
    ("safety.velocity_factor", NAN), ("safety.on_trip", "explode"), ("safety.gantry_lookahead_s", 1e6),
    ("backend.physics_hz", 0.0), ("backend.physics_hz", 1e9), ("backend.kind", "ros"),
    ("backend.position_gain", 5.0), ("backend.joints", {"theta99": {"effort": 1.0}}),
    ("backend.joints", {"theta4": {"effort": INF}}),
    ("faults", [{"name": "deadband", "joints": "all", "tol_deg": NAN}]),
    ("faults", [{"name": "no-such-fault"}]), ("faults", [{"name": "deadband"}] * 1000),
    ("emulator.seed", -3), ("emulator.ultrasonic_rate_hz", 1e9),
    ("plan.velosity_scale", 0.5), ("robot", "zerobot-9000"), ("urdf_dir", "no/such/dir"),
    ("backend.start", {"theta4": 1e300}), ("backend.start", {"d10": -0.5}), ("backend.start", {"nope": 0.0}),
    ("target.y_mm", 450.0), ("target.y_mm", -30.0), ("target.z_mm", -15.0),
]
LAB_MUTATIONS = [
    ("backend.baud", 123456), ("backend.servos.theta4.offset", INF),
    ("backend.servos.theta4.ratio", 0.0), ("backend.servos.theta4.ratio", NAN),
    ("backend.servos.theta4.id", 300), ("backend.servos.theta4.model", "XM999"),
    ("backend.servos.theta4.position_p", 10**6), ("backend.ultrasonic.baud", 7),
    ("backend.ultrasonic.stale_after_s", INF), ("backend.timeout_ms", -1.0),
    ("backend.retries", 10**6), ("backend.return_delay_us", -2),
    # each field valid alone, nonsense together: refused at validation, before anything moves
    ("backend.servos.theta4.ratio", 1e-4), ("backend.servos.theta4.ratio", 1e-9),
    ("backend.servos.train.ratio", 1e-4), ("backend.servos.d9.ratio", -1e-6),
    ("backend.servos.theta4.offset", 100.0), ("backend.servos.d10.offset", 99.0),
    ("backend.ultrasonic.joint", "theta4"), ("backend.ultrasonic.port", "/dev/ttyUSB0"),
]


def _cases() -> list[tuple[str, str]]:
    cases = [(f"sim {k}={v!r:.40}", yaml.safe_dump(_set(SIM, k, v), allow_unicode=True))
             for k, v in SIM_MUTATIONS]
    cases += [(f"lab {k}={v!r:.40}", yaml.safe_dump(_set(LAB, k, v))) for k, v in LAB_MUTATIONS]
    good = yaml.safe_dump(SIM)
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
        f"*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
        f"*{chr(97 + i)}]\n" for i in range(9))
    cases += [
        ("alias bomb in faults", good + "faults:\n  - name: deadband\n    joints: *j\n"
                                        "aliases:\n" + "".join("  " + ln + "\n" for ln in bomb.splitlines())),
        ("billion laughs", bomb),
        ("deep nesting", "name: x\nemulator: " + "[" * 5000 + "]" * 5000 + "\n"),
        ("duplicate key", good + "name: other\n"),
        ("huge integer", good.replace("seed: 0", "seed: " + "9" * 5000)),
        ("not a mapping", "- just\n- a list\n"),
        ("empty file", ""),
        ("broken yaml", "name: [unclosed\n"),
        ("tab soup", "name:\t\t- : :\n"),
        ("python object tag", good + "evil: !!python/object/apply:os.system ['true']\n"),
    ]
    return cases


CASES = _cases()


def test_there_are_at_least_fifty_hostile_configs():
    assert len(CASES) >= 50


@pytest.mark.parametrize("label,text", CASES, ids=[c[0] for c in CASES])
def test_hostile_config_is_refused_with_one_line(tmp_path, label, text):
    cfg = tmp_path / "hostile.yaml"
    cfg.write_bytes(text.encode("utf-8", "surrogatepass"))
    out = tmp_path / "runs"
    t0 = time.process_time()  # this process's processor time: the same on a loaded machine
    res = CliRunner().invoke(app, ["trial", str(cfg), "--out", str(out)])
    elapsed = time.process_time() - t0
    assert res.exit_code == 2, (label, res.output, res.exception)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output and len(lines[0]) < 400
    assert not out.exists()  # nothing written, nothing moved
    assert elapsed < 1.0, f"{label}: refused after {elapsed:.2f} s of processor time"


@pytest.mark.parametrize("raw,why", [
    (b"name: \xff\xfe\n", "not UTF-8 text"),
    (b"name: a\x00b\n", "control character U+0000"),
])
def test_bytes_that_are_not_text_are_refused_by_the_real_cli(tmp_path, raw, why):
    cfg = tmp_path / "bytes.yaml"
    cfg.write_bytes(raw)
    res = subprocess.run([HILBENCH, "trial", str(cfg), "--out", str(tmp_path / "runs")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and why in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "runs").exists()


def test_emulated_rig_with_an_impossible_baud_names_the_reason(tmp_path):
    cfg = tmp_path / "lab.yaml"
    cfg.write_text(yaml.safe_dump(_set(LAB, "backend.baud", 123456)))
    # refused while the config loads, before any rig starts
    res = invoke("trial", str(cfg), "--emulate")
    assert res.exit_code == 2 and "baud 123456 is not an X-series rate" in res.stderr


def test_messages_name_the_field_and_suggest_the_spelling(tmp_path):
    cfg = tmp_path / "typo.yaml"
    cfg.write_text(yaml.safe_dump(_set(SIM, "plan.velosity_scale", 0.5)))
    res = CliRunner().invoke(app, ["trial", str(cfg)])
    assert "plan.velosity_scale: unknown field; did you mean 'velocity_scale'?" in res.output
    dup = tmp_path / "dup.yaml"
    dup.write_text("name: a\nseed: 1\nname: b\n")
    with pytest.raises(ValueError, match="line 3: duplicate key 'name' \\(first on line 1\\)"):
        read_yaml_mapping(dup)


@pytest.mark.parametrize("path", sorted((REPO / "hil_configs").glob("*.yaml")))
def test_every_shipped_config_still_loads(path):
    assert load_trial_config(path).name
