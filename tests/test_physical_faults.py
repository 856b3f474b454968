"""Physical faults (bench/faults/physical.py): a contact pushing on a joint, a friction that drifts,
a joint that stops following. Each is checked where it acts: in the servo-model sim and the emulated
rig (the real Dynamixel driver against the project's emulator, in this process and in a child one),
PyBullet's ideal motors where they have it, and refused in one line where a backend cannot host it.
The numbers compare the same motion with and without the fault, on the same backend."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.core.runner import Runner, Segment
from bench.faults import Contact, FrictionDrift, Stuck, apply_faults, parse_faults
from bench.kinematics.arc_train import JOINTS
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend, make_dynamixel_backend
from bench.rig.emulated import EmulatedRig, EmulatorProcess
from drivers import Actuators, BackendSetupError
from drivers.clock import VirtualClock
from trajectories import LSPB

from stand_ins import Kinematic

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "hil_configs"
LAB = CONFIGS / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
DEG = math.pi / 180
THETA5, THETA4 = JOINTS.index("theta5"), JOINTS.index("theta4")
#: theta4's gearbox on the emulated rig: the worn rig's friction (servo_models/emulated_worn_rig.yaml).
WORN_THETA4 = {"coulomb_nm": 0.128, "viscous_nms": 0.051, "stribeck_nm": 0.129, "stribeck_velocity_rads": 0.1}


def sim(config: str) -> Actuators:
    cfg = load_trial_config(CONFIGS / config)
    return make_backend(cfg, get_robot(cfg.robot))


def run_move(act: Actuators, joint: int, delta: float, settle: float, period: float,
             speed: float = 0.3, start: np.ndarray | None = None) -> TrialLog:
    """``joint`` moves by ``delta`` from ``start`` (default: where ``act`` first reads; an LSPB at
    ``speed`` × its velocity limit) and holds for ``settle`` s, every other joint holding its start;
    the stack is closed after."""
    try:
        act.enable()
        q0 = act.read().position.copy()  # the first read: the faults' clock starts here
        q1 = q0.copy() if start is None else np.asarray(start, dtype=float).copy()
        q1[joint] += delta
        v = np.asarray(act.limits.velocity) * speed
        log = TrialLog(list(act.joint_names))
        Runner(act, period).run([Segment("move", LSPB(q0, q1, v, 2 * v), settle)], log)
        return log
    finally:
        act.close()


def error_deg(log: TrialLog, joint: int) -> np.ndarray:
    """The joint's tracking error (measured − commanded) at each cycle, in degrees."""
    return (log.q[:, joint] - log.q_cmd[:, joint]) / DEG


def held(log: TrialLog, settle_cycles: int) -> slice:
    """The cycles of the hold at the end of a move (the last ``settle_cycles``, the closing read aside)."""
    return slice(len(log) - 1 - settle_cycles, len(log) - 1)


class Pushable(Kinematic):
    """A kinematic arc-train stand-in (joints where last commanded) whose physics records what the
    faults ask of it: each load and friction scale with the backend's time, and every goal."""

    def __init__(self, q0: np.ndarray | None = None) -> None:
        super().__init__(q0)
        self.calls: list[tuple[str, float, int, float]] = []
        self.goals: list[np.ndarray] = []

    def set_external_effort(self, joint: int, effort: float) -> None:
        self.calls.append(("load", self.t, joint, effort))

    def set_friction_scale(self, joint: int, scale: float) -> None:
        self.calls.append(("friction", self.t, joint, scale))

    def _command(self, position, velocity) -> None:
        self.goals.append(position.copy())
        super()._command(position, velocity)


def stack(base: Actuators, *faults: dict) -> Actuators:
    return apply_faults(base, parse_faults(list(faults), JOINTS), np.random.default_rng(0))


