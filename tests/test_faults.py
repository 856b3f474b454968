"""Fault wrappers: each one's effect, with the numbers it should have, on the sim backend
(and on a kinematic stand-in where physics would only blur the number)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.config.models import TrialConfig
from bench.core.log import TrialLog
from bench.core.outcome import settled_position
from bench.core.runner import Runner, Segment
from bench.core.truth import GroundTruth, settled_truth
from bench.faults import FAULTS, Backlash, Deadband, FaultWrapper, apply_faults, parse_faults
from bench.kinematics.arc_train import JOINTS, TARGET_1, epsilon_from_d2, train_pose
from bench.rig.backends import make_backend
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from drivers import Actuators, BackendSetupError, JointState
from trajectories import LSPB

from stand_ins import Kinematic

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
SIM_TRACKING_DEG = 0.02  # the simulator's own settled error at Target 1 (theta5: 0.014°)
DEG = np.pi / 180


def fast_config(faults: list[dict], **changes) -> TrialConfig:
    data = yaml.safe_load(FAST.read_text())
    data.update(changes)
    return TrialConfig.model_validate({**data, "faults": faults})


def run_with_truth(cfg: TrialConfig, tmp_path: Path):
    """A trial with the faults of ``cfg``, its log, the ground truth and the fault stack."""
    holder = {}

    def wrap(truth: GroundTruth):  # the trial's own ground truth around the fault stack
        holder["stack"] = truth.actuators
        holder["truth"] = truth
        return truth

    res = run_trial(prepare(cfg), tmp_path, TrialHooks(report=False, wrap=wrap))
    return res, TrialLog.load(res.log_path), holder["truth"], holder["stack"]


def move(act: Actuators, q_to: np.ndarray, settle: float = 0.3, dt: float = 0.002) -> TrialLog:
    """Drive ``act`` from where it reads to ``q_to`` with an LSPB and a settle."""
    q0 = act.read().position
    v = np.asarray(act.limits.velocity) * 0.5
    log = TrialLog(list(act.joint_names))
    Runner(act, dt).run([Segment("move", LSPB(q0, q_to, v, 2 * v), settle)], log)
    return log


@pytest.fixture(scope="module")
def target_prep():
    return prepare(fast_config([]))


# ---------------------------------------------------------------------------
# Tolerance faults
# ---------------------------------------------------------------------------


def test_deadband_leaves_every_revolute_joint_within_tolerance(tmp_path, target_prep):
    cfg = fast_config([{"name": "deadband", "joints": "all", "tol_deg": 0.29}], seed=7)
    res, log, truth, stack = run_with_truth(cfg, tmp_path)
    assert isinstance(stack, Deadband) and res.completed
    err = settled_truth(log, truth) - target_prep.q_insert
    kinds = [r.kind for r in target_prep.robot.chain.rows]
    rev = np.array([k == "revolute" for k in kinds])
    err_deg = np.degrees(err[rev])
    assert np.all(np.abs(err_deg) <= 0.29 + SIM_TRACKING_DEG), err_deg
    assert np.sum(np.abs(err_deg) > 0.05) >= 3  # not all at zero: real offsets were drawn
    # the error is the drawn offset, up to the simulator's own tracking error
    offset = stack.offset
    assert np.allclose(err_deg, np.degrees(offset[rev]), atol=SIM_TRACKING_DEG)
    assert np.all(np.abs(np.degrees(offset[rev])) <= 0.29)
    # the prismatic joints: the same servo angle through a 10 mm pinion (±0.0506 mm)
    assert np.all(np.abs(err[~rev]) <= 0.0506e-3 + 2e-6)
    # with nothing biased the reads agree with the truth
    assert np.allclose(settled_position(log, "insert"), settled_truth(log, truth), atol=1e-12)


def test_deadband_draws_anew_for_each_move_and_eases_it_in():
    base = Kinematic()  # velocity limits 1 rad/s: the offset eases at 0.1 rad/s
    act = Deadband(base, np.full(len(JOINTS), 0.29 * DEG), np.random.default_rng(1))
    act.enable()
    goal = np.zeros(len(JOINTS))
    applied, offsets = [], []
    for k in range(3):
        moves = list(np.linspace(0.0, 0.1, 5) + k)  # a move, then a hold long enough to settle
        for x in moves + [moves[-1]] * 60:
            goal[:] = x
            act.command(goal)
            applied.append(base.q - goal)
            base.wait_until(base.t + 0.002)
        offsets.append(base.q - goal)
        assert np.allclose(act.offset, offsets[-1])
    offsets = np.array(offsets)
    assert np.all(np.abs(offsets) <= 0.29 * DEG)
    assert not np.allclose(offsets[0], offsets[1]) and not np.allclose(offsets[1], offsets[2])
    assert len(np.unique(np.round(offsets, 12))) == offsets.size  # independent per joint and move
    # never a step: the applied offset changes by at most 0.1 rad/s × 2 ms a cycle
    assert np.abs(np.diff(np.array(applied), axis=0)).max() <= 0.1 * 0.002 + 1e-12


def test_bias_shifts_the_achieved_joint_by_minus_bias(tmp_path, target_prep):
    cfg = fast_config([{"name": "bias", "joints": ["theta5"], "bias_deg": 1.5},
                       {"name": "bias", "joints": ["d9"], "bias_mm": 2.0}])
    res, log, truth, _ = run_with_truth(cfg, tmp_path)
    q_goal = target_prep.q_insert
    true_err = settled_truth(log, truth) - q_goal
    read_err = settled_position(log, "insert") - q_goal
    i5, i9 = JOINTS.index("theta5"), JOINTS.index("d9")
    assert np.degrees(true_err[i5]) == pytest.approx(-1.5, abs=SIM_TRACKING_DEG)
    assert true_err[i9] == pytest.approx(-2.0e-3, abs=2e-6)
    # the biased encoders read the goal: the trial's own (measured) outcome sees nothing
    assert np.degrees(abs(read_err[i5])) < SIM_TRACKING_DEG and abs(read_err[i9]) < 2e-6
    others = [i for i in range(len(JOINTS)) if i not in (i5, i9)]
    assert np.all(np.abs(true_err[others]) < SIM_TRACKING_DEG * DEG + 1e-6)


def test_backlash_leaves_a_prismatic_joint_off_by_the_play_after_a_reversal(target_prep):
    play = 0.8e-3
    backend = make_backend(target_prep.config, target_prep.robot)
    names = list(JOINTS)
    i9 = names.index("d9")
    spec = parse_faults([{"name": "backlash", "joints": ["d9"], "play_mm": 0.8}], names)
    with apply_faults(backend, spec, np.random.default_rng(0)) as act:
        assert isinstance(act, Backlash)
        home = act.read().position
        up = home.copy()
        up[i9] += 0.010
        move(act, up)  # forward: the output follows the motor
        assert backend.read().position[i9] == pytest.approx(up[i9], abs=2e-6)
        down = home.copy()
        down[i9] += 0.004
        move(act, down)  # reversed: the output trails by the play
        assert backend.read().position[i9] - down[i9] == pytest.approx(play, abs=2e-5)
        assert act.read().position[i9] == pytest.approx(down[i9], abs=2e-5)  # the motor reads right
        up2 = home.copy()
        up2[i9] += 0.006
        move(act, up2)  # forward again: the play is taken up, exact again
        assert backend.read().position[i9] == pytest.approx(up2[i9], abs=2e-6)


def test_backlash_takes_up_the_play_before_the_output_moves():
    act = Backlash(Kinematic(), np.r_[np.zeros(7), 1e-3, 0.0], np.ones(len(JOINTS)))
    act.enable()
    q = np.zeros(len(JOINTS))
    outputs = []
    for x in (2e-3, 1.5e-3, 1.0e-3, 0.5e-3, 1.2e-3):
        q[7] = x
        act.command(q)
        outputs.append(act.unwrapped.q[7])
    # forward to 2 mm; back 0.5 mm and 1 mm: still in the play; back to 0.5 mm: pulled at +1 mm;
    # forward to 1.2 mm: inside the play again
    assert outputs == pytest.approx([2e-3, 2e-3, 2e-3, 1.5e-3, 1.5e-3])


def test_quantisation_rounds_reads_and_commands_to_ticks():
    step = 2 * np.pi / 4096
    spec = parse_faults([{"name": "quantisation", "joints": "revolute"}], JOINTS)
    base = Kinematic()
    act = apply_faults(base, spec, np.random.default_rng(0))
    act.enable()
    goal = np.linspace(0.01, 0.3, len(JOINTS))
    act.command(goal)
    rev = slice(0, 7)
    assert np.allclose(base.q[rev] / step, np.round(base.q[rev] / step), atol=1e-9)
    assert np.all(np.abs(base.q[rev] - goal[rev]) <= step / 2 + 1e-12)
    assert np.array_equal(base.q[7:], goal[7:])  # prismatic joints untouched
    r = act.read().position
    assert np.allclose(r[rev] / step, np.round(r[rev] / step), atol=1e-9)


def test_noise_has_the_configured_std(target_prep):
    names = list(JOINTS)
    spec = parse_faults([{"name": "noise", "joints": "all", "std_deg": 0.2, "std_mm": 0.1}], names)
    backend = make_backend(target_prep.config, target_prep.robot)
    with apply_faults(backend, spec, np.random.default_rng(3)) as act:
        n = 3000
        err = np.array([act.read().position - backend.read().position for _ in range(n)])
    std = err.std(axis=0)
    assert np.degrees(std[:7]) == pytest.approx(np.full(7, 0.2), rel=0.06)
    assert std[7:] == pytest.approx(np.full(2, 0.1e-3), rel=0.06)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * std / np.sqrt(n))


# ---------------------------------------------------------------------------
# Torque limit
# ---------------------------------------------------------------------------


def gravity_torques(q: np.ndarray) -> np.ndarray:
    from bench.scene.room import URDF_DIR
    from drivers.quiet import quiet_pybullet

    pb = quiet_pybullet()
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(URDF_DIR / "arc_train.urdf"), useFixedBase=True,
                           flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        return np.array(pb.calculateInverseDynamics(body, q.tolist(), [0.0] * 9, [0.0] * 9,
                                                    physicsClientId=c))
    finally:
        pb.disconnect(c)


def test_torque_limit_below_gravity_load_stalls_the_joint_and_fails(tmp_path, arc_train):
    q = arc_train.ik(TARGET_1)
    tau = gravity_torques(q)
    effort = np.array([r.effort for r in arc_train.chain.rows])
    load = np.abs(tau) / effort
    j = int(np.argmax(load))  # the joint whose gravity load is nearest its limit
    name = JOINTS[j]
    assert arc_train.chain.rows[j].kind == "revolute" and load[j] > 0.3
    scale = round(0.5 * load[j], 3)  # half the torque gravity needs there
    faults = [{"name": "torque_limit", "joints": [name], "scale": scale}]
    # with the interlocks on, the sagging arm trips one and the trial stops: failed
    guarded = run_trial(prepare(fast_config(faults)), tmp_path, TrialHooks(report=False))
    assert not guarded.completed and not guarded.passed and "interlock" in guarded.reason
    # without them, the trial runs to the end with the joint stalled and fails the acceptance
    cfg = fast_config(faults, safety={"enabled": False})
    res, log, truth, stack = run_with_truth(cfg, tmp_path)
    assert stack.unwrapped.limits.effort[j] == pytest.approx(scale * effort[j])
    err = settled_truth(log, truth) - q
    assert abs(np.degrees(err[j])) > 5.0  # stalled far from its goal
    others = [i for i in range(7) if i != j]
    assert np.all(np.abs(np.degrees(err[others])) < 1.0)
    assert res.completed and not res.passed
    # lag: the weak joint trails its command during the approach far more than the others
    approach = log.segment == 0
    lag = np.degrees(np.abs(log.q_cmd[approach] - log.q[approach]).max(axis=0))
    assert lag[j] > 5.0 and lag[j] > 5 * np.max(lag[others])
    # enough torque (but less than nominal): the same joint arrives
    res_ok = run_trial(prepare(fast_config([{"name": "torque_limit", "joints": [name],
                                             "scale": round(1.6 * load[j], 3)}])), tmp_path, TrialHooks(report=False))
    assert res_ok.passed


def test_torque_limit_needs_a_backend_that_can_limit_effort():
    spec = parse_faults([{"name": "torque_limit", "joints": ["theta5"], "scale": 0.2}], JOINTS)
    with pytest.raises(BackendSetupError, match=r"set_effort_limit.*Kinematic has none"):
        apply_faults(Kinematic(), spec, np.random.default_rng(0))


# ---------------------------------------------------------------------------
# Communication and sensor faults
# ---------------------------------------------------------------------------


def test_dropped_status_holds_the_last_sample_flagged_stale():
    base = Kinematic()
    act = apply_faults(base, parse_faults([{"name": "dropped_status", "joints": ["theta4", "d10"],
                                            "prob": 0.3}], JOINTS), np.random.default_rng(5))
    act.enable()
    n, stale, last = 2000, {"theta4": 0, "d10": 0}, None
    for k in range(n):
        base.q[:] = k
        st = act.read()
        for name in ("theta4", "d10"):
            j = JOINTS.index(name)
            if f"stale:{name}" in st.flags:
                stale[name] += 1
                assert st.position[j] == last.position[j] != k
            else:
                assert st.position[j] == k
        assert st.position[0] == k and not any("theta3" in f for f in st.flags)
        last = st
    assert stale["theta4"] / n == pytest.approx(0.3, abs=0.04)
    assert stale["d10"] / n == pytest.approx(0.3, abs=0.04)


class KeepsItsReading(Kinematic):
    """As the Dynamixel driver and the servo sim: keeps the reading it returned, to steer by it."""

    kept: list[tuple[JointState, np.ndarray]]

    def read(self) -> JointState:
        st = super().read()
        self.kept.append((st, st.position.copy()))
        return st


#: Faults that never rewrite a reading (they act on the bus, the physics or the goals).
NOT_ON_READINGS = {"corrupt_crc", "torque_limit", "deadband", "contact", "friction_drift", "stuck"}


@pytest.mark.parametrize("name", sorted(set(FAULTS) - NOT_ON_READINGS))
def test_no_fault_writes_into_the_reading_it_received(name):
    """What a fault changes it changes in a new reading: the backend's own stays as it returned it."""
    base = KeepsItsReading(kept=[])
    spec = {"name": name, **({"prob": 1.0} if "prob" in FAULTS[name].valid_parameters else {})}
    act = apply_faults(base, parse_faults([spec], JOINTS), np.random.default_rng(3))
    act.enable()
    changed = 0
    for k in range(40):
        base.q[:] = 0.01 * k
        base.t = 0.002 * k
        st = act.read()
        changed += st is not base.kept[-1][0]
        act.command(base.q)
    assert changed > 0  # the fault did rewrite readings
    for st, position in base.kept:
        assert np.array_equal(st.position, position) and st.flags == ()
        assert not st.position.flags.writeable


