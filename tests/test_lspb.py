"""Acceptance tests for the phase-synchronised LSPB."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from trajectories import LSPB, Trajectory, TrajectoryError

TINY = 1e-12


# -- an independent reference: the three textbook equations, scalar per joint --
def reference_plan(q0, qf, vmax, amax, duration=None):
    """(tb, tf, A) of the normalised profile, computed without numpy."""
    v_ratio, a_ratio = [], []
    for a, b, v, acc in zip(q0, qf, vmax, amax):
        d = abs(b - a)
        if d > 0:
            v_ratio.append(v / d)
            a_ratio.append(acc / d)
    if not v_ratio:
        return 0.0, 0.0, 0.0
    V, A = min(v_ratio), min(a_ratio)
    if duration is None:
        if V * V / A >= 1:
            tb = math.sqrt(1 / A)
            return tb, 2 * tb, A
        return V / A, 1 / V + V / A, A
    tf = duration
    tb = tf / 2 - math.sqrt(A * A * tf * tf - 4 * A) / (2 * A)
    return tb, tf, A


def reference_state(q0, qf, A, tb, tf, t):
    """Per-joint LSPB with signed blend acceleration a = A (qf - q0)."""
    a = A * (qf - q0)
    if t < 0:
        return q0, 0.0, 0.0
    if t < tb:
        return q0 + 0.5 * a * t * t, a * t, a
    if t < tf - tb:
        return q0 + a * tb * (t - tb / 2), a * tb, 0.0
    if t < tf:
        return qf - 0.5 * a * (tf - t) ** 2, a * (tf - t), -a
    return qf, 0.0, 0.0


def random_case(rng, dof, triangular):
    start = rng.uniform(-2, 2, dof)
    goal = start + rng.uniform(-1.5, 1.5, dof)
    amax = rng.uniform(0.5, 4.0, dof)
    # A huge speed limit is never reached (triangular); a small one always is.
    vmax = rng.uniform(50, 100, dof) if triangular else rng.uniform(0.05, 0.3, dof)
    return start, goal, vmax, amax


def dense(traj, dt=1e-4):
    t = np.arange(-0.05, traj.duration + 0.05, dt)
    return (t, *traj.sample(t))


ROBOT_START = np.array([0.12, -0.04, 0.30, 0.0, 0.35, -0.60, 1.20, 0.0, 0.010])
ROBOT_GOAL = np.array([0.18, -0.01, 0.25, 0.40, 0.35, -0.20, 0.80, 1.57, 0.045])
ROBOT_VMAX = np.array([0.05, 0.05, 0.05, 0.5, 0.5, 0.8, 0.8, 1.0, 0.01])  # m/s, rad/s
ROBOT_AMAX = np.array([0.10, 0.10, 0.10, 1.0, 1.0, 2.0, 2.0, 2.0, 0.02])  # m/s², rad/s²


# -- values ------------------------------------------------------------------
@pytest.mark.parametrize("triangular", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_matches_independent_analytic_lspb(seed, triangular):
    rng = np.random.default_rng(seed)
    start, goal, vmax, amax = random_case(rng, dof=int(rng.integers(1, 8)), triangular=triangular)
    traj = LSPB(start, goal, vmax, amax)
    tb, tf, A = reference_plan(start, goal, vmax, amax)
    assert bool(tb == pytest.approx(tf / 2, rel=1e-15)) is triangular
    assert traj.duration == pytest.approx(tf, rel=1e-13)
    assert traj.blend_time == pytest.approx(tb, rel=1e-13)

    t = np.sort(np.concatenate([rng.uniform(-0.2, tf + 0.2, 300), [0.0, tb, tf - tb, tf]]))
    q, qd, qdd = traj.sample(t)
    for k, tk in enumerate(t):
        on_boundary = any(abs(tk - b) < 1e-9 for b in (0.0, tb, tf - tb, tf))
        for i in range(len(start)):
            rq, rqd, rqdd = reference_state(start[i], goal[i], A, tb, tf, float(tk))
            assert q[k, i] == pytest.approx(rq, abs=1e-12)
            assert qd[k, i] == pytest.approx(rqd, abs=1e-12)
            if not on_boundary:
                assert qdd[k, i] == pytest.approx(rqdd, abs=1e-12)


def test_matches_analytic_lspb_with_requested_duration():
    rng = np.random.default_rng(42)
    for _ in range(10):
        start, goal, vmax, amax = random_case(rng, dof=5, triangular=False)
        fastest = LSPB(start, goal, vmax, amax).duration
        duration = fastest * rng.uniform(1.0, 3.0)
        traj = LSPB(start, goal, vmax, amax, duration=duration)
        tb, tf, A = reference_plan(start, goal, vmax, amax, duration)
        assert traj.duration == duration
        assert traj.blend_time == pytest.approx(tb, rel=1e-9)
        t = rng.uniform(0, tf, 100)
        q, qd, _ = traj.sample(t)
        for k, tk in enumerate(t):
            for i in range(5):
                rq, rqd, _ = reference_state(start[i], goal[i], A, tb, tf, float(tk))
                assert q[k, i] == pytest.approx(rq, abs=1e-12)
                assert qd[k, i] == pytest.approx(rqd, abs=1e-12)


# -- continuity ----------------------------------------------------------------
@pytest.mark.parametrize("triangular", [True, False])
@pytest.mark.parametrize("seed", range(4))
def test_position_and_velocity_continuous_on_dense_grid(seed, triangular):
    rng = np.random.default_rng(100 + seed)
    start, goal, vmax, amax = random_case(rng, dof=6, triangular=triangular)
    traj = LSPB(start, goal, vmax, amax)
    t, q, qd, _ = dense(traj, dt=1e-4)
    dt = np.diff(t)[:, None]
    assert np.all(np.abs(np.diff(q, axis=0)) <= vmax * dt + TINY)
    assert np.all(np.abs(np.diff(qd, axis=0)) <= amax * dt + TINY)


@pytest.mark.parametrize("triangular", [True, False])
def test_continuous_across_each_blend_boundary(triangular):
    rng = np.random.default_rng(7)
    start, goal, vmax, amax = random_case(rng, dof=4, triangular=triangular)
    traj = LSPB(start, goal, vmax, amax)
    tb, tf = traj.blend_time, traj.duration
    for b in (0.0, tb, tf - tb, tf):
        left, right = np.nextafter(b, -np.inf), np.nextafter(b, np.inf)
        q, qd, _ = traj.sample(np.array([left, b, right]))
        assert np.max(np.abs(q[1] - q[0])) <= 1e-12
        assert np.max(np.abs(q[2] - q[1])) <= 1e-12
        assert np.max(np.abs(qd[1] - qd[0])) <= 1e-12
        assert np.max(np.abs(qd[2] - qd[1])) <= 1e-12


# -- boundary states, limits, synchronisation -----------------------------------------
@pytest.mark.parametrize("triangular", [True, False])
def test_boundary_states_exact(triangular):
    rng = np.random.default_rng(3)
    start, goal, vmax, amax = random_case(rng, dof=7, triangular=triangular)
    traj = LSPB(start, goal, vmax, amax)
    tf = traj.duration
    for t, expected in ((0.0, start), (-1.0, start), (tf, goal), (tf + 5, goal)):
        q, qd, qdd = traj.sample(t)
        assert np.array_equal(q, expected)
        assert np.all(qd == 0.0)
    assert np.all(traj.sample(traj.duration)[2] == 0.0)


@pytest.mark.parametrize("triangular", [True, False])
@pytest.mark.parametrize("seed", range(4))
def test_limits_respected_and_one_is_active(seed, triangular):
    rng = np.random.default_rng(200 + seed)
    start, goal, vmax, amax = random_case(rng, dof=5, triangular=triangular)
    traj = LSPB(start, goal, vmax, amax)
    _, _, qd, qdd = dense(traj, dt=1e-3)
    assert np.all(np.abs(qdd) <= amax + TINY)
    assert np.all(np.abs(qd) <= vmax * (1 + TINY))
    assert np.all(np.abs(traj.peak_velocity) <= vmax * (1 + TINY))
    assert np.all(np.abs(traj.acceleration) <= amax * (1 + TINY))
    # Time-optimal: the acceleration limit of some joint is used in full, and in
    # the trapezoidal case the velocity limit of some joint too.
    assert np.max(np.abs(traj.acceleration) / amax) == pytest.approx(1.0, rel=1e-14)
    speed_use = np.max(np.abs(traj.peak_velocity) / vmax)
    if triangular:
        assert speed_use < 1.0
    else:
        assert speed_use == pytest.approx(1.0, rel=1e-14)


@pytest.mark.parametrize("triangular", [True, False])
def test_joints_start_and_finish_together_on_the_joint_space_line(triangular):
    rng = np.random.default_rng(11)
    start, goal, vmax, amax = random_case(rng, dof=6, triangular=triangular)
    goal[2] = start[2]  # one joint stays put
    traj = LSPB(start, goal, vmax, amax)
    tf = traj.duration
    t = np.linspace(1e-3, tf - 1e-3, 500)
    q, qd, _ = traj.sample(t)
    moving = np.arange(6) != 2
    assert np.all(q[:, 2] == start[2]) and np.all(qd[:, 2] == 0.0)
    # Every moving joint is in motion for the whole of (0, tf) and has not arrived early.
    assert np.all(np.abs(qd[:, moving]) > 0.0)
    assert np.all(q[:, moving] != goal[moving])
    # Common progress s(t): the path is the straight line from start to goal.
    s = (q[:, moving] - start[moving]) / (goal[moving] - start[moving])
    assert np.max(np.abs(s - s[:, :1])) <= 1e-12
    assert np.array_equal(traj.sample(tf)[0], goal)


def test_requested_duration_is_honoured_within_limits():
    start, goal = np.array([0.0, 1.0, -0.5]), np.array([1.0, 0.0, 0.5])
    vmax, amax = np.array([1.0, 2.0, 1.0]), np.array([2.0, 2.0, 4.0])
    fastest = LSPB(start, goal, vmax, amax)
    same = LSPB(start, goal, vmax, amax, duration=fastest.duration)
    assert same.blend_time == pytest.approx(fastest.blend_time, rel=1e-6)
    slow = LSPB(start, goal, vmax, amax, duration=4.0)
    assert slow.duration == 4.0
    assert np.array_equal(slow.sample(4.0)[0], goal)
    _, _, qd, qdd = dense(slow, dt=1e-3)
    assert np.all(np.abs(qd) <= vmax + TINY)
    assert np.all(np.abs(qdd) <= amax + TINY)
    # Slowed down, but still at the full acceleration of the limiting joint.
    assert np.max(np.abs(slow.acceleration) / amax) == pytest.approx(1.0, rel=1e-12)


def test_nine_joint_robot_move():
    traj = LSPB(ROBOT_START, ROBOT_GOAL, ROBOT_VMAX, ROBOT_AMAX)
    assert isinstance(traj, Trajectory)
    assert traj.dof == 9
    tb, tf, A = reference_plan(ROBOT_START, ROBOT_GOAL, ROBOT_VMAX, ROBOT_AMAX)
    assert traj.duration == pytest.approx(tf, rel=1e-14)
    q, qd, qdd = traj.sample(np.array([0.0, tf]))
    assert np.array_equal(q[0], ROBOT_START) and np.array_equal(q[1], ROBOT_GOAL)
    assert np.all(qd == 0.0)
    _, q, qd, qdd = dense(traj, dt=1e-3)
    assert np.all(np.abs(qd) <= ROBOT_VMAX * (1 + TINY))
    assert np.all(np.abs(qdd) <= ROBOT_AMAX + TINY)
    # Joint 4 does not move; joint 8 (needle insertion, 35 mm at 10 mm/s) sets the pace.
    assert np.all(q[:, 4] == ROBOT_START[4])
    assert np.argmax(np.abs(traj.peak_velocity) / ROBOT_VMAX) == 8
    assert abs(traj.peak_velocity[8]) == pytest.approx(ROBOT_VMAX[8], rel=1e-14)


# -- degenerate moves and shapes ---------------------------------------------------
def test_no_motion_has_zero_duration():
    start = np.array([0.3, -0.1, 0.02])
    traj = LSPB(start, start.copy(), [1, 1, 1], [1, 1, 1])
    assert traj.duration == 0.0
    q, qd, qdd = traj.sample(np.array([-1.0, 0.0, 1.0]))
    assert np.array_equal(q, np.tile(start, (3, 1)))
    assert np.all(qd == 0) and np.all(qdd == 0)


def test_sample_shapes():
    traj = LSPB([0, 0], [1, 2], [1, 1], [1, 1])
    q, qd, qdd = traj.sample(0.5)
    assert q.shape == qd.shape == qdd.shape == (2,)
    q, qd, qdd = traj.sample(np.linspace(0, 1, 7))
    assert q.shape == qd.shape == qdd.shape == (7, 2)
    q, qd, qdd = traj.sample(np.array([0.5]))
    assert q.shape == (1, 2)
    with pytest.raises(TrajectoryError, match="1-D"):
        traj.sample(np.zeros((2, 2)))


# -- errors ------------------------------------------------------------------------
def _numbers(message):
    return [float(x) for x in re.findall(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", message)]


def test_duration_with_too_little_acceleration_names_joint_and_minimum():
    start, goal = np.array([0.0, 0.0, 0.0]), np.array([0.5, 2.0, 0.1])
    amax = np.array([10.0, 1.0, 10.0])
    with pytest.raises(TrajectoryError, match="acceleration") as err:
        LSPB(start, goal, [10, 10, 10], amax, duration=2.0)
    message = str(err.value)
    assert "joint 1" in message
    needed = 4 * 2.0 / 2.0**2
    assert any(x == pytest.approx(needed, rel=1e-5) for x in _numbers(message)), message
    assert any(x == pytest.approx(1.0) for x in _numbers(message)), message


def test_duration_too_short_for_velocity_names_joint():
    with pytest.raises(TrajectoryError, match=r"joint 0's velocity") as err:
        LSPB([0.0, 0.0], [2.0, 0.1], [0.5, 10.0], [100.0, 100.0], duration=1.0)
    assert "0.5" in str(err.value)


@pytest.mark.parametrize(
    "args, match",
    [
        (([0, 0], [1, 1, 1], [1, 1], [1, 1]), "goal has 3 values"),
        (([0, 0], [1, 1], [1, 1, 1], [1, 1]), "velocity_limit has 3 values"),
        (([0, 0], [1, 1], [1, -1], [1, 1]), "velocity limit of joint 1 must be > 0, got -1"),
        (([0, 0], [1, 1], [1, 1], [0, 1]), "acceleration limit of joint 0 must be > 0, got 0"),
        (([0, np.nan], [1, 1], [1, 1], [1, 1]), r"start\[1\] is not finite: nan"),
        (([0, 0], [1, np.inf], [1, 1], [1, 1]), r"goal\[1\] is not finite: inf"),
        (([0, 0], [1, 1], [1, 1], [1, np.nan]), r"acceleration_limit\[1\] is not finite"),
    ],
)
def test_invalid_input_is_rejected_with_reason(args, match):
    with pytest.raises(TrajectoryError, match=match):
        LSPB(*args)


@pytest.mark.parametrize("duration", [0.0, -1.0, np.nan, np.inf])
def test_invalid_duration_is_rejected(duration):
    with pytest.raises(TrajectoryError, match="duration"):
        LSPB([0.0], [1.0], [1.0], [1.0], duration=duration)


def test_nan_time_is_rejected():
    with pytest.raises(TrajectoryError, match="NaN"):
        LSPB([0.0], [1.0], [1.0], [1.0]).sample(np.nan)
