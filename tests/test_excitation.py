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


def test_an_excitation_trial_runs_around_the_entry_pose_and_passes_by_completing(tmp_path):
    """`excitation:` in a trial config: approach, excite, home; every interlock on; no needle."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    from bench.core.log import TrialLog

    repo = Path(__file__).resolve().parents[1]
    data = yaml.safe_load((repo / "hil_configs" / "sim_target1_servo.yaml").read_text())
    data.update(name="excite", excitation={"joints": ["theta4", "d9"], "chirp_s": 2.0, "multisine_s": 2.0,
                                           "multisine_period_s": 1.0})
    cfg = tmp_path / "excite.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = subprocess.run([str(Path(sys.executable).with_name("hilbench")), "trial", str(cfg), "--json",
                          "--out", str(tmp_path / "runs")], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["passed"] is True and res["completed"] is True and res["tip_deviation_mm"] is None
    log = TrialLog.load(Path(res["run_dir"]) / "trial.npz")
    assert log.segment_names == ["approach", "excite", "home"]
    excite = log.segment == 1
    swing = np.ptp(log.q[excite], axis=0)
    names = list(log.joint_names)
    assert swing[names.index("theta4")] > np.radians(2.0) and swing[names.index("d9")] > 1e-3
    assert swing[names.index("theta7")] < np.radians(0.5)  # not excited: holds
    md = (Path(res["run_dir"]) / "report.md").read_text()
    assert "## Excitation" in md and "Table 3" not in md


def test_the_lab_excitation_plan_checks_out_and_excites_every_joint_with_room():
    from pathlib import Path

    from bench.config.models import load_trial_config
    from bench.trial.plan import plan, planned_limits, prepare

    cfg = load_trial_config(Path(__file__).resolve().parents[1] / "hil_configs" / "identify.yaml")
    prep = prepare(cfg)  # refuses a plan that would trip an interlock
    segs = plan(prep, prep.robot.chain.home, planned_limits(prep).velocity)
    excited = {prep.robot.joint_names[j] for _, _, j, _ in segs[1].trajectory.pieces}
    assert excited == set(prep.robot.joint_names) - {"d10"}  # the needle slide sits at its limit
    kinds = {k for *_, k in segs[1].trajectory.pieces}
    assert kinds == {"chirp", "multisine", "sweeps", "reversals", "holds"}
    # the whole plan, approach and home included, under 3 minutes of rig time
    assert sum(s.trajectory.duration + s.settle for s in segs) < 180.0


def test_the_sweeps_hold_each_speed_both_ways_from_the_stribeck_region_to_near_the_top(arm):
    """Sweeps at log-spaced speeds, each held at constant speed in both directions; slow reversals;
    four holds at rest; all within the limits and smooth, the sweeps' top speed a joint's own."""
    rest, lo, hi, lim = arm
    spec = ExcitationSpec(chirp_s=1.0, multisine_s=1.0, multisine_period_s=1.0, sweep_speeds=4,
                          sweep_slowest=0.02, sweep_fastest=0.4, sweep_s=0.6, reversal_s=2.0, hold_s=0.5,
                          pause_s=0.2)
    top = np.full(9, 4.8)
    top[8] = 0.048
    ex = Excitation(rest, [3, 8], np.r_[np.radians([10.0] * 8), 0.005], lo, hi, lim, spec, top_speed=top)
    assert [k for _, _, j, k in ex.pieces if j == 3] == ["chirp", "multisine", "sweeps", "reversals", "holds"]
    dt = 0.0005
    t = np.arange(0.0, ex.duration + 1e-9, dt)
    q, qd, qdd = ex.sample(t)
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    assert np.all(np.abs(qd) <= np.maximum(lim.velocity, top) * (1 + 1e-9))
    assert np.abs(qd[:, [0, 1, 2, 4, 5, 6, 7]]).max() == 0.0
    for j in (3, 8):
        assert np.max(np.abs(np.gradient(q[:, j], t) - qd[:, j])) < 2e-3 * top[j]
        t0, dur = next((t0, d) for t0, d, jj, k in ex.pieces if jj == j and k == "sweeps")
        m = (t >= t0) & (t <= t0 + dur)
        speeds = spec.sweep_fractions() * top[j]
        assert speeds[-1] / speeds[0] == pytest.approx(20.0) and speeds[0] == pytest.approx(0.02 * top[j])
        for v in speeds:  # each speed held, each way (the fastest across the room for over 0.1 s)
            for sign in (1, -1):
                held = np.isclose(qd[m, j], sign * v, rtol=1e-6)
                assert held.sum() * dt >= 0.1, (j, v, sign)
        t0, dur = next((t0, d) for t0, d, jj, k in ex.pieces if jj == j and k == "holds")
        m = (t >= t0) & (t <= t0 + dur)
        still = np.abs(qd[m, j]) == 0.0
        offsets = np.round(q[m, j][still] - rest[j], 9)
        assert set(offsets) == {0.0, round(ex.updown_amplitude[j], 9), round(-ex.updown_amplitude[j], 9)}
        assert still.sum() * dt >= 4 * 0.5 - 1e-6
        # the reversals turn round slowly: their peak speed is the second-slowest sweep's
        t0, dur = next((t0, d) for t0, d, jj, k in ex.pieces if jj == j and k == "reversals")
        m = (t >= t0) & (t <= t0 + dur)
        assert np.abs(qd[m, j]).max() <= speeds[1] * (1 + 1e-9)
        assert np.sum(np.diff(np.sign(qd[m, j][np.abs(qd[m, j]) > 1e-9])) != 0) >= 3
    with pytest.raises(TrajectoryError, match="sweep_slowest"):
        ExcitationSpec(sweep_speeds=3, sweep_slowest=0.5, sweep_fastest=0.2)


def test_an_excitation_of_a_joint_that_cannot_move_is_refused_before_anything_moves(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    cfg = tmp_path / "stuck.yaml"
    cfg.write_text(yaml.safe_dump({"name": "stuck", "robot": "arc-train",
                                   "target": {"x_mm": 0.0, "y_mm": 88.2, "z_mm": 66.0, "depth_mm": 30.1,
                                              "angle_deg": 47.0},
                                   "excitation": {"joints": ["theta4", "d10"]}}))
    out = subprocess.run([str(Path(sys.executable).with_name("hilbench")), "trial", str(cfg), "--out",
                          str(tmp_path / "runs")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "d10 cannot move" in out.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