def test_a_reading_cannot_be_edited_nor_made_writable():
    st = Kinematic().read()
    with pytest.raises(ValueError):
        st.position[0] = 1.0
    with pytest.raises(ValueError):
        st.velocity.flags.writeable = True
    with pytest.raises(AttributeError):
        st.effort = np.ones(len(JOINTS))
    q = np.zeros(len(JOINTS))
    mine = JointState(0.0, q, q, q)
    q[0] = 1.0  # the arrays it was built from stay the builder's; the reading keeps its copy
    assert mine.position[0] == 0.0 and q.flags.writeable


def test_late_status_returns_an_older_sample_flagged_late():
    base = Kinematic()
    act = apply_faults(base, parse_faults([{"name": "late_status", "prob": 1.0, "delay_ms": 4}],
                                          JOINTS), np.random.default_rng(0))
    for k in range(10):
        base.t = k * 0.002
        base.q[:] = k
        st = act.read()
        if k >= 2:
            assert np.all(st.position == k - 2) and st.time == pytest.approx(k * 0.002)
            assert "late:train" in st.flags


def test_status_faults_go_to_the_emulator_when_the_backend_has_one():
    from drivers.emulator import BusFaults

    faults = BusFaults()
    base = Kinematic(fault_hooks=faults)
    specs = parse_faults([{"name": "dropped_status", "prob": 0.2},
                          {"name": "corrupt_crc", "prob": 0.1},
                          {"name": "late_status", "prob": 1.0, "delay_ms": 3.0},
                          {"name": "dropped_status", "joints": ["train"], "prob": 0.5}], JOINTS)
    act = apply_faults(base, specs, np.random.default_rng(0))
    assert (faults.drop_prob, faults.corrupt_crc_prob, faults.delay_s) == (0.2, 0.1, 0.003)
    # one joint cannot be dropped on the bus: that one is the wrapper-level fault
    assert type(act).__name__ == "DroppedStatus"
    act.close()
    assert (faults.drop_prob, faults.corrupt_crc_prob, faults.delay_s) == (0.0, 0.0, 0.0)


