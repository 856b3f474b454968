"""The excitation motion for identifying the servos: within limits, smooth, at rest at both ends."""

from __future__ import annotations

import numpy as np
import pytest

from bench.kinematics.registry import get_robot
from trajectories import Excitation, ExcitationSpec, Limits, Trajectory, TrajectoryError


@pytest.fixture(scope="module")
def arm():
    robot = get_robot("arc-train")
    rows = robot.chain.rows
    lo, hi = np.array([r.lower for r in rows]), np.array([r.upper for r in rows])
    vel = np.array([r.velocity for r in rows])
    rest = robot.chain.home.copy()
    rest[8] = 0.03  # the needle slide sits at its lower limit at home: excite it mid-stroke
    return rest, lo, hi, Limits(vel, 2.0 * vel)


def test_every_excited_joint_gets_a_chirp_a_multisine_and_an_up_and_down_in_turn(arm):
    rest, lo, hi, lim = arm
    ex = Excitation(rest, [2, 3, 8], np.r_[np.radians([10.0] * 8), 0.02], lo, hi, lim)
    assert isinstance(ex, Trajectory)
    kinds = [(j, k) for _, _, j, k in ex.pieces]
    assert kinds == [(j, k) for j in (2, 3, 8) for k in ("chirp", "multisine", "updown")]
    starts = [t0 for t0, *_ in ex.pieces]
    assert starts == sorted(starts) and ex.duration > starts[-1]


def test_the_motion_stays_within_limits_and_is_smooth_and_at_rest_at_both_ends(arm):
    rest, lo, hi, lim = arm
    ex = Excitation(rest, [2, 3, 8], np.r_[np.radians([10.0] * 8), 0.02], lo, hi, lim)
    t = np.arange(0.0, ex.duration + 1e-9, 0.0005)
    q, qd, qdd = ex.sample(t)
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    assert np.all(np.abs(qd) <= lim.velocity * (1 + 1e-9))
    assert np.all(np.abs(qdd) <= lim.acceleration * (1 + 1e-9))
    # only the excited joints move, one at a time
    moving = np.abs(q - rest) > 1e-12
    assert not moving[:, [0, 1, 4, 5, 6, 7]].any() and moving.sum(axis=1).max() == 1
    # velocity is the derivative of position (no jumps)
    for j in (2, 3, 8):
        assert np.max(np.abs(np.gradient(q[:, j], t) - qd[:, j])) < 1e-3 * lim.velocity[j]
    for end in (0.0, ex.duration):
        qe, qde, _ = ex.sample(end)
        assert np.allclose(qe, rest) and np.allclose(qde, 0.0)


def test_the_band_limits_the_sine_amplitudes_and_the_slow_move_uses_the_room(arm):
    rest, lo, hi, lim = arm
    spec = ExcitationSpec(f1_hz=2.0)
    ex = Excitation(rest, [3], np.radians([10.0] * 9), lo, hi, lim, spec)
    w = 2 * np.pi * 2.0
    assert ex.amplitude[3] == pytest.approx(0.8 * lim.acceleration[3] / w ** 2)
    assert ex.updown_amplitude[3] == pytest.approx(np.radians(10.0))


def test_a_joint_with_no_room_or_a_bad_spec_is_refused(arm):
    rest, lo, hi, lim = arm
    at_limit = rest.copy()
    at_limit[8] = lo[8]
    with pytest.raises(TrajectoryError, match=r"joint\(s\) \[8\] have no room"):
        Excitation(at_limit, [8], np.full(9, 0.01), lo, hi, lim)
    with pytest.raises(TrajectoryError, match="f1_hz"):
        ExcitationSpec(f0_hz=2.0, f1_hz=1.0)
    with pytest.raises(TrajectoryError, match="indices"):
        Excitation(rest, [9], np.full(9, 0.01), lo, hi, lim)
