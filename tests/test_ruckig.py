"""Acceptance tests for the ruckig-based trajectories (offline and online)."""

from __future__ import annotations

import numpy as np
import pytest

from trajectories import LSPB, Limits, RuckigOnline, RuckigTrajectory, Trajectory, TrajectoryError

RATE = 1e-3  # 1 kHz sampling for the limit checks
REL = 1e-9  # ruckig solves its polynomials numerically


def random_case(rng, dof, jerk=np.inf):
    start = rng.uniform(-1.5, 1.5, dof)
    goal = start + rng.uniform(-1.0, 1.0, dof)
    limits = Limits(
        velocity=rng.uniform(0.3, 1.5, dof),
        acceleration=rng.uniform(0.5, 4.0, dof),
        jerk=jerk if np.isscalar(jerk) else np.asarray(jerk),
    )
    return start, goal, limits


def dense(traj, rate=RATE):
    t = np.arange(0.0, traj.duration + 0.05, rate)
    return (t, *traj.sample(t))


# -- offline ---------------------------------------------------------------------
@pytest.mark.parametrize("jerk", [np.inf, "finite"])
@pytest.mark.parametrize("seed", range(4))
def test_offline_respects_limits_on_dense_sampling(seed, jerk):
    rng = np.random.default_rng(seed)
    dof = 6
    jerk = rng.uniform(5.0, 30.0, dof) if jerk == "finite" else jerk
    start, goal, limits = random_case(rng, dof, jerk)
    traj = RuckigTrajectory(start, goal, limits)
    t, q, qd, qdd = dense(traj)
    assert np.all(np.abs(qd) <= limits.velocity * (1 + REL) + 1e-12)
    assert np.all(np.abs(qdd) <= limits.acceleration * (1 + REL) + 1e-12)
    assert np.all(np.abs(np.diff(q, axis=0)) <= limits.velocity * RATE * (1 + REL))
    assert np.all(np.abs(np.diff(qd, axis=0)) <= limits.acceleration * RATE * (1 + REL))
    if np.all(np.isfinite(limits.jerk)):
        jerk_fd = np.diff(qdd, axis=0) / np.diff(t)[:, None]
        assert np.all(np.abs(jerk_fd) <= limits.jerk * (1 + 1e-6))
        # Jerk-limited profiles start and end without an acceleration step.
        assert np.all(qdd[0] == 0.0)


@pytest.mark.parametrize("jerk", [np.inf, 20.0])
@pytest.mark.parametrize("seed", range(4))
def test_offline_reaches_start_and_goal(seed, jerk):
    rng = np.random.default_rng(10 + seed)
    start, goal, limits = random_case(rng, 5, jerk)
    traj = RuckigTrajectory(start, goal, limits)
    q, qd, _ = traj.sample(0.0)
    np.testing.assert_allclose(q, start, rtol=0, atol=1e-12)
    np.testing.assert_allclose(qd, 0.0, rtol=0, atol=1e-12)
    # The ruckig profile itself arrives (not only the clamp after the end).
    q, qd, _ = traj.sample(np.nextafter(traj.duration, 0.0))
    np.testing.assert_allclose(q, goal, rtol=0, atol=1e-9)
    np.testing.assert_allclose(qd, 0.0, rtol=0, atol=1e-9)
    q, qd, qdd = traj.sample(traj.duration + 1.0)
    assert np.array_equal(q, goal) and np.all(qd == 0) and np.all(qdd == 0)
    q, qd, qdd = traj.sample(-1.0)
    assert np.array_equal(q, start) and np.all(qd == 0) and np.all(qdd == 0)


@pytest.mark.parametrize("seed", range(4))
def test_offline_joints_finish_together(seed):
    rng = np.random.default_rng(20 + seed)
    start, goal, limits = random_case(rng, 6)
    traj = RuckigTrajectory(start, goal, limits)
    # Each joint alone would be done sooner; synchronised, none arrives early.
    alone = [
        RuckigTrajectory(
            start[[i]], goal[[i]], Limits(limits.velocity[[i]], limits.acceleration[[i]])
        )
        for i in range(6)
    ]
    assert traj.duration == pytest.approx(max(a.duration for a in alone), rel=1e-12)
    assert min(a.duration for a in alone) < traj.duration
    t = np.linspace(0.01, traj.duration - 0.01, 300)
    q, qd, _ = traj.sample(t)
    assert np.all(np.abs(q - goal) > 1e-9)
    assert np.all(np.abs(qd[-1]) > 0.0)


