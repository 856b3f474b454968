"""One contract for every way the bench drives joints (drivers/checker.py, after Gymnasium's env
checker): the PyBullet backend, the Dynamixel backend on the emulated rig, and each fault wrapper
around them pass the same checks: shapes, refusals (ActuatorError before anything reaches the
hardware), the enable/disable/close life cycle, the clock, capabilities found where they live."""

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
from drivers.capabilities import EffortLimited, EmulatorHooks, JointKinds, ServoInfo, find_capability
from drivers.checker import ContractViolation, check_actuators

REPO = Path(__file__).resolve().parents[1]
SIM = REPO / "hil_configs" / "sim_target1.yaml"
LAB = REPO / "hil_configs" / "lab_real.yaml"
#: Faults that act on the emulated bus itself: they need the emulator's hooks.
BUS_ONLY = {"corrupt_crc"}


def _sim_backend() -> Actuators:
    cfg = load_trial_config(SIM)
    return make_backend(cfg, get_robot(cfg.robot))


@pytest.fixture(scope="module")
def rig():
    cfg = load_trial_config(LAB)
    with EmulatedRig(cfg) as r:
        yield r, r.retarget(cfg)


def _rig_backend(rig) -> Actuators:
    r, cfg = rig
    backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))
    backend.fault_hooks = r.bus.faults
    return backend


def _spec(name: str) -> dict:
    spec: dict = {"name": name}
    if FAULTS[name].joints == "":
        spec["joints"] = "all"
    if "level" in FAULTS[name].valid_parameters:
        spec["level"] = "wrapper"
    return spec


def test_the_pybullet_backend_keeps_the_contract():
    act = _sim_backend()
    assert find_capability(act, EffortLimited) is act and find_capability(act, JointKinds) is act
    assert find_capability(act, ServoInfo) is None and find_capability(act, EmulatorHooks) is None
    check_actuators(act)


def test_the_dynamixel_backend_on_the_emulated_rig_keeps_the_contract(rig):
    act = _rig_backend(rig)
    assert find_capability(act, ServoInfo) is act and find_capability(act, EmulatorHooks) is act
    assert find_capability(act, JointKinds) is None
    check_actuators(act)


@pytest.mark.parametrize("name", sorted(set(FAULTS) - BUS_ONLY))
def test_every_fault_wrapper_keeps_the_contract(name):
    act = apply_faults(_sim_backend(), [_spec(name)], np.random.default_rng(0))
    assert act is not act.unwrapped  # a wrapper really is being checked
    assert find_capability(act, EffortLimited) is act.unwrapped  # found through the stack, not forwarded
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


def test_the_ground_truth_recorder_keeps_the_contract():
    from bench.core.truth import GroundTruth

    check_actuators(GroundTruth(apply_faults(_sim_backend(), [_spec("bias")], np.random.default_rng(0))))