# ---------------------------------------------------------------------------
# Validation: one line per bad input, saying what is valid
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("fault, says", [
    ({"name": "contact", "joints": ["theta5"]}, "revolute joint theta5 needs torque_nm, the torque (N·m)"),
    ({"name": "contact", "joints": ["d10"], "torque_nm": 0.3}, "torque_nm applies to revolute joints"),
    ({"name": "contact", "joints": ["theta5"], "force_n": 2.0}, "force_n applies to prismatic joints"),
    ({"name": "contact", "joints": ["theta5", "d10"], "torque_nm": 0.3}, "prismatic joint d10 needs force_n"),
    ({"name": "contact", "joints": ["theta5", "d10"], "torque_nm": 0.3, "force_n": 2.0, "past_deg": 5.0},
     "prismatic joint d10 needs past_mm too"),
    ({"name": "contact", "torque_nm": 0.3}, "joints must be given"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": "0.3 Nm"}, "torque_nm must be a number (N·m)"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": 250}, "torque_nm must be <= 100, got 250"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": math.inf}, "torque_nm must be finite"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": -1}, "from_s must be >= 0"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "for_s": 0}, "for_s must be > 0, got 0"),
    ({"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "at_s": 1},
     "unknown parameter 'at_s'; valid parameters of contact: for_s, force_n, from_s, joints, past_deg, "
     "past_mm, torque_nm"),
    ({"name": "friction_drift", "factor": 2.5}, "joints must be given"),
    ({"name": "friction_drift", "joints": ["theta4"], "factor": -0.5}, "factor must be >= 0, got -0.5"),
    ({"name": "friction_drift", "joints": ["theta4"], "factor": 50}, "factor must be <= 20, got 50"),
    ({"name": "friction_drift", "joints": ["theta4"], "over_s": -2}, "over_s must be >= 0, got -2"),
    ({"name": "friction_drift", "joints": ["theta4"], "scale": 2},
     "unknown parameter 'scale'; valid parameters of friction_drift: factor, from_s, joints, over_s"),
    ({"name": "stuck", "from_s": 1.0}, "joints must be given"),
    ({"name": "stuck", "joints": ["theta9"]}, "unknown joint 'theta9'"),
    ({"name": "stuck", "joints": ["theta4"], "from_s": "soon"}, "from_s must be a number (s), got 'soon'"),
    ({"name": "stuck", "joints": ["theta4"], "for_s": -1}, "for_s must be > 0, got -1"),
])
def test_bad_physical_faults_are_refused_in_one_line(fault, says):
    with pytest.raises(ValueError) as e:
        parse_faults([fault], JOINTS)
    assert str(e.value).startswith(f"faults[0] ({fault['name']}): ") and says in str(e.value)
    assert "\n" not in str(e.value)


def test_the_yaml_of_each_fault_parses_in_its_units():
    contact, drift, stuck = parse_faults([
        {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 2.0},
        {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5, "over_s": 4.0},
        {"name": "stuck", "joints": ["theta6"], "from_s": 1.5}], JOINTS)
    assert contact.si("torque_nm") == 0.3 and contact.params["from_s"] == 2.0
    assert contact.params["for_s"] is None  # to the end of the trial
    assert (drift.params["factor"], drift.params["from_s"], drift.params["over_s"]) == (2.5, 0.0, 4.0)
    assert stuck.joints == ("theta6",) and stuck.params["from_s"] == 1.5
    slide, = parse_faults([{"name": "contact", "joints": ["d10"], "force_n": -2.0, "past_mm": 12.5}], JOINTS)
    assert slide.si("force_n") == -2.0 and slide.si("past_mm") == pytest.approx(0.0125)


# ---------------------------------------------------------------------------
# When each fault acts, on the trial's clock (the kinematic stand-in records every call)
# ---------------------------------------------------------------------------


def test_a_contact_pushes_from_from_s_for_for_s_and_lets_go_when_the_stack_closes():
    base = Pushable()
    act = stack(base, {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 0.5,
                       "for_s": 0.25})
    base.t = 10.0  # the trial's clock starts at the first read, not at the backend's zero
    for _ in range(600):
        act.read()
        base.t += 0.002
    assert [c[0] for c in base.calls] == ["load", "load"]
    (_, on, j_on, push), (_, off, j_off, free) = base.calls
    assert (j_on, push, j_off, free) == (THETA5, 0.3, THETA5, 0.0)
    assert on == pytest.approx(10.5) and off == pytest.approx(10.75)
    base.calls.clear()
    act = stack(Pushable(), {"name": "contact", "joints": ["theta5"], "torque_nm": -0.2})
    act.read()
    act.close()  # still pushing at the end: the stack takes it back (an emulated rig outlives its trial)
    assert [(c[2], c[3]) for c in act.unwrapped.calls] == [(THETA5, -0.2), (THETA5, 0.0)]


