"""``hilbench robot|fk|ik`` as a script would call them: JSON out, exit 2 with one line on error."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_in_process import invoke as _invoke
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def run(*args: str) -> subprocess.CompletedProcess:
    """``hilbench ARGS`` in its own process: the installed command, start-up and exit code included."""
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=120)


def test_robot_lists_nine_joints():
    """Run as the installed command: the JSON a script reads from the process it starts."""
    out = run("robot", "arc-train", "--json")
    assert out.returncode == 0, out.stderr
    joints = json.loads(out.stdout)["joints"]
    assert [j["name"] for j in joints] == ["train", "theta3", "theta4", "theta5", "theta6",
                                           "theta7", "theta8", "d9", "d10"]
    assert [j["type"] for j in joints].count("prismatic") == 2
    for j in joints:
        assert set(j) == {"name", "type", "lower", "upper", "home"}
        assert j["lower"] <= j["home"] <= j["upper"]


def test_ik_target_1_then_fk_returns_it(tmp_path):
    png = tmp_path / "t1.png"
    out = _invoke("ik", "arc-train", "--x-mm", "0", "--y-mm", "88.2", "--z-mm", "66",
                  "--depth-mm", "30.1", "--angle-deg", "47", "--json", "--render", str(png))
    assert out.exit_code == 0, out.stderr
    sol = json.loads(out.stdout)
    assert png.stat().st_size > 10_000
    assert set(sol["joints"]) == {"train", "theta3", "theta4", "theta5", "theta6", "theta7",
                                  "theta8", "d9", "d10"}
    back = _invoke("fk", "arc-train", "--joints", json.dumps(sol["joints"]), "--json")
    assert back.exit_code == 0, back.stderr
    fk = json.loads(back.stdout)
    assert fk["entry_mm"] == pytest.approx([0.0, 88.2, 66.0], abs=0.01)
    assert fk["angle_deg"] == pytest.approx(47.0, abs=0.01)
    assert fk["depth_mm"] == pytest.approx(30.1, abs=0.01)
    assert fk["tip_mm"] == pytest.approx(sol["tip_mm"], abs=1e-6)


def test_fk_missing_joints_take_home():
    out = _invoke("fk", "arc-train", "--joints", "{}", "--json")
    fk = json.loads(out.stdout)
    assert fk["entry_mm"] == pytest.approx([0.0, 200.0, 100.0], abs=1e-6)  # straight down at home
    assert fk["angle_deg"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("args, words", [
    (["ik", "arc-train", "--x-mm", "0", "--y-mm", "88.2", "--z-mm", "666", "--depth-mm", "30",
      "--angle-deg", "47", "--json"], "out of the arm's reach"),
    (["fk", "arc-train", "--joints", '{"theta9": 1}', "--json"], "theta9"),
    (["fk", "arc-train", "--joints", '{"d9": 5}', "--json"], "d9"),
    (["robot", "delta-bot", "--json"], "known robots"),
])
def test_bad_input_exits_2_with_one_line(args, words):
    out = _invoke(*args)
    assert out.exit_code == 2
    assert out.stdout == ""
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0]


ROBOT_NAMES = ("arc-train", "zerobot", "para-brachy")


def test_robot_without_a_name_lists_every_robot_and_whether_trial_runs_it():
    out = _invoke("robot", "--json")
    assert out.exit_code == 0, out.stderr
    robots = json.loads(out.stdout)["robots"]
    assert set(robots) == set(ROBOT_NAMES)
    assert robots["arc-train"]["trial"]["runs"] is True
    for name in ("zerobot", "para-brachy"):
        assert robots[name]["trial"]["runs"] is False and name in robots[name]["trial"]["why"]


@pytest.mark.parametrize("name", ROBOT_NAMES)
def test_every_robot_answers_robot_fk_ik_and_accuracy(name):
    """One registry: each robot's home needle, pushed 20 mm deeper, is found by IK and reached."""
    joints = json.loads(_invoke("robot", name, "--json").stdout)["joints"]
    fk = _invoke("fk", name, "--json")  # home
    assert fk.exit_code == 0, fk.stderr
    pose = json.loads(fk.stdout)
    depth = pose["depth_mm"] + 20.0
    a, b = np.radians(pose["angle_deg"]), np.radians(pose["tilt_deg"])
    direction = np.array([np.sin(b), np.cos(b) * np.sin(a), -np.cos(b) * np.cos(a)])
    want_tip = np.array(pose["entry_mm"]) + depth * direction
    ik = _invoke("ik", name, "--x-mm", str(pose["entry_mm"][0]), "--y-mm", str(pose["entry_mm"][1]),
                 "--z-mm", str(pose["entry_mm"][2]), "--depth-mm", str(depth),
                 "--angle-deg", str(pose["angle_deg"]), "--tilt-deg", str(pose["tilt_deg"]), "--json")
    assert ik.exit_code == 0, ik.stderr
    back = json.loads(ik.stdout)
    assert list(back["joints"]) == [j["name"] for j in joints]
    assert np.abs(np.array(back["tip_mm"]) - want_tip).max() < 1e-3  # µm
    acc = _invoke("accuracy", name, "--samples", "200", "--json")
    assert acc.exit_code == 0, acc.stderr
    assert json.loads(acc.stdout)["robot"] == name


def test_a_trial_of_a_robot_without_servos_is_refused_saying_why(tmp_path):
    cfg = tmp_path / "zb.yaml"
    text = (Path(__file__).resolve().parents[1] / "hil_configs" / "sim_target1.yaml").read_text()
    cfg.write_text(text.replace("robot: arc-train", "robot: para-brachy"))
    out = _invoke("check", str(cfg))
    assert out.exit_code == 2
    assert "para-brachy" in out.stdout + out.stderr and "no URDF" in out.stdout + out.stderr