def test_crc_faults_are_refused_on_the_sim_backend(target_prep):
    backend = make_backend(target_prep.config, target_prep.robot)
    try:
        spec = parse_faults([{"name": "corrupt_crc", "prob": 0.1}], JOINTS)
        with pytest.raises(BackendSetupError, match="corrupt_crc needs a backend with emulator hooks.*"
                                                     "PyBulletActuators has none"):
            apply_faults(backend, spec, np.random.default_rng(0))
        spec = parse_faults([{"name": "dropped_status", "level": "bus"}], JOINTS)
        with pytest.raises(BackendSetupError, match="level: wrapper or auto"):
            apply_faults(backend, spec, np.random.default_rng(0))
    finally:
        backend.close()


def test_ultrasonic_dropouts_mark_samples_stale_and_hold_the_reading():
    base = Kinematic()
    act = apply_faults(base, parse_faults([{"name": "ultrasonic_dropout", "prob": 0.25}], JOINTS),
                       np.random.default_rng(2))
    i = JOINTS.index("train")
    n, stale, last = 2000, 0, None
    for k in range(n):
        base.q[:] = 0.5 + 1e-4 * k
        st = act.read()
        if "stale:train" in st.flags:
            stale += 1
            assert st.position[i] == last
        else:
            assert st.position[i] == base.q[i]
        assert st.position[1] == base.q[1]  # only the train
        last = st.position[i]
    assert stale / n == pytest.approx(0.25, abs=0.03)