@pytest.mark.parametrize("start_deg, path_deg", [(0.0, [0, 2, 4, 6, 3, 0]), (10.0, [10, 8, 6, 4, 7, 9])])
def test_a_contact_past_a_position_starts_when_the_joint_passes_it_either_way(start_deg, path_deg):
    """past_deg: 5° starts the push at the first read at or beyond 5° from the side the joint started on;
    the joint coming back does not end it."""
    q0 = np.zeros(len(JOINTS))
    q0[THETA5] = start_deg * DEG
    base = Pushable(q0)
    act = stack(base, {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "past_deg": 5.0})
    for k, deg in enumerate(path_deg):
        base.t = 0.1 * k
        base.q[THETA5] = deg * DEG
        act.read()
    assert [(c[1], c[3]) for c in base.calls] == [(pytest.approx(0.3), 0.3)]  # at 6° (or 4°), never before


def test_friction_drifts_linearly_from_from_s_over_over_s_and_is_restored_on_close():
    base = Pushable()
    act = stack(base, {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5, "from_s": 1.0,
                       "over_s": 2.0})
    seen = {}
    for k in range(41):
        base.t = 0.1 * k
        act.read()
        seen[round(base.t, 1)] = act.scale
    assert seen[0.9] == 1.0 and seen[2.0] == pytest.approx(1.75) and seen[3.0] == seen[4.0] == 2.5
    assert all(c[0] == "friction" and c[2] == THETA4 for c in base.calls)
    first = base.calls[0]  # nothing asked before from_s; at it the scale is still 1: the next read
    assert first[1] == pytest.approx(1.1) and first[3] == pytest.approx(1.075)
    act.close()
    assert base.calls[-1][3] == 1.0
    step = stack(Pushable(), {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5})  # over_s 0
    step.read()
    assert step.unwrapped.calls == [("friction", 0.0, THETA4, 2.5)]


def test_a_stuck_joint_keeps_the_goal_it_had_and_the_others_follow():
    base = Pushable()
    act = stack(base, {"name": "stuck", "joints": ["theta5"], "from_s": 0.01, "for_s": 0.02})
    act.enable()
    for k in range(25):
        act.read()
        act.command(np.full(len(JOINTS), 0.1 * k), np.ones(len(JOINTS)))
        base.t += 0.002
    goals = np.array(base.goals)
    assert np.allclose(goals[5:15, THETA5], 0.4)  # from 0.01 s (cycle 5): the goal it had, cycle 4's
    assert np.allclose(goals[:5, THETA5], 0.1 * np.arange(5)) and goals[15, THETA5] == pytest.approx(1.5)
    assert np.allclose(goals[:, THETA4], 0.1 * np.arange(25))  # the others follow


# ---------------------------------------------------------------------------
# The servo-model sim: the core's plant feels the push and the friction
# ---------------------------------------------------------------------------


def test_a_contact_on_the_servo_model_sim_pushes_the_joint_off_its_goal_from_from_s_on():
    period, settle = 0.002, 1.0
    free = run_move(sim("sim_target1_servo.yaml"), THETA5, 0.3, settle, period)
    pushed = run_move(apply_faults(sim("sim_target1_servo.yaml"), [
        {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3}], np.random.default_rng(0)),
        THETA5, 0.3, settle, period)
    pulled = run_move(apply_faults(sim("sim_target1_servo.yaml"), [
        {"name": "contact", "joints": ["theta5"], "torque_nm": -0.3}], np.random.default_rng(0)),
        THETA5, 0.3, settle, period)
    late = run_move(apply_faults(sim("sim_target1_servo.yaml"), [
        {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3, "from_s": 0.8}],
        np.random.default_rng(0)),
        THETA5, 0.3, settle, period)
    hold = held(free, 500)
    base = error_deg(free, THETA5)[hold].mean()
    # 0.3 N·m against an XM430's position loop: 0.41° of sag over the hold, each way (measured)
    assert error_deg(pushed, THETA5)[hold].mean() - base > 0.3
    assert error_deg(pulled, THETA5)[hold].mean() - base < -0.3
    # from 0.8 s: nothing before it, bit for bit; after it, the joint sags (1.14° at most, measured)
    before = free.time < 0.8
    assert np.array_equal(late.q[before], free.q[before])
    assert np.abs(late.q[~before, THETA5] - free.q[~before, THETA5]).max() / DEG > 0.8
    assert late.time[np.flatnonzero(np.any(late.q != free.q, axis=1))[0]] >= 0.8


