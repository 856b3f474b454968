"""The PyBullet backend honours the Actuators contract: lifecycle, limits, clock, isolation."""

from __future__ import annotations

import numpy as np
import pytest

from bench.scene.room import URDF_DIR, default_scene
from drivers import Actuators, BackendSetupError, NotEnabledError
from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings


def settings(arc_train, **kw) -> PyBulletSettings:
    base = dict(robot_urdf=URDF_DIR / "arc_train.urdf", joint_names=arc_train.joint_names,
                scene=default_scene(), initial_position=arc_train.chain.home)
    base.update(kw)
    return PyBulletSettings(**base)


def test_is_an_actuators_and_refuses_commands_before_enable(arc_train):
    with PyBulletActuators(settings(arc_train)) as sim:
        assert isinstance(sim, Actuators)
        st = sim.read()
        assert st.position == pytest.approx(arc_train.chain.home)
        with pytest.raises(NotEnabledError, match="enable"):
            sim.command(arc_train.chain.home)
        sim.enable()
        sim.command(arc_train.chain.home)
        with pytest.raises(ValueError, match="shape"):
            sim.command(np.zeros(3))
        for bad in (np.nan, np.inf, -np.inf):
            q = np.array(arc_train.chain.home, dtype=float)
            q[4] = bad
            with pytest.raises(ValueError, match="finite"):
                sim.command(q)
    assert not sim.enabled


def test_control_period_must_be_whole_physics_steps(arc_train):
    with pytest.raises(BackendSetupError, match="integer multiple"):
        PyBulletActuators(settings(arc_train, physics_hz=1000.0, control_period=0.0025))


def test_missing_urdf_is_named(arc_train, tmp_path):
    with pytest.raises(BackendSetupError, match="nowhere.urdf"):
        PyBulletActuators(settings(arc_train, robot_urdf=tmp_path / "nowhere.urdf"))


def test_clock_moves_only_when_stepped_and_instances_are_isolated(arc_train):
    a = PyBulletActuators(settings(arc_train))
    b = PyBulletActuators(settings(arc_train))
    try:
        assert a.client != b.client
        assert a.now() == 0.0
        a.enable()
        goal = arc_train.chain.home.copy()
        goal[2] += 0.3  # theta4, ramped over 0.5 s with velocity feed-forward
        home = arc_train.chain.home
        for k in range(1, 251):
            s = min(1.0, k / 250)
            a.command(home + s * (goal - home), (goal - home) / 0.5 * (s < 1.0))
            a.wait_until(k * 0.002)
        a.command(goal)
        a.wait_until(1.0)
        assert a.now() == pytest.approx(1.0)
        assert b.now() == 0.0
        assert a.read().position[2] == pytest.approx(goal[2], abs=1e-3)
        assert b.read().position[2] == pytest.approx(arc_train.chain.home[2], abs=1e-9)
    finally:
        a.close()
        b.close()


def test_effort_limit_makes_a_loaded_joint_sag(arc_train):
    """theta5 carries the arm against gravity; with 1 % of its torque it cannot hold."""
    q0 = arc_train.chain.home.copy()
    q0[0] = 0.3  # train tilted so the pitch joints carry load
    eff = np.array([r.effort for r in arc_train.chain.rows])
    weak = eff.copy()
    weak[3] = 0.01 * eff[3]
    results = []
    for effort in (eff, weak):
        with PyBulletActuators(settings(arc_train, initial_position=q0, max_effort=effort)) as sim:
            sim.enable()
            sim.command(q0)
            sim.wait_until(1.0)
            st = sim.read()
            results.append(abs(st.position[3] - q0[3]))
            assert np.all(np.abs(st.effort) <= effort + 1e-6)
    strong_err, weak_err = results
    assert strong_err < 1e-3
    assert weak_err > 50 * strong_err


def test_safe_stop_hold_keeps_position(arc_train):
    q0 = arc_train.chain.home.copy()
    q0[0] = 0.4
    with PyBulletActuators(settings(arc_train, initial_position=q0, safe_stop="hold")) as sim:
        sim.enable()
        sim.wait_until(0.2)
        sim.disable()
        before = sim.read().position
        sim.wait_until(1.2)
        assert np.max(np.abs(sim.read().position - before)) < 2e-3


@pytest.mark.parametrize("servo_model", ["ideal", "datasheet"])
def test_a_sim_starts_where_backend_start_says_and_refuses_an_unknown_joint(servo_model):
    """compare starts each sim repeat where the rig's started: both simulators take backend.start."""
    import yaml

    from bench.config.models import TrialConfig
    from bench.kinematics.registry import get_robot
    from bench.paths import REPO_ROOT
    from bench.rig.backends import make_backend

    data = yaml.safe_load((REPO_ROOT / "hil_configs" / "sim_target1.yaml").read_text())
    data["backend"] = {"kind": "pybullet", "servo_model": servo_model, "start": {"theta4": 0.1, "d9": 0.06}}
    robot = get_robot("arc-train")
    act = make_backend(TrialConfig.model_validate(data), robot)
    try:
        q = act.read().position
    finally:
        act.close()
    names = list(robot.joint_names)
    tick = 2 * np.pi / 4096
    assert q[names.index("theta4")] == pytest.approx(0.1, abs=tick)
    assert q[names.index("d9")] == pytest.approx(0.06, abs=1e-4)
    assert q[names.index("theta5")] == pytest.approx(robot.chain.home[names.index("theta5")], abs=tick)
    data["backend"]["start"] = {"theta99": 0.1}
    with pytest.raises(ValueError, match=r"backend.start: unknown joint\(s\) \['theta99'\]"):
        TrialConfig.model_validate(data)
