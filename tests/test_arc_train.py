"""The arc-and-train robot of seed 000: DH model, the arc mapping, IK, and the URDF."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from bench.kinematics.arc_train import (
    DEG,
    TARGET_1,
    ArcTrainParams,
    NeedleTarget,
    UnreachableError,
    epsilon_for_target_y,
    epsilon_from_d2,
    epsilon_from_omega,
    train_pose,
)
from bench.kinematics.dh import joint_split
from bench.scene.room import URDF_DIR, generated_files


def constrained_config(rng, p: ArcTrainParams) -> np.ndarray:
    """A random configuration obeying eqs 7-9 (theta3 = 0, theta4 = theta7, theta5 = -theta6)."""
    lim = p.revolute_limit
    t6, t7, t8 = rng.uniform(-lim, lim, 3)
    return np.array([rng.uniform(0, p.arc_span), 0.0, t7, -t6, t6, t7, t8,
                     rng.uniform(0, p.d9_stroke), rng.uniform(0, p.d10_stroke)])


def angle_between(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))


def test_dh_fk_equals_pybullet_link_poses(arc_train):
    """200 random configurations within limits: needle tip and axis to 1e-6 m / 1e-6 rad,
    and every DH frame equals PyBullet's link frame times the row's trailing transform."""
    from drivers.quiet import quiet_pybullet

    pb = quiet_pybullet()
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(URDF_DIR / "arc_train.urdf"), useFixedBase=True, physicsClientId=c)
        chain = arc_train.chain
        trails = [joint_split(r)[1] for r in chain.rows]
        rng = np.random.default_rng(7)
        worst_pos = worst_ang = worst_frame = 0.0
        for _ in range(200):
            q = rng.uniform(chain.lower, chain.upper)
            for j, v in enumerate(q):
                pb.resetJointState(body, j, float(v), physicsClientId=c)
            frames = chain.frames(q)
            tool = frames[-1] @ chain.tool
            st = pb.getLinkState(body, len(q), computeForwardKinematics=True, physicsClientId=c)
            R = np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)
            worst_pos = max(worst_pos, float(np.max(np.abs(np.array(st[4]) - tool[:3, 3]))))
            worst_ang = max(worst_ang, angle_between(R[:, 2], tool[:3, 2]))
            for j in range(len(q)):
                st = pb.getLinkState(body, j, computeForwardKinematics=True, physicsClientId=c)
                L = np.eye(4)
                L[:3, :3] = np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)
                L[:3, 3] = st[4]
                worst_frame = max(worst_frame, float(np.max(np.abs(L @ trails[j] - frames[j + 1]))))
        assert worst_pos < 1e-6
        assert worst_ang < 1e-6
        assert worst_frame < 1e-6
    finally:
        pb.disconnect(c)


def test_target_1_reachable_and_round_trips(arc_train):
    q = arc_train.ik(TARGET_1)
    pose = arc_train.needle(q)
    assert np.max(np.abs(pose.entry - TARGET_1.entry)) < 1e-5  # 0.01 mm
    assert np.max(np.abs(pose.tip - TARGET_1.tip)) < 1e-5
    assert abs(pose.angle - TARGET_1.angle) < 0.01 * DEG
    assert pose.depth == pytest.approx(0.0301, abs=1e-5)
    # eqs 7-9 hold in the answer, and the needle stays in its axial plane
    assert q[1] == 0.0 and q[2] == q[5] and q[3] == -q[4]
    assert abs(pose.out_of_plane) < 1e-12
    # Target 1 is solved in closed form at the train position of eq 11
    assert q[0] == pytest.approx(epsilon_for_target_y(0.0882))


def test_fk_ik_fk_round_trip_500_targets(arc_train):
    rng = np.random.default_rng(11)
    worst = 0.0
    worst_angle = 0.0
    for _ in range(500):
        pose = arc_train.needle(constrained_config(rng, arc_train.params))
        target = NeedleTarget(pose.entry, pose.depth, pose.angle)
        back = arc_train.needle(arc_train.ik(target))
        worst = max(worst, float(np.max(np.abs(back.entry - pose.entry))),
                    float(np.max(np.abs(back.tip - pose.tip))), abs(back.depth - pose.depth))
        worst_angle = max(worst_angle, abs(back.angle - pose.angle))
    assert worst < 1e-5
    assert worst_angle < 0.01 * DEG


def test_targets_outside_workspace_error_never_wrong(arc_train):
    """Random targets in a box far larger than the workspace: each either round-trips or raises."""
    rng = np.random.default_rng(5)
    reached = refused = 0
    for _ in range(300):
        target = NeedleTarget(rng.uniform([-0.3, -0.2, -0.2], [0.3, 0.6, 0.6]),
                              rng.uniform(0, 0.1), rng.uniform(-np.pi, np.pi))
        try:
            q = arc_train.ik(target)
        except UnreachableError as e:
            assert str(e)  # one clear reason
            refused += 1
            continue
        pose = arc_train.needle(q)
        assert np.max(np.abs(pose.tip - target.tip)) < 1e-5
        assert np.all(q >= arc_train.chain.lower - 1e-12) and np.all(q <= arc_train.chain.upper + 1e-12)
        reached += 1
    assert reached > 0 and refused > 0


@pytest.mark.parametrize("target, words, equations", [
    (NeedleTarget(np.array([0.0, 0.0882, 0.666]), 0.0301, 47 * DEG),
     r"the needle guide would be 315\.1 mm out of the arm's reach", "eq 19"),
    (NeedleTarget(np.array([0.0, 0.0882, 0.066]), 0.250, 47 * DEG), "insertion depth 250.0 mm", ""),
    (NeedleTarget(np.array([0.4, 0.0882, 0.066]), 0.0301, 47 * DEG),
     r"d9 \(the travel along the bed\) would need 457\.5 mm, outside its range \[0\.0 mm, 100\.0 mm\]",
     "eq 4"),
    (NeedleTarget(np.array([0.0, 0.0882, 0.066]), 0.0301, 170 * DEG),
     r"theta8 \(the needle angle on the train\) would need 136\.5°, outside its range \[-90\.0°",
     "eqs 8-9"),
    (NeedleTarget(np.array([0.0, 0.9, 0.066]), 0.0301, 47 * DEG), "faces the entry point's Y = 900.0 mm",
     "eq 11"),
])
def test_unreachable_says_why_in_mm_and_degrees_and_keeps_the_equations_apart(
        arc_train, target, words, equations):
    with pytest.raises(UnreachableError, match=words) as e:
        arc_train.ik(target)
    assert equations in e.value.equations
    assert "eq" not in str(e.value)  # equation numbers belong in e.equations, not the message


def test_arc_mapping_continuous_at_top_and_inverts(arc_train):
    p = arc_train.params
    top = p.arc_span / 2  # h = G/2
    below, above = train_pose(top - 1e-12, p), train_pose(top + 1e-12, p)
    at = train_pose(top, p)
    for a, b in ((below, at), (at, above)):
        assert abs(a.d1 - b.d1) < 1e-11 and abs(a.d2 - b.d2) < 1e-11 and abs(a.omega - b.omega) < 1e-11
    # the paper's values at h = G/2: d1 = R, d2 = R, Omega = 0
    assert at.d1 == pytest.approx(p.arc_radius, abs=1e-15)
    assert at.d2 == pytest.approx(p.arc_radius, abs=1e-15)
    assert at.omega == pytest.approx(0.0, abs=1e-15)
    eps = np.linspace(0, p.arc_span, 2001)
    tp = train_pose(eps, p)
    assert np.max(np.abs(epsilon_from_d2(tp.d2, p) - eps)) < 1e-9
    assert np.max(np.abs(epsilon_from_omega(tp.omega, p) - eps)) < 1e-15
    assert np.all(np.diff(tp.d2) > 0)  # d2 strictly monotonic: the ultrasonic inverse is unique
    # the DH model puts the train exactly where eqs 13-18 say (d1 = Z, d2 = Y, tilt Omega)
    q = np.tile(arc_train.chain.home, (eps.size, 1))
    q[:, 0] = eps
    F1 = arc_train.chain.frames(q)[:, 1]
    assert np.max(np.abs(F1[:, 2, 3] - tp.d1)) < 1e-12
    assert np.max(np.abs(F1[:, 1, 3] - tp.d2)) < 1e-12
    radial = F1[:, :3, 0]  # x1 points away from the arc centre
    assert np.max(np.abs(np.arctan2(radial[:, 1], radial[:, 2]) - tp.omega)) < 1e-12


def test_urdf_files_match_the_parameter_set():
    for rel, text in generated_files().items():
        assert (URDF_DIR / rel).read_text() == text, f"urdf/{rel} is stale: run `hilbench urdf build`"


def test_scene_loads_in_direct_mode_without_warnings():
    code = (
        "import pybullet as pb\n"
        "c = pb.connect(pb.DIRECT)\n"
        f"for f in ['arc_train', 'ct_gantry', 'ct_bed', 'phantom']:\n"
        f"    assert pb.loadURDF(r'{URDF_DIR}/' + f + '.urdf', useFixedBase=True) >= 0\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    noise = [line for line in (out.stdout + out.stderr).splitlines()
             if line.strip() and not line.startswith("pybullet build time")]
    assert noise == []


def test_gravity_loads_fit_x_series_servos(arc_train):
    """At Target 1 every revolute joint's static gravity torque is within an XM430-W350's
    stall torque, and the heaviest is the train (the torque-heavy joint the paper saw lag)."""
    from drivers.quiet import quiet_pybullet

    pb = quiet_pybullet()
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(URDF_DIR / "arc_train.urdf"), useFixedBase=True,
                           flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        q = arc_train.ik(TARGET_1)
        tau = np.array(pb.calculateInverseDynamics(body, q.tolist(), [0.0] * 9, [0.0] * 9,
                                                   physicsClientId=c))
    finally:
        pb.disconnect(c)
    revolute = [i for i, r in enumerate(arc_train.chain.rows) if r.kind == "revolute"]
    assert np.all(np.abs(tau[revolute][1:]) < 4.1)
    assert np.argmax(np.abs(tau)) == 0
    assert 0.05 < abs(tau[4]) < 4.1  # the pitch joints carry the arm