def test_a_contact_beyond_an_ideal_motors_force_moves_the_joint_one_within_it_barely():
    """PyBullet's position motors are stiff: 0.3 N·m moves theta5 by thousandths of a degree, and 3 N·m
    on top of gravity is beyond what its 4.1 N·m motor holds (measured: 32.7° off its goal, where
    the joint stops)."""
    period, settle = 0.002, 1.0
    free = run_move(sim("sim_target1.yaml"), THETA5, -0.3, settle, period)
    hold = held(free, 500)
    light, heavy = (run_move(apply_faults(sim("sim_target1.yaml"), [
        {"name": "contact", "joints": ["theta5"], "torque_nm": tau}], np.random.default_rng(0)),
        THETA5, -0.3, settle, period) for tau in (0.3, 3.0))
    offset = lambda log: np.abs(log.q[hold, THETA5] - free.q[hold, THETA5]).max() / DEG  # noqa: E731
    assert 0.0 < offset(light) < 0.01
    assert offset(heavy) > 10.0
    # a slide: the needle's rack (d10, a 40 N motor) pushed back by 60 N goes to its stop, by 5 N stays
    d10 = JOINTS.index("d10")
    light, heavy = (run_move(apply_faults(sim("sim_target1.yaml"), [
        {"name": "contact", "joints": ["d10"], "force_n": f}], np.random.default_rng(0)),
        d10, 0.02, 0.5, period) for f in (-5.0, -60.0))
    assert abs(light.q[-1, d10] - 0.02) < 1e-5 and heavy.q[-1, d10] < 1e-4


def lag_and_miss(log: TrialLog, joint: int, settle_cycles: int) -> tuple[float, float]:
    """A positive move's largest lag behind its command while it moves, and how far off its goal the
    joint stays over the hold (the integrator wound up by the lag overshoots; friction holds it there),
    in degrees."""
    e = error_deg(log, joint)
    hold = held(log, settle_cycles)
    return float(-e[:hold.start].min()), float(e[hold].mean())


def test_friction_drift_makes_the_servo_model_sims_joint_lag_more():
    """theta4 with the worn rig's identified friction (sim_target1_identified.yaml), ×2.5."""
    period, settle = 0.002, 1.0
    free = run_move(sim("sim_target1_identified.yaml"), THETA4, 0.3, settle, period)
    worn = run_move(apply_faults(sim("sim_target1_identified.yaml"), [
        {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5}], np.random.default_rng(0)),
        THETA4, 0.3, settle, period)
    (lag_free, miss_free), (lag_worn, miss_worn) = (lag_and_miss(log, THETA4, 500) for log in (free, worn))
    assert lag_worn - lag_free > 0.5  # 4.82° → 5.82° (measured)
    assert miss_worn - miss_free > 0.4  # 0.48° → 1.18° (measured)


def test_friction_drift_is_refused_on_pybullets_ideal_motors_naming_what_to_use():
    backend = sim("sim_target1.yaml")
    try:
        with pytest.raises(BackendSetupError) as e:
            apply_faults(backend, [{"name": "friction_drift", "joints": ["theta4"], "factor": 2.5}],
                         np.random.default_rng(0))
    finally:
        backend.close()
    said = str(e.value)
    assert "\n" not in said and said.startswith("friction_drift needs a backend with set_friction_scale")
    assert "PyBulletActuators (PyBullet's ideal motors, no servo friction) has none" in said
    assert "sim_target1_servo.yaml" in said and "--emulate" in said


