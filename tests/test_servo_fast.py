"""The servo-model sim's fast paths give what the plain ones give: the fused position loop the
servo array's torques bit for bit, the plant that reuses its mass matrix the trajectory of one
that computes it every step, and a block of cycles what the same cycles give one call at a time,
trips included."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import drivers.servo.plant as plant_module
from bench.config.models import TrialConfig, load_trial_config
from bench.kinematics.arc_train import TARGET_1
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend
from bench.scene.room import URDF_DIR
from drivers.dynamixel.control_table import XM430_W350
from drivers.servo import ServoArray, ServoParams, friction_torque
from drivers.servo.fast import PositionLoop
from drivers.servo.plant import PyBulletPlant
from trajectories import LSPB

REPO = Path(__file__).resolve().parents[1]
SERVO_SIM = REPO / "hil_configs" / "sim_target1_servo.yaml"
DT = 0.001
TOLERANCE = plant_module.MASS_MATRIX_TOLERANCE


@pytest.mark.parametrize("profile, deadband, fused", [((0, 0), 0, True), ((60, 20), 0, False),
                                                      ((0, 0), 3, False)])
def test_the_fused_position_loop_gives_the_servo_arrays_torque_bit_for_bit(profile, deadband, fused):
    """Nine servos with mixed gains through moves, a current limit lowered half-way through the
    array's setter: the fused loop (or, outside the plain case, the general step it hands over to)
    gives the array's very torques, from the shafts and from joint values through transmissions
    (the path the servo sim runs), bit for bit; rewound to a snapshot of the array, it gives them again."""
    rng = np.random.default_rng(3)
    n = 9
    gains = [(int(p), int(i), int(d)) for p, i, d in zip(rng.integers(400, 1500, n), rng.integers(0, 400, n),
                                                         rng.integers(0, 300, n))]
    params = ServoParams.datasheet([XM430_W350] * n, gains=gains, deadband_ticks=deadband).with_(
        profile_velocity=profile[0], profile_acceleration=profile[1], coulomb=0.02, viscous=0.05)
    plain, fast, geared, geared_plain = (ServoArray(params) for _ in range(4))
    q, qd = rng.uniform(-0.5, 0.5, n), np.zeros(n)
    # the same servos behind transmissions, stepped from joint values (joint = offset + ratio · shaft)
    ratio, offset = rng.choice([0.01, 0.05, 1.0, -1.0], n), rng.uniform(-1.0, 1.0, n)
    for array in (plain, fast, geared, geared_plain):
        array.reset(q)
    loop = PositionLoop(fast, DT)
    joint_loop = PositionLoop(geared, DT, ratio, offset)
    transmission = geared_plain.transmission(ratio, offset)
    assert loop.fused is fused and joint_loop.fused is fused
    start = q.copy()
    rewound = None
    for k in range(3000):
        if k % 400 == 0:
            goal = q + rng.uniform(-0.4, 0.4, n)
            for target in (plain, loop, joint_loop, geared_plain):
                target.set_goal(goal)
        if k == 1500:  # the owner lowers a limit through the array's setter: the loops refresh themselves
            for array in (plain, fast, geared, geared_plain):
                array.set_current_limit(2, 0.4)
        if k == 2000:  # a snapshot to rewind to
            rewound = (fast.snapshot(), geared.snapshot(), q.copy(), qd.copy(), [])
        tau = plain.step(DT, q, qd)
        assert np.array_equal(loop.step(q, qd), tau), f"step {k}"
        qj, qdj = offset + ratio * q, ratio * qd
        at_joint = joint_loop.step_joint(qj, qdj)
        expected = geared_plain.step_joint(DT, qj, qdj, transmission)
        assert np.array_equal(at_joint, expected), f"step {k} from the joints"
        np.testing.assert_allclose(at_joint * ratio, tau, rtol=1e-9, atol=1e-12, err_msg=f"step {k}")
        if k >= 2000:
            rewound[4].append((goal if k % 400 == 0 else None, tau, at_joint))
        qd = qd + DT * (tau - friction_torque(params, qd)) / 0.02
        q = q + DT * qd
    assert np.array_equal(fast.integral, plain.integral) and np.array_equal(fast.current, plain.current)
    assert np.abs(q - start).max() > 0.2  # the comparison covered real moves
    # rewound through the array's snapshot, the loops give the same torques again, bit for bit
    fast.restore(rewound[0])
    geared.restore(rewound[1])
    q, qd = rewound[2], rewound[3]
    for new_goal, tau, at_joint in rewound[4]:
        if new_goal is not None:
            loop.set_goal(new_goal)
            joint_loop.set_goal(new_goal)
        assert np.array_equal(loop.step(q, qd), tau)
        assert np.array_equal(joint_loop.step_joint(offset + ratio * q, ratio * qd), at_joint)
        qd = qd + DT * (tau - friction_torque(params, qd)) / 0.02
        q = q + DT * qd


class _Counting:
    """PyBullet with its mass-matrix calls counted."""

    def __init__(self, pb) -> None:
        self._pb, self.mass_matrices = pb, 0

    def __getattr__(self, name):
        return getattr(self._pb, name)

    def calculateMassMatrix(self, *args, **kwargs):
        self.mass_matrices += 1
        return self._pb.calculateMassMatrix(*args, **kwargs)


def _plant_run(arc_train, monkeypatch, tolerance: float) -> tuple[np.ndarray, int]:
    """The arc robot from home towards Target 1's entry under nine datasheet servos at 1 kHz, a
    second of the move and a second holding: its path and how many mass matrices it computed."""
    monkeypatch.setattr(plant_module, "MASS_MATRIX_TOLERANCE", tolerance)
    names = arc_train.joint_names
    ratio = np.array([0.05, 1, 1, 1, 1, 1, 1, 0.01, 0.01], dtype=float)
    offset = np.zeros(len(names))
    params = ServoParams.datasheet([XM430_W350] * len(names)).with_(coulomb=0.03, viscous=0.02)
    home = np.asarray(arc_train.chain.home, dtype=float)
    plant = PyBulletPlant(URDF_DIR / "arc_train.urdf", names, ratio, offset, home, params, physics_dt=DT)
    counting = plant._pb = _Counting(plant._pb)
    servos = ServoArray(params)
    servos.hold(plant.position(), plant.holding_torque())
    loop = PositionLoop(servos, DT)
    traj = LSPB(home, arc_train.ik(TARGET_1), np.array([r.velocity for r in arc_train.chain.rows]) * 0.5,
                np.array([r.velocity for r in arc_train.chain.rows]))
    path = []
    for k in range(2000):  # a second of the move, then holding where it was sent
        loop.set_goal((traj.sample(np.array([min(k, 1000) * DT]))[0][0] - offset) / ratio)
        plant.step(DT, loop.step(plant.position(), plant.velocity()))
        path.append(plant.joint_position())
    plant.close()
    return np.array(path), counting.mass_matrices


def test_the_plant_reusing_its_mass_matrix_follows_the_one_computed_every_step(arc_train, monkeypatch):
    exact, every = _plant_run(arc_train, monkeypatch, 0.0)
    reused, fewer = _plant_run(arc_train, monkeypatch, TOLERANCE)
    assert every == len(exact) and fewer < 0.6 * every  # it really was reused
    assert np.abs(exact[-1] - exact[0]).max() > 0.1  # along a real move
    # at every step, within a hundredth of an encoder tick (1.5e-3 rad) of the exact matrix's run
    assert np.abs(reused - exact).max() < 1.5e-5


def _servo_sim(delay_ms: float = 0.0, control_hz: float = 500.0):
    backend = {"kind": "pybullet", "physics_hz": 1000, "servo_model": "datasheet",
               "rig": str(REPO / "hil_configs" / "lab_real.yaml"), "transport_delay_ms": delay_ms}
    cfg = load_trial_config(SERVO_SIM, {"control_hz": control_hz, "backend": backend})
    return make_backend(cfg, get_robot(cfg.robot)), cfg.control_period


def _plan(arc_train, period: float, cycles: int):
    vel = np.array([r.velocity for r in arc_train.chain.rows]) * 0.5
    traj = LSPB(arc_train.chain.home, arc_train.ik(TARGET_1), vel, vel * 2)
    q, qd, _ = traj.sample(np.arange(cycles) * period)
    return q, qd


@pytest.mark.parametrize("delay_ms, control_hz", [(0.0, 500.0), (3.0, 1000.0)])
def test_a_block_of_the_servo_sim_equals_the_same_cycles_one_by_one(arc_train, delay_ms, control_hz,
                                                                     block_equals_cycles):
    """The lab's servo table and train sensor with its host loop, a transport delay or none: blocks
    give every reading of the cycles one by one, bit for bit, and a rewind puts the sim back
    where it was read, from where it goes on as it did."""
    k = 900
    one, period = _servo_sim(delay_ms, control_hz)
    block, _ = _servo_sim(delay_ms, control_hz)
    q, qd = _plan(arc_train, period, k)
    with one, block:
        one.enable()
        block.enable()
        rows, ends = block_equals_cycles(one, block, q, qd, period, 200)
        assert np.abs(rows[-1][1] - rows[0][1]).max() > 0.01  # it moved
        assert np.array_equal(one.read().position, block.read().position)
        # rewind into the last block, then on cycle by cycle: the same readings as before
        a, j = 800, 60
        st = block.rewind(j)
        assert st.time == rows[a + j][0] and block.now() == st.time
        for i in range(a + j, k):
            if i > a + j:
                st = block.read()
            assert np.array_equal(st.position, rows[i][1]) and np.array_equal(st.effort, rows[i][3]), i
            block.command(q[i], qd[i])
            block.wait_until(ends[i])


def test_the_servo_sim_runs_blocks_and_trips_where_checking_every_cycle_trips(monkeypatch):
    """A plan aimed through the gantry on the servo-model sim, in blocks and cycle by cycle: the
    same trip at the same cycle with the same cause, and the same log to the end of the hold."""
    from test_interlock_trial import INTO_GANTRY

    import bench.core.runner as runner_module
    from bench.core.log import TrialLog
    from bench.trial.plan import interlocks_for, plan, prepare

    cfg = TrialConfig.model_validate({**INTO_GANTRY, "backend": {"kind": "pybullet", "servo_model": "datasheet",
                                                                 "rig": str(REPO / "hil_configs" / "lab_real.yaml")}})

    def run(blocks: bool) -> TrialLog:
        prep = prepare(cfg)
        with make_backend(prep.config, prep.robot) as act:
            assert runner_module.runs_blocks(act, interlocks_for(prep, act))
            monkeypatch.setattr(runner_module, "runs_blocks", lambda a, i: blocks)
            log = TrialLog(list(prep.robot.joint_names))
            result = runner_module.Runner(act, cfg.control_period, interlocks_for(prep, act)).run(
                plan(prep, act.read().position, act.limits.velocity), log)
            monkeypatch.undo()
        assert not result.completed and result.reason.startswith("interlock gantry_clearance")
        return log

    cycles, blocks = run(False), run(True)
    assert [(e.kind, e.message) for e in blocks.events] == [(e.kind, e.message) for e in cycles.events]
    assert len(blocks) == len(cycles)
    for field in ("time", "q_cmd", "qd_cmd", "q", "qd", "effort"):
        assert np.array_equal(getattr(blocks, field), getattr(cycles, field)), field


def test_the_loops_joint_gains_are_its_torques_slope_in_position_and_speed():
    """What a coarse integrator takes implicitly is the loop's own slope: a few ticks more of joint
    position take the P gain's torque off, at any transmission; a current limit met, the slope is
    gone and the loop says so."""
    n = 4
    params = ServoParams.datasheet([XM430_W350] * n, gains=[(800, 0, 0), (640, 0, 120), (800, 0, 0), (1500, 0, 0)])
    ratio, offset = np.array([1.0, 0.05, -0.01, 1.0]), np.array([0.0, 0.3, 0.0, -0.2])
    servos = ServoArray(params)
    q = offset + ratio * 0.1
    servos.reset(np.full(n, 0.1))
    loop = PositionLoop(servos, 0.005, ratio, offset)
    loop.set_goal(np.full(n, 0.1))
    gain, derivative = loop.joint_gains()
    tick = 2 * np.pi / 4096 * np.abs(ratio)
    base = loop.step_joint(q, np.zeros(n))
    loop.set_goal(np.full(n, 0.1))
    moved = loop.step_joint(q + 3 * tick * np.sign(ratio), np.zeros(n))
    slope = -(moved - base) / (3 * tick * np.sign(ratio))
    assert np.allclose(slope[[0, 2, 3]], gain[[0, 2, 3]], rtol=0.02), (slope, gain)
    assert derivative[1] > 0 and not derivative[[0, 2, 3]].any()  # D only where the gain has one
    assert loop.unsaturated()[[0, 2]].all()
    loop.set_goal(np.full(n, 1.6))  # 1.5 rad of error: the PWM at its cap
    loop.step_joint(q, np.zeros(n))
    assert not loop.unsaturated().any()
