"""Zerobot (seed 001): modified-DH model against eq 3 and PyBullet, IK, remote-centre motion."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_in_process import invoke as _invoke
from bench.kinematics.dh import DHRow, dh_transform, joint_split, mdh_transform
from bench.kinematics.needle import NeedleTarget, UnreachableError, needle_direction
from bench.kinematics.zerobot import DEG, ZerobotParams, ZerobotRobot, eq3_tip_pose
from bench.scene.room import URDF_DIR, generated_files

HILBENCH = str(Path(sys.executable).with_name("hilbench"))


@pytest.fixture(scope="module")
def zerobot() -> ZerobotRobot:
    return ZerobotRobot()


def rot(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    T = np.eye(4)
    i, j = {"x": (1, 2), "z": (0, 1)}[axis]
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


def trans(axis: str, d: float) -> np.ndarray:
    T = np.eye(4)
    T["xyz".index(axis), 3] = d
    return T


def test_modified_dh_is_eq1_and_standard_rows_are_unchanged():
    rng = np.random.default_rng(3)
    for theta, d, a, alpha in rng.uniform(-2, 2, (20, 4)):
        craig = rot("x", alpha) @ trans("x", a) @ rot("z", theta) @ trans("z", d)
        assert np.allclose(mdh_transform(np.array(theta), np.array(d), a, alpha), craig, atol=1e-15)
        std = rot("z", theta) @ trans("z", d) @ trans("x", a) @ rot("x", alpha)
        assert np.allclose(dh_transform(np.array(theta), np.array(d), a, alpha), std, atol=1e-15)
    row = DHRow("j", "revolute", 0.3, 0.1, 0.2, 0.4, -1, 1, 0, 1, 1)
    assert row.convention == "standard"
    lead, trail = joint_split(DHRow("j", "revolute", 0.3, 0.1, 0.2, 0.4, -1, 1, 0, 1, 1, "modified"))
    assert np.allclose(trail, np.eye(4))
    assert np.allclose(lead, mdh_transform(np.array(0.3), np.array(0.1), 0.2, 0.4))
    with pytest.raises(ValueError, match="convention 'craig'"):
        DHRow("j", "revolute", 0, 0, 0, 0, -1, 1, 0, 1, 1, "craig")  # type: ignore[arg-type]


@pytest.mark.parametrize("alpha3", [90.0, -90.0])
def test_chain_reproduces_eq3(alpha3):
    p = ZerobotParams(alpha3=alpha3 * DEG)
    robot = ZerobotRobot(p)
    Q = np.random.default_rng(1).uniform(robot.chain.lower, robot.chain.upper, (300, 6))
    assert np.max(np.abs(robot.tip_pose(Q) - eq3_tip_pose(Q, p))) < 1e-12


def test_home_puts_the_needle_down_in_the_scan_plane(zerobot):
    pose = zerobot.needle(zerobot.chain.home)
    assert pose.tip == pytest.approx([0.0, 0.2, 0.1], abs=1e-12)
    assert pose.direction == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    # q4 is the insertion angle and -q5 the tilt (alpha3 = +90 deg)
    q = zerobot.chain.home.copy()
    q[3], q[4] = 0.3, -0.2
    a, t = zerobot.angles(q)
    assert (a, t) == pytest.approx((0.3, 0.2), abs=1e-12)
    # the end-effector beam is l1 = 900 mm long along X (the paper's ~900 mm)
    F = zerobot.chain.frames(zerobot.chain.home)
    assert F[4][:3, 3] - F[3][:3, 3] == pytest.approx([0.9, 0.0, 0.0], abs=1e-12)


def test_dh_fk_equals_pybullet_link_poses(zerobot):
    """200 random configurations: every DH frame equals PyBullet's URDF link frame (modified
    DH: the link frame is the DH frame) and the needle tip its tool frame, to 1e-6."""
    from drivers.quiet import quiet_pybullet

    pb = quiet_pybullet()
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(URDF_DIR / "zerobot.urdf"), useFixedBase=True, physicsClientId=c)
        chain = zerobot.chain
        assert pb.getNumJoints(body, physicsClientId=c) == 7
        rng = np.random.default_rng(7)
        worst = 0.0
        for _ in range(200):
            q = rng.uniform(chain.lower, chain.upper)
            for j, v in enumerate(q):
                pb.resetJointState(body, j, float(v), physicsClientId=c)
            F = chain.frames(q)
            ref = list(F[1:]) + [F[-1] @ chain.tool]
            for j, T in enumerate(ref):
                st = pb.getLinkState(body, j, computeForwardKinematics=True, physicsClientId=c)
                L = np.eye(4)
                L[:3, :3] = np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)
                L[:3, 3] = st[4]
                worst = max(worst, float(np.max(np.abs(L - T))))
        assert worst < 1e-6
    finally:
        pb.disconnect(c)


def test_fk_ik_fk_round_trip_with_tilt(zerobot):
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(500):
        q = rng.uniform(zerobot.chain.lower, zerobot.chain.upper)
        pose = zerobot.needle(q)
        target = NeedleTarget(pose.entry, pose.depth, pose.angle, pose.out_of_plane)
        q_back = zerobot.ik(target)
        back = zerobot.needle(q_back)
        worst = max(worst, float(np.max(np.abs(q_back - q))),
                    float(np.max(np.abs(back.tip - pose.tip))))
    assert worst < 1e-9


@pytest.mark.parametrize("target, words", [
    (NeedleTarget(np.array([0.0, 0.2, 0.1]), 0.15, 0.0), "q6's stroke"),
    (NeedleTarget(np.array([0.0, 0.2, 0.1]), 0.02, 70 * DEG), "q4"),
    (NeedleTarget(np.array([0.0, 0.2, 0.1]), 0.02, 0.0, 40 * DEG), "q5"),
    (NeedleTarget(np.array([0.0, 0.2, 0.9]), 0.02, 0.0), "q1 (the vertical stage)"),
    (NeedleTarget(np.array([0.5, 0.2, 0.1]), 0.02, 0.0), "q2 (the X stage)"),
    (NeedleTarget(np.array([0.0, 0.9, 0.1]), 0.02, 0.0), "q3 (the Y stage)"),
    (NeedleTarget(np.array([0.0, np.nan, 0.1]), 0.02, 0.0), "not finite"),
])
def test_unreachable_names_the_failed_constraint(zerobot, target, words):
    with pytest.raises(UnreachableError, match=words.replace("(", r"\(").replace(")", r"\)")):
        zerobot.ik(target)


def test_remote_centre_keeps_the_tip_fixed(zerobot):
    """Section 2.2: re-orienting about the tip moves q1-q3 so the tip stays put (1e-9 m)."""
    rng = np.random.default_rng(5)
    done = 0
    for _ in range(400):
        q = rng.uniform(zerobot.chain.lower, zerobot.chain.upper)
        angle, tilt = rng.uniform(-50, 50) * DEG, rng.uniform(-25, 25) * DEG
        try:
            q2 = zerobot.remote_centre(q, angle, tilt)
        except UnreachableError as e:
            assert "stroke" in str(e)
            continue
        tip0, tip1 = zerobot.tip_pose(q)[:3, 3], zerobot.tip_pose(q2)[:3, 3]
        assert np.max(np.abs(tip1 - tip0)) < 1e-9
        assert zerobot.tip_pose(q2)[:3, 2] == pytest.approx(needle_direction(angle, tilt), abs=1e-12)
        assert q2[5] == q[5]
        done += 1
    assert done > 200
    path = zerobot.remote_centre_path(zerobot.chain.home, np.linspace(-0.4, 0.4, 9), 0.1)
    tips = zerobot.tip_pose(path)[:, :3, 3]
    assert np.max(np.abs(tips - zerobot.tip_pose(zerobot.chain.home)[:3, 3])) < 1e-9


def test_urdf_is_generated_and_loads_quietly():
    assert (URDF_DIR / "zerobot.urdf").read_text() == generated_files()["zerobot.urdf"]
    code = ("import pybullet as pb\nc = pb.connect(pb.DIRECT)\n"
            f"assert pb.loadURDF(r'{URDF_DIR}/zerobot.urdf', useFixedBase=True) >= 0\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    noise = [line for line in (out.stdout + out.stderr).splitlines()
             if line.strip() and not line.startswith("pybullet build time")]
    assert noise == []


def test_cli_robot_ik_fk_with_tilt():
    out = _invoke("robot", "zerobot", "--json")
    assert out.exit_code == 0, out.stderr
    joints = json.loads(out.stdout)["joints"]
    assert [j["name"] for j in joints] == ["q1", "q2", "q3", "q4", "q5", "q6"]
    assert [j["type"] for j in joints] == ["prismatic"] * 3 + ["revolute"] * 2 + ["prismatic"]
    out = _invoke("ik", "zerobot", "--x-mm", "0", "--y-mm", "150", "--z-mm", "80",
                  "--depth-mm", "40", "--angle-deg", "20", "--tilt-deg", "-10", "--json")
    assert out.exit_code == 0, out.stderr
    sol = json.loads(out.stdout)
    assert sol["joints"]["q4"] == pytest.approx(20 * DEG) and sol["joints"]["q5"] == pytest.approx(10 * DEG)
    back = _invoke("fk", "zerobot", "--joints", json.dumps(sol["joints"]), "--json")
    fk = json.loads(back.stdout)
    assert fk["entry_mm"] == pytest.approx([0.0, 150.0, 80.0], abs=1e-6)
    assert fk["tip_mm"] == pytest.approx(sol["tip_mm"], abs=1e-6)
    # the installed command in its own process
    bad = subprocess.run([HILBENCH, "ik", "zerobot", "--x-mm", "0", "--y-mm", "150", "--z-mm", "800",
                          "--depth-mm", "40", "--angle-deg", "20", "--json"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "q1" in bad.stderr and bad.stdout == ""