@pytest.mark.parametrize("config", ["sim_target1.yaml", "sim_target1_servo.yaml"])
def test_a_stuck_joint_in_simulation_keeps_the_goal_it_had_while_its_command_moves(config):
    period = 0.002

    def moved(*faults: dict) -> TrialLog:
        act = apply_faults(sim(config), list(faults), np.random.default_rng(0))
        return run_move(act, THETA5, -0.3, 0.5, period)

    free = moved()
    stuck, midway = (moved({"name": "stuck", "joints": ["theta5"], "from_s": t}) for t in (0.0, 0.2))
    assert np.abs(free.q[-1, THETA5] - free.q[0, THETA5]) / DEG > 16.0  # the move: 17.2°
    assert np.abs(stuck.q[:, THETA5] - stuck.q[0, THETA5]).max() / DEG < 0.2  # held where it was
    others = [j for j in range(len(JOINTS)) if j != THETA5]
    assert np.abs(stuck.q[-1, others] - free.q[-1, others]).max() / DEG < 0.5  # the others as without it
    goal_then = midway.q_cmd[np.flatnonzero(midway.time < 0.2)[-1], THETA5]  # the last goal before 0.2 s
    assert abs(goal_then - midway.q_cmd[0, THETA5]) / DEG > 2.0  # it had started to move
    assert abs(midway.q[-1, THETA5] - goal_then) / DEG < 0.3  # and stopped at that goal


# ---------------------------------------------------------------------------
# The emulated rig: the real driver, the emulator's plant reached through its fault hooks
# ---------------------------------------------------------------------------

RIG_PERIOD = 0.01  # the lab config's 100 Hz


def lab_holding(directory: Path, **emulator) -> Path:
    """The lab config, its servos left holding at each safe stop (a torque-off stop would let the arm
    sag between two runs), with ``emulator`` fields set."""
    data = yaml.safe_load(LAB.read_text())
    data["backend"]["safe_stop"] = "hold"
    data["emulator"].update(emulator)
    path = directory / "lab_holding.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The lab's emulated rig in this process, theta4's gearbox worn (the friction a drift scales)."""
    path = lab_holding(tmp_path_factory.mktemp("rig"), servo_physics={"theta4": WORN_THETA4})
    cfg = load_trial_config(path)
    with EmulatedRig(cfg, clock=VirtualClock()) as r:
        yield r, r.retarget(cfg)


def on_rig(rig, *faults: dict) -> Actuators:
    r, cfg = rig
    backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))  # carries the rig's hooks (bench.rig.serving)
    assert backend.fault_hooks is r.hooks
    return apply_faults(backend, list(faults), np.random.default_rng(0))


def there_and_back(rig, joint: int, delta: float, settle: float, *faults: dict) -> TrialLog:
    """A move on the emulated rig with ``faults``, then, without them, back to where it started."""
    log = run_move(on_rig(rig, *faults), joint, delta, settle, RIG_PERIOD)
    run_move(on_rig(rig), joint, 0.0, 0.2, RIG_PERIOD, start=log.q_cmd[0])
    return log


def test_a_contact_on_the_emulated_rig_pushes_the_joint_off_its_goal(rig):
    settle = 0.6
    free = there_and_back(rig, THETA5, 0.2, settle)
    pushed = there_and_back(rig, THETA5, 0.2, settle,
                            {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3})
    hold = held(free, 60)
    sag = error_deg(pushed, THETA5)[hold].mean() - error_deg(free, THETA5)[hold].mean()
    assert sag > 0.25, sag  # 0.45–0.48° over three repeats (measured); the same core as the sim's 0.41°


