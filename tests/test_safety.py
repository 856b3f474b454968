"""Interlocks on synthetic joint states: each trips on its own fault, names it, and stays quiet
otherwise; Interlocks reports the first trip in order."""

from __future__ import annotations

import numpy as np
import pytest

from bench.core.safety import (
    GantryClearanceInterlock,
    Interlock,
    Interlocks,
    JointLimitInterlock,
    StaleDataInterlock,
    TrackingErrorInterlock,
    Trip,
    VelocityLimitInterlock,
)
from bench.kinematics.arc_train import TARGET_1
from bench.kinematics.registry import get_robot
from drivers import JointState

NAMES = ["a", "b", "c"]


def state(position, velocity=(0.0, 0.0, 0.0), flags=(), t=1.5) -> JointState:
    return JointState(t, np.array(position, float), np.array(velocity, float), np.zeros(3),
                      tuple(flags))


def test_joint_limits_measured_and_commanded():
    il = JointLimitInterlock([-1, 0, -2], [1, 0.1, 2], NAMES, tolerance=0.01)
    assert isinstance(il, Interlock)
    assert il.check(0.0, state([1.005, 0.05, 0]), np.zeros(3)) is None  # within tolerance
    trip = il.check(2.0, state([0, 0.2, 0]), np.zeros(3))
    assert trip == Trip("joint_limits", trip.cause, 2.0, "b", 0.2)
    assert trip.cause == "measured b at 0.2 is outside its range [0, 0.1] (tolerance 0.01)"
    trip = il.check(0.0, state([0, 0.05, 0]), np.array([0, 0.05, -3.0]))
    assert trip.joint == "c" and trip.cause.startswith("commanded c")
    assert JointLimitInterlock([-1, 0, -2], [1, 0.1, 2], NAMES, check_commanded=False).check(
        0.0, state([0, 0.05, 0]), np.array([0, 0.05, -3.0])) is None
    nan = il.check(0.0, state([np.nan, 0.05, 0]), np.zeros(3))
    assert nan.joint == "a"  # a NaN reading is never within limits
    with pytest.raises(ValueError, match="lower limit above upper limit for joints \\['b'\\]"):
        JointLimitInterlock([0, 1, 0], [1, 0, 1], NAMES)
    with pytest.raises(ValueError, match="one value per joint"):
        JointLimitInterlock([0, 0], [1, 1], NAMES)
    with pytest.raises(ValueError, match="measured position has shape"):
        il.check(0.0, JointState(0.0, np.zeros(2), np.zeros(2), np.zeros(2)), np.zeros(3))


def test_velocity_limits_with_factor():
    il = VelocityLimitInterlock([1.0, 0.05, 2.0], NAMES, factor=1.2)
    assert il.check(0.0, state([0, 0, 0], [1.19, -0.059, 2.3]), np.zeros(3)) is None
    trip = il.check(0.5, state([0, 0, 0], [0.0, -0.07, 0.0]), np.zeros(3))
    assert (trip.interlock, trip.joint, trip.value, trip.time) == ("velocity_limits", "b", -0.07, 0.5)
    assert "beyond 1.2 × its limit of 0.05" in trip.cause
    # with the joints' kinds, in the units a technician reads
    named = VelocityLimitInterlock([1.0, 0.05, 2.0], NAMES, 1.5, kinds=["revolute", "prismatic", "revolute"])
    trip = named.check(0.0, state([0, 0, 0], [0.0, -0.750609, 0.0]), np.zeros(3))
    assert trip.cause == "b moves at -750.6 mm/s, beyond 1.5 × its limit of 50.0 mm/s"
    assert il.check(0.0, state([0, 0, 0], [np.inf, 0, 0]), np.zeros(3)).joint == "a"
    with pytest.raises(ValueError, match="positive"):
        VelocityLimitInterlock([1.0, 0.0, 1.0], NAMES)


def test_tracking_error_per_joint():
    il = TrackingErrorInterlock([0.1, 0.01, 0.1], NAMES)
    assert il.check(0.0, state([0.0, 0.0, 0.0]), np.array([0.09, -0.009, 0.0])) is None
    trip = il.check(0.0, state([0.0, 0.0, 0.0]), np.array([0.0, 0.0, -0.2]))
    assert (trip.interlock, trip.joint) == ("tracking_error", "c")
    assert trip.value == pytest.approx(-0.2) and "is 0.2 off its command (limit 0.1)" in trip.cause
    named = TrackingErrorInterlock([np.radians(5), 0.02, 0.1], NAMES, kinds=["revolute", "prismatic", "revolute"])
    trip = named.check(0.0, state([np.radians(-8.02), 0.0, 0.0]), np.zeros(3))
    assert trip.cause == "a is 8.02° off its command (limit 5.00°)"
    limits = JointLimitInterlock([-1.0, 0.0, -2.0], [1.0, 0.1, 2.0], NAMES, kinds=["revolute", "prismatic", "revolute"])
    trip = limits.check(0.0, state([0.0, 0.1234, 0.0]), np.zeros(3))
    assert trip.cause == "measured b at 123.4 mm is outside its range [0.0 mm, 100.0 mm]"
    assert TrackingErrorInterlock(0.05, NAMES).bound.tolist() == [0.05] * 3
    with pytest.raises(ValueError, match="commanded position has shape"):
        il.check(0.0, state([0, 0, 0]), np.zeros(4))