@pytest.mark.parametrize("seed", range(8))
def test_offline_is_no_slower_than_lspb(seed):
    rng = np.random.default_rng(30 + seed)
    start, goal, limits = random_case(rng, int(rng.integers(2, 9)))
    lspb = LSPB(start, goal, limits.velocity, limits.acceleration)
    assert RuckigTrajectory(start, goal, limits).duration <= lspb.duration + 1e-12
    stiff = Limits(limits.velocity, limits.acceleration, jerk=1e9)
    assert RuckigTrajectory(start, goal, stiff).duration <= lspb.duration + 1e-6


def test_offline_with_boundary_velocities():
    limits = Limits([1.0, 1.0], [2.0, 2.0])
    traj = RuckigTrajectory(
        [0.0, 0.0], [1.0, -1.0], limits, start_velocity=[0.5, 0.0], goal_velocity=[0.2, -0.3]
    )
    q, qd, _ = traj.sample(0.0)
    np.testing.assert_allclose(qd, [0.5, 0.0], atol=1e-12)
    q, qd, _ = traj.sample(np.nextafter(traj.duration, 0.0))
    np.testing.assert_allclose(q, [1.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(qd, [0.2, -0.3], atol=1e-9)
    np.testing.assert_allclose(traj.sample(traj.duration + 1)[1], [0.2, -0.3])


def test_offline_sample_shapes_and_protocol():
    traj = RuckigTrajectory([0, 0, 0], [1, 2, 3], Limits([1, 1, 1], [1, 1, 1]))
    assert isinstance(traj, Trajectory)
    assert traj.dof == 3
    assert all(a.shape == (3,) for a in traj.sample(0.3))
    assert all(a.shape == (5, 3) for a in traj.sample(np.linspace(-1, 10, 5)))


# -- online ----------------------------------------------------------------------
DT = 0.002


@pytest.mark.parametrize("jerk", [np.inf, 15.0])
@pytest.mark.parametrize("seed", range(3))
def test_online_reaches_goal_and_matches_offline(seed, jerk):
    rng = np.random.default_rng(40 + seed)
    start, goal, limits = random_case(rng, 5, jerk)
    offline = RuckigTrajectory(start, goal, limits)
    online = RuckigOnline(start, goal, limits, DT)
    assert isinstance(online, Trajectory)
    assert online.duration == pytest.approx(offline.duration, abs=1e-12)
    assert not online.finished
    t = np.arange(0.0, offline.duration + 10 * DT, DT)
    q_on = np.array([online.sample(tk)[0] for tk in t])  # one control cycle at a time
    q_off = offline.sample(t)[0]
    np.testing.assert_allclose(q_on, q_off, rtol=0, atol=1e-6)
    np.testing.assert_allclose(q_on[-1], goal, rtol=0, atol=1e-9)
    assert online.finished
    assert online.duration == pytest.approx(offline.duration, abs=1e-12)


def test_online_array_time_equals_stepping_and_reset_replays():
    rng = np.random.default_rng(50)
    start, goal, limits = random_case(rng, 4)
    online = RuckigOnline(start, goal, limits, DT)
    t = np.arange(0.0, online.duration + 0.1, DT)
    q1, qd1, qdd1 = online.sample(t)
    assert q1.shape == (t.size, 4)
    online.reset()
    assert online.time == 0.0 and not online.finished
    q2 = np.array([online.sample(tk)[0] for tk in t])
    assert np.array_equal(q1, q2)
    # Off-grid times round to the nearest cycle.
    online.reset()
    np.testing.assert_array_equal(online.sample(10.4 * DT)[0], q1[10])
    np.testing.assert_array_equal(online.sample(11.6 * DT)[0], q1[12])


def test_online_set_goal_mid_motion():
    rng = np.random.default_rng(60)
    start, goal, limits = random_case(rng, 6)
    new_goal = start + rng.uniform(-1.0, 1.0, 6)
    online = RuckigOnline(start, goal, limits, DT)
    first_plan_end = online.duration
    q_mid, qd_mid, _ = online.sample(0.4 * first_plan_end)
    t_switch = online.time  # on the cycle grid
    assert np.any(np.abs(qd_mid) > 0.1)  # really mid-motion

    online.set_goal(new_goal)
    assert not online.finished
    assert np.array_equal(online.goal, new_goal)
    replan = RuckigTrajectory(q_mid, new_goal, limits, start_velocity=qd_mid)
    assert online.duration == pytest.approx(online.time + replan.duration, abs=1e-9)

    t = np.arange(online.time + DT, online.duration + 10 * DT, DT)
    q, qd, qdd = online.sample(t)
    assert online.finished
    np.testing.assert_allclose(q[-1], new_goal, rtol=0, atol=1e-9)
    np.testing.assert_allclose(qd[-1], 0.0, rtol=0, atol=1e-9)
    assert np.all(np.abs(qd) <= limits.velocity * (1 + REL))
    assert np.all(np.abs(qdd) <= limits.acceleration * (1 + REL))
    assert np.all(np.abs(np.diff(q, axis=0)) <= limits.velocity * DT * (1 + REL))
    np.testing.assert_allclose(q, replan.sample(t - t_switch)[0], rtol=0, atol=1e-6)


def test_online_rejects_going_back_in_time():
    online = RuckigOnline([0.0], [1.0], Limits([1.0], [1.0]), DT)
    online.sample(0.5)
    online.sample(0.5 + 0.3 * DT)  # same cycle: fine
    with pytest.raises(TrajectoryError, match="must not decrease"):
        online.sample(0.2)
    with pytest.raises(TrajectoryError, match="must not decrease"):
        online.sample(np.array([0.6, 0.55]))
    with pytest.raises(TrajectoryError, match="t must be finite"):
        online.sample(np.inf)


def test_online_bad_new_goal_keeps_the_current_plan():
    limits = Limits([1.0, 1.0], [1.0, 1.0])
    online = RuckigOnline([0.0, 0.0], [1.0, 1.0], limits, DT)
    online.sample(0.3)
    duration = online.duration
    too_fast = r"goal_velocity\[1\] = -2 exceeds joint 1's velocity"
    with pytest.raises(TrajectoryError, match=too_fast):
        online.set_goal([0.5, 0.5], goal_velocity=[0.0, -2.0])
    with pytest.raises(TrajectoryError, match="goal has 3 values"):
        online.set_goal([0.5, 0.5, 0.5])
    assert online.duration == duration
    assert np.array_equal(online.goal, [1.0, 1.0])
    q = online.sample(duration + 0.1)[0]
    np.testing.assert_allclose(q, [1.0, 1.0], atol=1e-9)


# -- invalid input ---------------------------------------------------------------
@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Limits([1.0, 1.0], [1.0]), "acceleration limit has 1 values"),
        (lambda: Limits([1.0, -1.0], [1.0, 1.0]), "velocity limit of joint 1 must be > 0, got -1"),
        (lambda: Limits([1.0, 1.0], [1.0, 0.0]), "acceleration limit of joint 1 must be > 0"),
        (lambda: Limits([1.0, 1.0], [1.0, 1.0], [1.0, -3.0]), "jerk limit of joint 1 must be > 0"),
        (lambda: Limits([1.0, 1.0], [1.0, 1.0], [1.0, 1.0, 1.0]), "jerk limit has shape"),
        (lambda: Limits([1.0, np.nan], [1.0, 1.0]), r"velocity limit\[1\] is not finite: nan"),
        (lambda: Limits([1.0, 1.0], [1.0, 1.0], np.nan), "jerk limit of joint 0 .* got nan"),
    ],
)
def test_invalid_limits(make, match):
    with pytest.raises(TrajectoryError, match=match):
        make()