def test_friction_drift_makes_the_emulated_rigs_joint_lag_more(rig):
    settle = 0.4
    free = there_and_back(rig, THETA4, 0.3, settle)
    worn = there_and_back(rig, THETA4, 0.3, settle,
                          {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5})
    (lag_free, miss_free), (lag_worn, miss_worn) = (lag_and_miss(log, THETA4, 40) for log in (free, worn))
    # measured over three repeats: lag 4.54–4.74° → 5.06–5.24°, miss 1.51–1.60° → 2.39–2.45°
    assert lag_worn - lag_free > 0.15, (lag_free, lag_worn)
    assert miss_worn - miss_free > 0.4, (miss_free, miss_worn)


def test_a_stuck_joint_on_the_emulated_rig_stays_while_its_command_moves(rig):
    log = run_move(on_rig(rig, {"name": "stuck", "joints": ["theta5"]}), THETA5, 0.2, 0.3, RIG_PERIOD)
    assert abs(log.q_cmd[-1, THETA5] - log.q_cmd[0, THETA5]) / DEG > 11.0
    assert np.abs(log.q[:, THETA5] - log.q[0, THETA5]).max() / DEG < 0.3


def test_a_contact_is_refused_on_a_rig_without_emulator_hooks(rig):
    """The real driver on a bus no emulator of this process serves (a real rig, as the trial sees it)."""
    _, cfg = rig
    backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))
    del backend.fault_hooks
    try:
        for fault in ({"name": "contact", "joints": ["theta5"], "torque_nm": 0.3},
                      {"name": "friction_drift", "joints": ["theta4"], "factor": 2.5}):
            with pytest.raises(BackendSetupError) as e:
                apply_faults(backend, [fault], np.random.default_rng(0))
            said = str(e.value)
            assert said.startswith(f"{fault['name']} needs a backend with ") and "\n" not in said
            assert "DynamixelActuators has none" in said and "--emulate" in said
        assert not backend.enabled  # refused before anything moved
    finally:
        backend.close()


def test_a_contact_reaches_an_emulator_in_a_child_process(tmp_path):
    """``trial --emulate`` runs the rig in its own process: the push travels over its stdin (the
    wrapper goes on once the child says it applied it), and is taken back when the stack closes. Three holds of theta5: free, pushed, free again (the sag of
    each from where it started, in the push's direction)."""
    path = lab_holding(tmp_path)
    with EmulatorProcess(path) as child:
        cfg = child.retarget(load_trial_config(path))
        robot = get_robot(cfg.robot)

        def hold(*faults: dict) -> TrialLog:
            act = apply_faults(make_dynamixel_backend(cfg, robot), list(faults), np.random.default_rng(0))
            return run_move(act, THETA5, 0.0, 0.6, RIG_PERIOD)

        hold()  # the rig just started: its servos take up their loads first
        free = hold()
        pushed = hold({"name": "contact", "joints": ["theta5"], "torque_nm": 0.3})
        after = hold()
    # each hold's sag from where it was told to hold (the first read, before any push: the push is
    # in the plant before the hold's first cycle, the child having said it applied it)
    sag = {name: error_deg(log, THETA5).max() for name, log in (("free", free), ("pushed", pushed), ("after", after))}
    # measured: free 0–0.18° (the last of the start's settling), pushed 1.06–1.32°, after 0°
    assert sag["pushed"] - max(sag["free"], sag["after"]) > 0.5 and sag["after"] < 0.3, sag


def test_the_child_emulator_applies_each_command_line_and_says_which_it_could_not(capsys):
    """What ``hilbench emulate`` reads on its stdin: a bad line is said on stderr, and the rig goes on."""
    from bench.rig.hooks import follow_commands

    class Rig:
        def __init__(self) -> None:
            self.done: list[tuple] = []
            self.drop_prob = 0.0

        def set_external_effort(self, joint: int, effort: float) -> None:
            if joint >= len(JOINTS):
                raise BackendSetupError(f"set_external_effort: joint {joint} is not a joint index (0 to 8)")
            self.done.append(("load", joint, effort))

        def set_friction_scale(self, joint: int, scale: float) -> None:
            self.done.append(("friction", joint, scale))

        def unplug(self) -> None:
            self.done.append(("unplug",))

        def replug(self) -> None:
            self.done.append(("replug",))

    rig = Rig()
    lines = ['{"plant": {"external_effort": [3, 0.3]}}', 'not json',
             '{"plant": {"external_effort": [12, 0.3]}}', '{"plant": {"friction_scale": 3}}',
             '{"faults": {"drop_prob": 0.1}, "unplug": true}',
             '{"plant": {"friction_scale": [2, 2.5]}}', '{"replug": true}']
    answers = []
    follow_commands(rig, rig, iter(f'{line[:-1]}, "seq": {k}}}\n' if line.startswith("{") else line + "\n"
                                   for k, line in enumerate(lines)), lambda seq, answer: answers.append(seq))
    assert rig.done == [("load", 3, 0.3), ("unplug",), ("friction", 2, 2.5), ("replug",)]
    assert answers == [0, 2, 3, 4, 5, 6]  # every numbered line told, applied or refused
    assert rig.drop_prob == 0.1
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 3 and all(line.startswith("emulator: command ") for line in said)
    assert "not a joint index" in said[1]


