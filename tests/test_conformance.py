"""One contract for every way the bench drives joints (drivers/checker.py, after Gymnasium's env
checker): the PyBullet backend, the servo-model simulator, the Dynamixel backend on the emulated
rig, and each fault wrapper around each of them pass the same checks: shapes, refusals
(ActuatorError before anything reaches the hardware), the enable/disable/close life cycle, the
clock, readings no one can edit, every capability found where it lives and doing what it says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.config.models import load_trial_config
from bench.faults.spec import FAULTS, apply_faults
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend, make_dynamixel_backend
from bench.rig.emulated import EmulatedRig
from drivers import Actuators
from drivers.capabilities import (
    BlockExecution,
    EffortLimited,
    EmulatorHooks,
    ExternalLoad,
    FrictionScaled,
    HostLoop,
    JointKinds,
    PositionReset,
    ServoInfo,
    TruePosition,
    find_capability,
)
from drivers.checker import ContractViolation, check_actuators
from drivers.clock import VirtualClock

REPO = Path(__file__).resolve().parents[1]
SIM = REPO / "hil_configs" / "sim_target1.yaml"
SERVO_SIM = REPO / "hil_configs" / "sim_target1_servo.yaml"
LAB = REPO / "hil_configs" / "lab_real.yaml"
#: Faults that act on the emulated bus itself: they need the emulator's hooks.
BUS_ONLY = {"corrupt_crc"}
#: Faults that scale the servo model's friction: PyBullet's ideal motors have none (refused there).
SERVO_FRICTION = {"friction_drift"}
#: What a fault needs beyond its defaults: a contact's push on every kind of joint (small: the checker
#: holds the joints still while it pushes).
REQUIRED = {"contact": {"torque_nm": 0.05, "force_n": 0.5}}


def _sim_backend() -> Actuators:
    cfg = load_trial_config(SIM)
    return make_backend(cfg, get_robot(cfg.robot))


def _servo_sim_backend() -> Actuators:
    cfg = load_trial_config(SERVO_SIM)
    return make_backend(cfg, get_robot(cfg.robot))


@pytest.fixture(scope="module")
def rig():
    cfg = load_trial_config(LAB)
    with EmulatedRig(cfg, clock=VirtualClock()) as r:
        yield r, r.retarget(cfg)


def _rig_backend(rig) -> Actuators:
    r, cfg = rig
    backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))
    backend.fault_hooks = r.hooks
    return backend


def _spec(name: str) -> dict:
    spec: dict = {"name": name}
    if FAULTS[name].joints == "":
        spec["joints"] = "all"
    if "level" in FAULTS[name].valid_parameters:
        spec["level"] = "wrapper"
    if "prob" in FAULTS[name].valid_parameters and name not in BUS_ONLY:
        spec["prob"] = 1.0  # every read after the first is rewritten: the checker sees what that does
    spec.update(REQUIRED.get(name, {}))
    return spec


def test_the_pybullet_backend_keeps_the_contract():
    act = _sim_backend()
    assert find_capability(act, EffortLimited) is act and find_capability(act, JointKinds) is act
    assert find_capability(act, ServoInfo) is None and find_capability(act, EmulatorHooks) is None
    assert find_capability(act, ExternalLoad) is act and find_capability(act, FrictionScaled) is None
    check_actuators(act)


def test_the_dynamixel_backend_on_the_emulated_rig_keeps_the_contract(rig):
    act = _rig_backend(rig)
    assert find_capability(act, ServoInfo) is act and find_capability(act, EmulatorHooks) is act
    assert find_capability(act, JointKinds) is None
    # the driver pushes on nothing itself: the emulated rig's plant is reached through its hooks
    assert find_capability(act, ExternalLoad) is None and find_capability(act, FrictionScaled) is None
    assert isinstance(act.fault_hooks, ExternalLoad) and isinstance(act.fault_hooks, FrictionScaled)
    check_actuators(act)


def test_the_servo_model_sim_keeps_the_contract():
    act = _servo_sim_backend()
    assert find_capability(act, HostLoop) is act and find_capability(act, TruePosition) is act
    assert find_capability(act, BlockExecution) is act and find_capability(act, PositionReset) is None
    assert find_capability(act, ExternalLoad) is act and find_capability(act, FrictionScaled) is act
    check_actuators(act)


@pytest.mark.parametrize("name", sorted(set(FAULTS) - BUS_ONLY - SERVO_FRICTION))
def test_every_fault_wrapper_keeps_the_contract(name):
    act = apply_faults(_sim_backend(), [_spec(name)], np.random.default_rng(0))
    assert act is not act.unwrapped  # a wrapper really is being checked
    assert find_capability(act, EffortLimited) is act.unwrapped  # found through the stack, not forwarded
    check_actuators(act)


@pytest.mark.parametrize("name", sorted(set(FAULTS) - BUS_ONLY))
def test_every_fault_wrapper_keeps_the_contract_on_the_servo_model_sim(name):
    """The servo-model sim keeps the reading it returned (its train loop steers by it)."""
    act = apply_faults(_servo_sim_backend(), [_spec(name)], np.random.default_rng(0))
    assert act is not act.unwrapped
    check_actuators(act)


@pytest.mark.parametrize("name", sorted(set(FAULTS) - BUS_ONLY - {"torque_limit"}))
def test_every_fault_wrapper_keeps_the_contract_on_the_emulated_rig(rig, name):
    """The Dynamixel driver keeps the reading it returned (its train loop steers by it)."""
    act = apply_faults(_rig_backend(rig), [_spec(name)], np.random.default_rng(0))
    assert act is not act.unwrapped
    check_actuators(act)


def test_the_torque_limit_wrapper_keeps_the_contract_on_the_emulated_rig():
    """On a rig whose limited joint's servo is in current-based position mode (the lab config's
    are not: there torque_limit is refused in one line)."""
    cfg = load_trial_config(LAB)
    with EmulatedRig(cfg, clock=VirtualClock()) as r:
        cfg = r.retarget(cfg)
        servos = dict(cfg.backend.servos)
        servos["theta4"] = servos["theta4"].model_copy(update={"mode": "current_based_position"})
        cfg = cfg.model_copy(update={"backend": cfg.backend.model_copy(update={"servos": servos})})
        backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))
        act = apply_faults(backend, [{"name": "torque_limit", "joints": ["theta4"], "scale": 0.9}],
                           np.random.default_rng(0))
        assert find_capability(act, EffortLimited) is backend
        check_actuators(act)


@pytest.mark.parametrize("name", sorted(BUS_ONLY))
def test_bus_faults_keep_the_contract_on_the_emulated_rig(rig, name):
    act = apply_faults(_rig_backend(rig), [_spec(name)], np.random.default_rng(0))
    check_actuators(act)


def test_the_checker_catches_a_wrapper_that_lets_nan_through():
    """A checker that cannot fail proves nothing: a wrapper skipping the backend's refusal is caught."""
    from bench.faults.base import FaultWrapper

    class Careless(FaultWrapper):
        def command(self, position, velocity=None):
            self.actuators.command(np.nan_to_num(np.asarray(position, dtype=float)), velocity)

    with pytest.raises(ContractViolation, match="NaN"):
        check_actuators(Careless(_sim_backend()))