LIM2 = Limits([1.0, 1.0], [1.0, 1.0])


@pytest.mark.parametrize("cls", [RuckigTrajectory, lambda s, g, lim: RuckigOnline(s, g, lim, DT)])
@pytest.mark.parametrize(
    "start, goal, limits, match",
    [
        ([0.0, 0.0], [1.0, 1.0, 1.0], LIM2, "goal has 3 values but the motion has 2 joints"),
        ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], LIM2, "limits are for 2 joints but start has 3"),
        ([0.0, np.nan], [1.0, 1.0], LIM2, r"start\[1\] is not finite: nan"),
        ([0.0, 0.0], [np.nan, 1.0], LIM2, r"goal\[0\] is not finite: nan"),
        ([0.0, 0.0], [1.0, 1.0], {"velocity": [1, 1]}, "limits must be a trajectories.Limits"),
    ],
)
def test_invalid_motion(cls, start, goal, limits, match):
    with pytest.raises(TrajectoryError, match=match):
        cls(start, goal, limits)


def test_invalid_boundary_velocity_and_dt():
    with pytest.raises(TrajectoryError, match=r"goal_velocity\[0\] = 1.5 exceeds joint 0's"):
        RuckigTrajectory([0.0, 0.0], [1.0, 1.0], LIM2, goal_velocity=[1.5, 0.0])
    with pytest.raises(TrajectoryError, match=r"start_velocity has 1 values"):
        RuckigTrajectory([0.0, 0.0], [1.0, 1.0], LIM2, start_velocity=[0.0])
    for dt in (0.0, -0.001, np.nan):
        with pytest.raises(TrajectoryError, match="dt must be finite and > 0"):
            RuckigOnline([0.0, 0.0], [1.0, 1.0], LIM2, dt)