def test_ultrasonic_stuck_repeats_one_reading_without_a_flag():
    base = Kinematic()
    act = apply_faults(base, parse_faults([{"name": "ultrasonic_stuck", "at_s": 0.01, "for_s": 0.02}],
                                          JOINTS), np.random.default_rng(0))
    seen = []
    for k in range(25):
        base.t = k * 0.002
        base.q[0] = 0.4 + 0.01 * k
        st = act.read()
        seen.append(st.position[0])
        assert not st.flags
    seen = np.array(seen)
    assert np.all(seen[5:15] == seen[5]) and seen[5] == pytest.approx(0.45)
    assert seen[4] == pytest.approx(0.44) and seen[15] == pytest.approx(0.55)


def test_ultrasonic_noise_is_gaussian_in_d2(target_prep):
    backend = make_backend(target_prep.config, target_prep.robot)
    spec = parse_faults([{"name": "ultrasonic_noise", "std_mm": 2.0}], JOINTS)
    with apply_faults(backend, spec, np.random.default_rng(4)) as act:
        eps_true = backend.read().position[0]
        reads = np.array([act.read().position for _ in range(3000)])
    d2 = train_pose(reads[:, 0]).d2 - train_pose(eps_true).d2
    assert d2.std() == pytest.approx(2e-3, rel=0.06) and abs(d2.mean()) < 2e-4
    assert np.allclose(epsilon_from_d2(train_pose(reads[:, 0]).d2), reads[:, 0])
    assert np.all(reads[:, 1:] == reads[0, 1:])  # the other joints are untouched