def test_the_checker_catches_a_wrapper_writing_into_the_reading_it_received():
    """As DroppedStatus did: the backend's own reading (the driver steers by it) must not change."""
    from bench.faults.base import FaultWrapper

    class WritesIntoIt(FaultWrapper):
        def read(self):
            st = self.actuators.read()
            st.position[0] = 0.0
            return st

    with pytest.raises(ContractViolation, match="read.*raised ValueError"):
        check_actuators(WritesIntoIt(_servo_sim_backend()))


def test_the_checker_catches_a_reading_whose_edit_reaches_the_next_read():
    from drivers import JointState
    from bench.faults.base import FaultWrapper

    class Editable(JointState):
        def __init__(self, time, position, velocity, effort, flags=()):  # leaves the arrays writable
            for name, value in zip(("time", "position", "velocity", "effort", "flags"),
                                   (time, position, velocity, effort, flags)):
                object.__setattr__(self, name, value)

    class KeepsAndReturns(FaultWrapper):
        """Hands out the reading it keeps, again while the clock has not moved."""
        kept = None

        def read(self):
            st = self.actuators.read()
            if self.kept is None or self.kept.time != st.time:
                self.kept = Editable(st.time, st.position.copy(), st.velocity.copy(), st.effort.copy())
            return self.kept

    with pytest.raises(ContractViolation, match="changed the next read"):
        check_actuators(KeepsAndReturns(_sim_backend()))


def test_the_checker_catches_a_wrapper_offering_a_capability():
    """A wrapper's set_effort_limit would be found before the backend's: a call could skip the layers beneath."""
    from bench.faults.base import FaultWrapper

    class Forwards(FaultWrapper):
        def set_effort_limit(self, joint, effort):
            self.unwrapped.set_effort_limit(joint, effort)

    with pytest.raises(ContractViolation, match="Forwards offers EffortLimited"):
        check_actuators(Forwards(_sim_backend()))


def test_the_checker_catches_a_load_on_a_joint_that_is_not_one():
    """A push on joint 9 of nine joints must be refused in one line, not land in the physics' arrays."""
    act = _servo_sim_backend()
    act.plant.set_external_effort = lambda joint, effort: None  # takes anything
    with pytest.raises(ContractViolation, match=r"set_external_effort\(9, 0.0\) on the backend was accepted"):
        check_actuators(act)


def test_the_checker_catches_emulator_hooks_that_scale_any_friction(rig):
    class Lax:
        def set_friction_scale(self, joint, scale):
            pass

    act = _rig_backend(rig)
    act.fault_hooks = Lax()
    try:
        with pytest.raises(ContractViolation, match=r"set_friction_scale\(9, 1.0\) on its emulator hooks"):
            check_actuators(act)
    finally:
        act.close()


def test_the_checker_catches_a_backend_that_does_not_say_how_it_stopped():
    act = _sim_backend()
    act._disable = lambda: None  # the joints left as they were, and nothing said
    with pytest.raises(ContractViolation, match="safe_stop_report after disable"):
        check_actuators(act)


def test_the_checker_lists_every_capability_declared():
    """A Protocol added to drivers/capabilities.py without joining CAPABILITIES goes unchecked."""
    import typing

    import drivers.capabilities as caps

    declared = {v for v in vars(caps).values() if isinstance(v, type) and v.__module__ == caps.__name__
                and v is not typing.Protocol and getattr(v, "_is_protocol", False)}
    assert declared == set(caps.CAPABILITIES)


def test_the_ground_truth_recorder_keeps_the_contract():
    from bench.core.truth import GroundTruth

    check_actuators(GroundTruth(apply_faults(_sim_backend(), [_spec("bias")], np.random.default_rng(0))))
