"""Seed 001's contact experiment in simulation: the paper's 64 trials, all judged right."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from bench.contact.protocol import DISTANCES, POINTS, POSTURES, markdown_report, run_protocol

HILBENCH = str(Path(sys.executable).with_name("hilbench"))


@pytest.fixture(scope="module")
def result():
    return run_protocol()


def test_the_trial_grid_is_the_papers(result):
    assert len(result.trials) == 64
    per_point = Counter(t.point for t in result.trials)
    assert per_point == {"P1": 24, "P2": 16, "P3": 24}  # Tables 2, 3, 4
    axes = Counter((t.point, t.axis) for t in result.trials)
    assert axes == {("P1", "Y"): 12, ("P1", "Z"): 12, ("P2", "X"): 4, ("P2", "Z"): 12,
                    ("P3", "Y"): 12, ("P3", "Z"): 12}
    assert {(t.q4_deg, t.q5_deg) for t in result.trials if t.axis == "X"} == {(0, 15), (30, 15)}
    assert {(t.q4_deg, t.q5_deg) for t in result.trials} == set(POSTURES)
    assert Counter(t.target for t in result.trials) == {DISTANCES[0]: 32, DISTANCES[1]: 32}


def test_all_64_are_judged_right(result):
    assert result.summary() == {"trials": 64, "correct": 64}
    for t in result.trials:
        assert t.caliper == pytest.approx(t.target, abs=1e-7)  # the caliper hit its mark
        assert abs(t.detected - t.caliper) < 0.002  # mesh vs smooth gantry
        assert t.clearance <= t.detected  # the interlock's bound stays below the exact test
        assert t.contact == (t.target < t.margin)


def test_postures_and_approaches_are_as_stated(result):
    from bench.kinematics.zerobot import ZerobotRobot

    robot = ZerobotRobot()
    for t in result.trials:
        q = np.array(t.q)
        assert np.degrees(q[3]) == pytest.approx(t.q4_deg) and np.degrees(q[4]) == pytest.approx(t.q5_deg)
        assert np.all(q >= robot.chain.lower) and np.all(q <= robot.chain.upper)
    # along one approach, the two distances differ by a move along that axis only
    for point, approaches in POINTS.items():
        for a in approaches:
            for i in a.postures:
                q4, q5 = POSTURES[i]
                pair = [t for t in result.trials if (t.point, t.axis, t.q4_deg, t.q5_deg) ==
                        (point, a.axis, q4, q5)]
                tips = [robot.tip_pose(np.array(t.q))[:3, 3] for t in pair]
                step = tips[1] - tips[0]
                assert np.linalg.norm(np.cross(step, a.direction)) < 1e-9
                assert step @ a.direction > 0.005  # moved on towards the gantry


def test_report_tables(result):
    md = markdown_report(result)
    assert md.count("| q4 [deg] | q5 [deg] |") == 3
    assert "**Total: 64 of 64 correct** (real robot: 57 of 64)" in md
    assert md.count("| - | - |") == 4  # Table 3: no X approach for four postures
    rows = result.table("P2")
    assert rows[0] == ["0", "0", "-", "-", "✓", "✓"]


def test_cli_json_and_report(tmp_path):
    out = subprocess.run([HILBENCH, "contact-protocol", "zerobot", "--json", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {"trials": 64, "correct": 64}
    assert out.stdout.count("\n") == 1
    assert "Point P3" in (tmp_path / "report.md").read_text()
    bad = subprocess.run([HILBENCH, "contact-protocol", "arc-train", "--json"], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and "zerobot" in bad.stderr and bad.stdout == ""