# ---------------------------------------------------------------------------
# Stacking, generators, validation
# ---------------------------------------------------------------------------


def test_faults_stack_as_actuators_and_unwrap_to_the_backend():
    base = Kinematic()
    specs = parse_faults([{"name": "deadband"}, {"name": "bias", "bias_deg": 0.1},
                          {"name": "noise"}, {"name": "ultrasonic_noise"}], JOINTS)
    act = apply_faults(base, specs, np.random.default_rng(0))
    assert isinstance(act, FaultWrapper) and isinstance(act, Actuators)
    assert act.unwrapped is base
    chain = []
    a = act
    while isinstance(a, FaultWrapper):
        chain.append(type(a).__name__)
        a = a.actuators
    assert chain == ["UltrasonicNoise", "Noise", "Bias", "Deadband"]  # first fault innermost
    with act:
        act.enable()
        assert act.enabled and base.enabled
    assert base._closed


def test_adding_a_fault_does_not_change_another_fault_draws():
    def offsets(specs):
        base = Kinematic()
        act = apply_faults(base, parse_faults(specs, JOINTS), np.random.default_rng(11))
        act.enable()
        out = []
        for x in [0.0] * 30 + [0.1, 0.2] + [0.2] * 30 + [0.3] * 30:
            act.command(np.full(len(JOINTS), x))
            base.wait_until(base.t + 0.002)
            out.append(base.q - x)
        return np.array(out)

    alone = offsets([{"name": "deadband"}])
    assert np.abs(alone).max() > 0.1 * DEG  # offsets were drawn
    with_noise_first = offsets([{"name": "noise"}, {"name": "dropped_status"}, {"name": "deadband"}])
    assert np.array_equal(alone, with_noise_first)
    other_seed = apply_faults(Kinematic(), parse_faults([{"name": "deadband"}], JOINTS),
                              np.random.default_rng(12))
    other_seed.enable()
    for _ in range(30):
        other_seed.command(np.zeros(len(JOINTS)))
        other_seed.unwrapped.wait_until(other_seed.unwrapped.t + 0.002)
    assert not np.array_equal(other_seed.unwrapped.q, alone[29])  # the draws do follow the seed