def test_an_emulator_in_a_child_process_says_where_its_joints_truly_are(tmp_path):
    """What its rendered cameras see: asked over its stdin, the child's plant's joints, where its
    encoders read them to a tick; an answer of the wrong size is refused. The child runs in real
    time and its arm may still be settling under gravity: the answer is taken between two
    readings, and lies where the joints went between them."""
    from bench.rig.hooks import RemoteRigHooks

    path = lab_holding(tmp_path)
    with EmulatorProcess(path) as child:
        cfg = child.retarget(load_trial_config(path))
        robot = get_robot(cfg.robot)
        with make_dynamixel_backend(cfg, robot) as act:
            before = np.asarray(act.read().position)
            truth = child.faults.true_position()
            after = np.asarray(act.read().position)
    assert truth.shape == (len(robot.joint_names),)
    revolute = [j for j, n in enumerate(robot.joint_names) if n.startswith("theta")]
    tick = np.radians(0.2)
    low, high = np.minimum(before, after)[revolute] - tick, np.maximum(before, after)[revolute] + tick
    assert np.all((low < truth[revolute]) & (truth[revolute] < high)), (truth, before, after)
    with pytest.raises(BackendSetupError, match="did not say where its joints are"):
        RemoteRigHooks(lambda cmd: {"true_position": [0.0]}, len(robot.joint_names)).true_position()


def test_a_trial_on_a_rig_served_by_another_process_refuses_a_contact_in_one_line(tmp_path):
    """`hilbench emulate` in another terminal is a real rig to the trial (no hooks in its process):
    `contact` is refused, exit 2, before anything moves, as corrupt_crc is."""
    serve = subprocess.Popen([HILBENCH, "emulate", str(LAB), "--json"], stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True)
    try:
        ports = json.loads(serve.stdout.readline())
        data = yaml.safe_load(LAB.read_text())
        data["backend"]["port"] = ports["dynamixel_port"]
        data["backend"]["ultrasonic"]["port"] = ports["ultrasonic_port"]
        data["faults"] = [{"name": "contact", "joints": ["theta5"], "torque_nm": 0.3}]
        path = tmp_path / "lab_contact.yaml"
        path.write_text(yaml.safe_dump(data))
        runs = tmp_path / "runs"
        out = subprocess.run([HILBENCH, "trial", str(path), "--out", str(runs)], capture_output=True,
                             text=True, timeout=120)
    finally:
        serve.terminate()
        serve.wait(10)
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert out.returncode == 2, out.stderr
    assert len(lines) == 1 and "contact needs a backend with set_external_effort" in lines[0]
    assert "DynamixelActuators has none" in lines[0] and "--emulate" in lines[0]
    assert not runs.exists()


def test_the_wrappers_name_what_they_hold():
    """The classes a campaign's report may name, each found in the stack it built."""
    act = stack(Pushable(), {"name": "contact", "joints": ["theta5"], "torque_nm": 0.3},
                {"name": "friction_drift", "joints": ["theta4"]}, {"name": "stuck", "joints": ["d10"]})
    assert isinstance(act, Stuck) and isinstance(act.actuators, FrictionDrift)
    assert isinstance(act.actuators.actuators, Contact) and act.actuators.actuators.joints == ["theta5"]