def test_stale_data_flag():
    il = StaleDataInterlock()
    assert il.check(0.0, state([0, 0, 0], flags=("note:fine",)), np.zeros(3)) is None
    trip = il.check(3.0, state([0, 0, 0], flags=("note:x", "stale:ultrasonic")), np.zeros(3))
    assert (trip.interlock, trip.joint, trip.time) == ("stale_data", "ultrasonic", 3.0)
    assert "stale:ultrasonic" in trip.cause


def test_interlocks_report_the_first_trip_in_order():
    stale = StaleDataInterlock()
    limits = JointLimitInterlock([-1] * 3, [1] * 3, NAMES)
    chain = Interlocks([stale, limits])
    bad = state([5, 0, 0], flags=("stale:a",))
    assert chain.check(0.0, bad, np.zeros(3)).interlock == "stale_data"
    assert Interlocks([limits, stale]).check(0.0, bad, np.zeros(3)).interlock == "joint_limits"
    assert chain.check(0.0, state([0, 0, 0]), np.zeros(3)) is None
    assert len(chain) == 2 and list(chain) == [stale, limits]
    with pytest.raises(ValueError, match="unique"):
        Interlocks([stale, StaleDataInterlock()])
    with pytest.raises(TypeError, match="not an interlock"):
        Interlocks([object()])  # type: ignore[list-item]


def test_gantry_clearance_interlock_on_the_arc_robot():
    robot = get_robot("arc-train")
    il = GantryClearanceInterlock(robot, margin=0.020)
    n = len(robot.joint_names)
    q_ok = robot.ik(TARGET_1)
    measured = JointState(0.0, q_ok, np.zeros(n), np.zeros(n))
    assert il.check(0.0, measured, q_ok) is None
    # a random pose with an arm link in the bore's wall
    Q = np.random.default_rng(0).uniform(robot.chain.lower, robot.chain.upper, (500, n))
    d = il.clearance.distances_batch(Q).min(axis=1)
    q_bad = Q[np.flatnonzero((d > 0.005) & (d < 0.015))[0]]
    c = il.clearance.check(q_bad)
    assert c.distance < 0.02
    trip = il.check(4.0, JointState(4.0, q_bad, np.zeros(n), np.zeros(n)), q_bad)
    assert trip.interlock == "gantry_clearance" and trip.time == 4.0
    assert trip.value == pytest.approx(c.distance)
    assert c.link in trip.cause and f"{c.distance * 1e3:.1f} mm" in trip.cause
    assert "measured" in trip.cause and "margin 20.0 mm" in trip.cause
    # a command into the margin trips before the robot gets there
    trip = il.check(0.0, measured, q_bad)
    assert trip is not None and "commanded" in trip.cause
    assert GantryClearanceInterlock(robot, 0.02, il.clearance, check_commanded=False).check(
        0.0, measured, q_bad) is None
    nan = il.check(0.0, JointState(0.0, np.full(n, np.nan), np.zeros(n), np.zeros(n)), q_ok)
    assert "not finite" in nan.cause


def test_gantry_interlock_reuse_never_clears_a_contact():
    """Random joint-space walks into and out of the gantry: carrying the last result forward
    (bounded by the joints' lever arms) never clears a pose the exact test calls contact,
    and the lever bound really bounds how far the robot's surface moves."""
    from bench.scene.contact import GantryContact

    robot = get_robot("zerobot")
    il = GantryClearanceInterlock(robot, margin=0.020)
    exact = GantryContact(il.clearance.geometry)
    g = il.clearance.geometry
    n = len(robot.joint_names)
    rng = np.random.default_rng(9)
    reused = contacts = 0
    for _ in range(8):
        q = rng.uniform(robot.chain.lower, robot.chain.upper)
        step = rng.normal(size=n) * 0.004
        for k in range(80):
            q_next = np.clip(q + step, robot.chain.lower, robot.chain.upper)
            F0, F1 = g.link_frames(q), g.link_frames(q_next)
            moved = [np.linalg.norm((F1[i] - F0[i])[:3, :3] @ p + (F1[i] - F0[i])[:3, 3])
                     for i, p in zip(g.point_link[::97], g.points_local[::97])]
            assert max(moved) <= g.levers @ np.abs(q_next - q) + 1e-12
            q = q_next
            before = il._last_q
            trip = il.check(0.0, JointState(0.0, q, np.zeros(n), np.zeros(n)), q)
            reused += il._last_q is before
            if exact.check(q).contact:
                contacts += 1
                assert trip is not None
    assert reused > 50 and contacts > 10