@pytest.mark.parametrize("fault, words", [
    ({"name": "deadbnd"}, ["unknown fault 'deadbnd'", "valid faults: backlash, bias, contact, corrupt_crc, "
                           "deadband, dropped_status, friction_drift, late_status, noise, quantisation, "
                           "stuck, torque_limit, ultrasonic_dropout, ultrasonic_noise, ultrasonic_stuck"]),
    ({"name": "deadband", "tol": 0.3}, ["unknown parameter 'tol'",
                                        "valid parameters of deadband: joints, tol_deg, tol_mm"]),
    ({"name": "torque_limit", "joints": ["theta9"], "scale": 0.2},
     ["unknown joint 'theta9'", "joints are train, theta3, theta4, theta5, theta6, theta7, theta8, "
                                "d9, d10, or one of all, revolute, prismatic"]),
    ({"name": "torque_limit", "joints": ["theta5"], "scale": 1.5}, ["scale must be <= 1, got 1.5"]),
    ({"name": "torque_limit", "scale": 0.5}, ["joints must be given"]),
    ({"name": "backlash", "joints": ["d9"], "play_deg": 1.0}, ["play_deg applies to revolute joints"]),
    ({"name": "ultrasonic_noise", "joints": ["train"]}, ["unknown parameter 'joints'",
                                                          "valid parameters of ultrasonic_noise: std_mm"]),
    ({"name": "late_status", "level": "wire"}, ["level must be one of auto, wrapper, bus"]),
    ({"tol_deg": 0.3}, ["missing 'name'", "valid faults:"]),
])
def test_bad_faults_are_refused_listing_what_is_valid(fault, words):
    with pytest.raises(ValueError) as e:
        parse_faults([{"name": "noise"}, fault], JOINTS)
    assert str(e.value).startswith("faults[1]")
    for w in words:
        assert w in str(e.value)


def test_every_fault_parses_with_its_defaults_and_documents_its_parameters():
    required = {"contact": {"torque_nm": 0.3}}  # a contact's push has no default
    for name, fdef in FAULTS.items():
        raw = {"name": name, **required.get(name, {})}
        if fdef.joints == "":
            raw["joints"] = ["theta5"]
        spec = parse_faults([raw], JOINTS)[0]
        assert spec.name == name and spec.joints
        assert set(spec.as_dict()) - {"name", "joints"} == {p.name for p in fdef.params}
        assert fdef.summary


def test_the_docs_table_lists_every_fault_with_its_parameters():
    """docs/campaigns.md's table of faults is written by hand: it must not fall behind the registry."""
    text = (REPO / "docs" / "campaigns.md").read_text().split("## The faults", 1)[1].split("\n## ", 1)[0]
    rows = {m.group(1): m.group(0) for m in re.finditer(r"^\| `(\w+)` \|.*$", text, re.M)}
    assert sorted(rows) == sorted(FAULTS)
    for name, fdef in FAULTS.items():
        assert all(f"`{p.name}`" in rows[name] for p in fdef.params), rows[name]


@pytest.mark.parametrize("fault, words", [
    ({"name": "deadbnd"}, "unknown fault 'deadbnd'; valid faults: backlash, bias"),
    ({"name": "deadband", "tol": 0.3}, "unknown parameter 'tol'; valid parameters of deadband: joints, tol_deg, tol_mm"),
    ({"name": "bias", "joints": ["theta9"]}, "unknown joint 'theta9'; joints are train, theta3"),
])
def test_cli_trial_refuses_bad_faults_in_one_line(tmp_path, fault, words):
    data = yaml.safe_load(FAST.read_text())
    data["faults"] = [fault]
    path = tmp_path / "trial.yaml"
    path.write_text(yaml.safe_dump(data))
    runs = tmp_path / "runs"
    out = subprocess.run([HILBENCH, "trial", str(path), "--out", str(runs), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0] and "faults[0]" in lines[0], out.stderr
    assert not runs.exists()
