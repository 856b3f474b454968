"""A block of control cycles run by the PyBullet backend in one call gives, bit for bit, what
the same cycles give one call at a time; rewinding puts the robot back where it was."""

from __future__ import annotations

import numpy as np
import pytest

from bench.kinematics.arc_train import TARGET_1
from bench.scene.room import URDF_DIR, default_scene
from drivers import NotEnabledError
from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings
from trajectories import LSPB


def _sim(arc_train, physics_hz=1000.0, period=0.002) -> PyBulletActuators:
    return PyBulletActuators(PyBulletSettings(
        robot_urdf=URDF_DIR / "arc_train.urdf", joint_names=arc_train.joint_names,
        scene=default_scene(), initial_position=arc_train.chain.home, physics_hz=physics_hz,
        control_period=period))


def _plan(arc_train, period: float, cycles: int):
    vel = np.array([r.velocity for r in arc_train.chain.rows]) * 0.5
    traj = LSPB(arc_train.chain.home, arc_train.ik(TARGET_1), vel, vel * 2)
    q, qd, _ = traj.sample(np.arange(cycles) * period)
    return q, qd


@pytest.mark.parametrize("period", [0.001, 0.002])
def test_a_block_equals_the_same_cycles_one_by_one(arc_train, period, block_equals_cycles):
    q, qd = _plan(arc_train, period, 600)
    with _sim(arc_train, period=period) as one, _sim(arc_train, period=period) as block:
        one.enable()
        block.enable()
        block_equals_cycles(one, block, q, qd, period, 150)
        assert np.array_equal(one.read().position, block.read().position)


def test_rewind_restores_the_state_read_at_a_cycle(arc_train):
    k, period = 400, 0.002
    q, qd = _plan(arc_train, period, k)
    ends = (np.arange(k) + 1) * period
    with _sim(arc_train) as sim:
        with pytest.raises(NotEnabledError):
            sim.execute_block(q, qd, ends)
        sim.enable()
        states = sim.execute_block(q, qd, ends)
        st = sim.rewind(250)
        assert st.time == pytest.approx(250 * period) and sim.now() == pytest.approx(st.time)
        again = sim.read()
        assert np.array_equal(again.position, states.position[250])
        assert np.allclose(again.velocity, states.velocity[250], atol=1e-12)
        # the motors hold the command of the cycle before: the next cycle continues as it did
        sim.command(q[250], qd[250])
        sim.wait_until(251 * period)
        assert np.allclose(sim.read().position, states.position[251], atol=1e-6)


def test_a_block_refuses_bad_commands_before_moving(arc_train):
    q, qd = _plan(arc_train, 0.002, 10)
    q[7, 3] = np.nan
    with _sim(arc_train) as sim:
        sim.enable()
        with pytest.raises(ValueError, match="not finite in row 7"):
            sim.execute_block(q, qd, (np.arange(10) + 1) * 0.002)
        with pytest.raises(ValueError, match="needs"):
            sim.execute_block(q[:, :3], qd[:, :3], (np.arange(10) + 1) * 0.002)
        assert sim.now() == 0.0


@pytest.mark.parametrize("on_trip", ["hold", "stop"])
def test_runner_blocks_trip_at_the_cycle_checking_every_cycle_trips(on_trip, monkeypatch):
    """A plan aimed through the gantry, run in blocks and cycle by cycle: the same trip at the
    same cycle with the same cause, the same samples up to it, and the same hold after it to
    within the solver's tolerance (the block path rewinds the physics to the tripping cycle)."""
    from test_interlock_trial import INTO_GANTRY

    import bench.core.runner as runner_module
    from bench.config.models import TrialConfig
    from bench.core.log import TrialLog
    from bench.rig.backends import make_backend
    from bench.trial.plan import interlocks_for, plan, prepare

    cfg = TrialConfig.model_validate({**INTO_GANTRY, "safety": {**INTO_GANTRY["safety"],
                                                                 "on_trip": on_trip}})

    def run(blocks: bool) -> TrialLog:
        prep = prepare(cfg)
        with make_backend(prep.config, prep.robot) as act:
            assert runner_module.runs_blocks(act, interlocks_for(prep, act))
            monkeypatch.setattr(runner_module, "runs_blocks", lambda a, i: blocks)
            log = TrialLog(list(prep.robot.joint_names))
            result = runner_module.Runner(act, cfg.control_period, interlocks_for(prep, act),
                                          on_trip=on_trip).run(
                plan(prep, act.read().position, act.limits.velocity), log)
            monkeypatch.undo()
        assert not result.completed and result.reason.startswith("interlock gantry_clearance")
        return log

    cycles, blocks = run(False), run(True)
    kinds = lambda log: [(e.kind, e.message) for e in log.events]  # noqa: E731
    assert kinds(blocks) == kinds(cycles)
    trip_t = next(e.time for e in cycles.events if e.kind == "interlock")
    upto = int(np.searchsorted(cycles.time, trip_t)) + 1
    for field in ("time", "q_cmd", "qd_cmd", "q", "qd", "effort"):
        assert np.array_equal(getattr(blocks, field)[:upto], getattr(cycles, field)[:upto]), field
    assert len(blocks) == len(cycles)
    assert np.allclose(blocks.q, cycles.q, atol=1e-6)
