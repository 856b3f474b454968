"""Interlocks.scan over a block of cycles trips at the same cycle, with the same cause, as
checking every cycle in order — on random walks that wander into the CT gantry's margin,
past joint and velocity limits, and away from their commands."""

from __future__ import annotations

import numpy as np
import pytest

from bench.core.safety import (
    GantryClearanceInterlock,
    Interlocks,
    JointLimitInterlock,
    StaleDataInterlock,
    TrackingErrorInterlock,
    VelocityLimitInterlock,
)
from bench.kinematics.registry import get_robot
from drivers import JointState


def _interlocks(robot, clearance=None, lookahead_s=0.03) -> Interlocks:
    names = robot.joint_names
    lo, hi = robot.chain.lower, robot.chain.upper
    vel = np.array([r.velocity for r in robot.chain.rows])
    return Interlocks([JointLimitInterlock(lo - 0.01, hi + 0.01, names),
                       VelocityLimitInterlock(vel, names, 1.5),
                       TrackingErrorInterlock(0.05, names),
                       StaleDataInterlock(),
                       GantryClearanceInterlock(robot, 0.020, clearance, lookahead_s=lookahead_s)])


def _walk(robot, rng, k: int):
    """Measured and commanded positions of a wandering robot, with occasional bad samples."""
    n = len(robot.joint_names)
    lo, hi = robot.chain.lower, robot.chain.upper
    vel = np.array([r.velocity for r in robot.chain.rows])
    q = rng.uniform(lo, hi)
    step = rng.normal(size=n) * 0.4 * vel * 0.002
    P = np.empty((k, n))
    for i in range(k):
        q = q + step
        P[i] = q
    C = P + rng.normal(size=(k, n)) * 0.002
    V = np.vstack([np.zeros(n), np.diff(P, axis=0) / 0.002])
    for _ in range(rng.integers(0, 3)):  # a velocity spike, a tracking jump, a NaN reading
        i, j = rng.integers(0, k), rng.integers(0, n)
        kind = rng.integers(0, 3)
        if kind == 0:
            V[i, j] = 50.0
        elif kind == 1:
            C[i, j] += 0.2
        else:
            P[i, j] = np.nan
    return np.arange(k) * 0.002, P, V, np.zeros((k, n)), C


def _sequential(il: Interlocks, times, P, V, E, C):
    for i, t in enumerate(times):
        trip = il.check(float(t), JointState(float(t), P[i].copy(), V[i].copy(), E[i].copy()), C[i])
        if trip is not None:
            return i, trip
    return None


@pytest.mark.parametrize("robot_name", ["arc-train", "zerobot"])
def test_scan_trips_where_checking_every_cycle_trips(robot_name):
    robot = get_robot(robot_name)
    shared = GantryClearanceInterlock(robot, 0.020).clearance
    rng = np.random.default_rng(4)
    outcomes = {"gantry_clearance": 0, "none": 0}
    for _ in range(60):
        block = _walk(robot, rng, int(rng.integers(20, 120)))
        a, b = _interlocks(robot, shared), _interlocks(robot, shared)
        # the same history before the block: the gantry interlock carries its last result
        warm = block[1][0] - 0.01
        for il in (a, b):
            il.check(0.0, JointState(0.0, warm, np.zeros_like(warm), np.zeros_like(warm)), warm)
        expected = _sequential(a, *block)
        got = b.scan(*block)
        if expected is None:
            assert got is None
            outcomes["none"] += 1
        else:
            assert got is not None and got[0] == expected[0] and repr(got[1]) == repr(expected[1])
            outcomes[expected[1].interlock] = outcomes.get(expected[1].interlock, 0) + 1
        # after the block, both carry the same gantry state forward
        ga, gb = a.interlocks[-1], b.interlocks[-1]
        if expected is None:
            assert np.array_equal(ga._last_q, gb._last_q) and ga._last_d == gb._last_d
    assert outcomes["none"] >= 5 and sum(outcomes.values()) - outcomes["none"] >= 10, outcomes


def test_scan_skips_the_per_cycle_checks_when_far_from_every_limit():
    """A quiet block far from the gantry costs one exact check at most, not one per cycle."""
    robot = get_robot("arc-train")
    il = _interlocks(robot)
    n = len(robot.joint_names)
    home = robot.chain.home
    k = 200
    P = np.tile(home, (k, 1)) + np.linspace(0, 1e-3, k)[:, None]
    calls = []
    gantry = il.interlocks[-1]
    original = gantry.clearance.check
    gantry.clearance.check = lambda q: calls.append(1) or original(q)
    assert il.scan(np.arange(k) * 0.002, P, np.zeros((k, n)), np.zeros((k, n)), P.copy()) is None
    assert len(calls) == 1  # the first cycle, which has nothing to carry forward


@pytest.mark.parametrize("robot_name", ["arc-train", "zerobot"])
def test_the_fused_check_changes_no_trip_and_no_gantry_state(robot_name):
    """Interlocks.check proves most cycles clear in one pass; every trip and every exact
    gantry check is still the one the interlocks make checking one by one."""
    robot = get_robot(robot_name)
    shared = GantryClearanceInterlock(robot, 0.020).clearance
    rng = np.random.default_rng(12)
    fused_hits = 0
    for _ in range(40):
        times, P, V, E, C = _walk(robot, rng, 80)
        fused, plain = _interlocks(robot, shared), _interlocks(robot, shared)
        assert fused._clear is not None
        plain._clear = None
        for i, t in enumerate(times):
            st = JointState(float(t), P[i], V[i], E[i])
            fused_hits += fused._clear(st, C[i])
            a, b = fused.check(float(t), st, C[i]), plain.check(float(t), st, C[i])
            assert repr(a) == repr(b)
            ga, gb = fused.interlocks[-1], plain.interlocks[-1]
            assert ga._last_d == gb._last_d
            if a is not None:
                break
    assert fused_hits > 500  # it does clear most cycles on its own
