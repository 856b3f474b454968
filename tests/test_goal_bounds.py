"""No goal beyond what a servo's operating mode and its joint's limits allow ever reaches the bus.

The rig is the project's emulator, built from the very config (so it follows the bad transmission
perfectly: its plant turns ticks into joint motion through the same ratio), and every Goal
Position written to each emulated servo is recorded where the bus hands it over.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from bench.config.models import load_trial_config
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_dynamixel_backend
from bench.rig.emulated import EmulatedRig, Planted
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from drivers import BenchError, BackendSetupError
from drivers.clock import VirtualClock
from drivers.dynamixel.settings import ServoSettings
from drivers.dynamixel.control_table import x_series_table
from drivers.dynamixel.goals import GoalBounds, GoalOutOfRange, mode_ticks, transmission_problem

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
GOAL = x_series_table()["Goal Position"].address
NAMES = list(get_robot("arc-train").joint_names)


def _servo_changed(cfg, joint: str, **change):
    """The config with one servo changed *without validation*: what a driver must survive on its own."""
    servos = dict(cfg.backend.servos)
    servos[joint] = servos[joint].model_copy(update=change)
    return cfg.model_copy(update={"backend": cfg.backend.model_copy(update={"servos": servos})})


def _cold(cfg):
    """Servos powered up with torque off: a torque enable would show."""
    return cfg.model_copy(update={"emulator": cfg.emulator.model_copy(update={"start_torque_on": False})})


def record_goals(rig: EmulatedRig) -> dict[int, list[int]]:
    """Every Goal Position each emulated servo is handed by the bus (Sync Write or Write)."""
    seen: dict[int, list[int]] = {sid: [] for sid in rig.bus.servos}
    for sid, servo in rig.bus.servos.items():
        def write(address, data, _write=servo.write, _sid=sid):
            if address == GOAL and len(data) == 4:
                seen[_sid].append(int.from_bytes(bytes(data), "little", signed=True))
            return _write(address, data)
        servo.write = write
    return seen


@pytest.mark.parametrize("joint,change,says", [
    ("theta4", {"ratio": 1e-4}, "theta4: range [-1.5708, 1.5708] through ratio 0.0001"),
    ("theta4", {"ratio": 1e-9}, "theta4: range"),  # once: goals of -2,000,793,744 ticks, a struct.error
    ("train", {"ratio": 1e-4}, "a servo in extended_position mode takes -1,048,575 to 1,048,575"),
    ("theta4", {"offset": 100.0}, "offset 100 needs goals of -64,166 to -62,118 ticks"),
])
def test_a_transmission_typo_never_reaches_the_bus(tmp_path, joint, change, says):
    cfg = _cold(_servo_changed(load_trial_config(LAB), joint, **change))
    with EmulatedRig(cfg, clock=VirtualClock()) as rig:
        goals = record_goals(rig)
        with pytest.raises(BackendSetupError) as err:
            run_trial(prepare(rig.retarget(cfg)), tmp_path / "runs", TrialHooks(report=False))
        assert says in str(err.value) and "torque not enabled" in str(err.value)
        assert not any(rig.bus.servo(i).torque_enabled for i in rig.bus.servos)
        lo, hi = mode_ticks(cfg.backend.servos[joint].mode)
        sent = [g for gs in goals.values() for g in gs]
        assert all(lo <= g <= hi for g in sent) and not sent  # refused before any goal at all
    assert not (tmp_path / "runs").exists()  # refused before anything moved: exit 2


def test_commands_far_beyond_the_limits_reach_the_bus_within_the_joint_band():
    """The rig driven at twice its joint limits, each way: the driver clips to the limits, and
    every goal the servos get lies in its joint's band and its mode's range."""
    cfg = load_trial_config(LAB)
    robot = get_robot(cfg.robot)
    with EmulatedRig(cfg, clock=VirtualClock()) as rig:
        goals = record_goals(rig)
        with make_dynamixel_backend(rig.retarget(cfg), robot) as act:
            act.enable()
            lim = act.limits
            home = act.read().position
            centre = (lim.lower + lim.upper) / 2
            for far in (centre + 2 * (lim.upper - centre), centre - 2 * (centre - lim.lower)):
                for k in range(5):
                    q = home.copy()
                    q[1:] = far[1:]  # the train moves slowly; the sensor steers it
                    act.command(q)
                    rig.clock.sleep(0.02)
            with pytest.raises(GoalOutOfRange, match=r"theta4: goal 2 is 3,35\d ticks, outside the 1,023 "
                                                     r"to 3,073 its joint's limits and its mode allow"):
                act._goal_ticks(np.where(np.array(NAMES) == "theta4", 2.0, home))  # the guard itself
        for j, name in enumerate(NAMES):
            sv = cfg.backend.servos[name]
            band = sorted(2048 + (np.array([lim.lower[j], lim.upper[j]]) - sv.offset)
                          / (sv.ratio * 2 * np.pi / 4096))
            extra = 0.05 / abs(sv.ratio) / (2 * np.pi / 4096) if name == "train" else 0.0
            lo, hi = mode_ticks(sv.mode)
            sent = goals[sv.id]
            assert sent, name
            assert all(max(lo, band[0] - extra - 1) <= g <= min(hi, band[1] + extra + 1) for g in sent), \
                (name, min(sent), max(sent), band)
        # theta4 went to each of its limits and no further
        theta4 = goals[cfg.backend.servos["theta4"].id]
        assert max(theta4) == 3072 and min(theta4) == 1024


def test_a_rig_reading_a_joint_beyond_its_limits_is_refused_before_torque(tmp_path):
    """A zero 1.7 rad out (a wrong offset or calibration): theta4 reads -1.7 rad at home."""
    cfg = _cold(load_trial_config(LAB))
    with EmulatedRig(cfg, clock=VirtualClock(), planted=Planted(zero_errors={"theta4": 1.7})) as rig:
        goals = record_goals(rig)
        with pytest.raises(BackendSetupError, match=r"theta4 reads -1\.(69|70)\d*, outside its limits "
                                                     r"\[-1\.5708, 1\.5708\]; torque not enabled"):
            run_trial(prepare(rig.retarget(cfg)), tmp_path / "runs", TrialHooks(report=False))
        assert not any(rig.bus.servo(i).torque_enabled for i in rig.bus.servos)
        assert not any(goals.values())
    assert not (tmp_path / "runs").exists()


def test_a_train_resting_on_its_lower_limit_enables_whatever_its_noisy_sensor_reads():
    """The train rests at home, on its lower limit; its ultrasonic reading scatters by centimetres
    either side. Torque-on holds the pinion's shaft, so the limit check at enable reads the shaft's
    encoder: a sensor reading below the limit never refuses a rig that is where it should be."""
    cfg = load_trial_config(LAB)
    cfg = cfg.model_copy(update={"emulator": cfg.emulator.model_copy(update={"ultrasonic_noise_mm": 60.0})})
    robot = get_robot(cfg.robot)
    train = list(robot.joint_names).index("train")
    home = robot.chain.home.copy()
    home[train] = robot.chain.lower[train]
    below = 0
    with EmulatedRig(cfg, clock=VirtualClock(), initial_position=home) as rig:
        for _ in range(2):
            with make_dynamixel_backend(rig.retarget(cfg), robot) as act:
                for _ in range(12):
                    below += act.read().position[train] < act.limits.lower[train] - 0.01
                    rig.clock.sleep(0.025)  # a new reading of the sensor comes on the rig's clock
                act.enable()
                assert rig.bus.servo(cfg.backend.servos["train"].id).torque_enabled
    assert below >= 4, below  # the sensor did read the train beyond its limit, and torque came on anyway


def _bounds(ratio: float = 1.0, mode: str = "position", limits=(0, 4095)) -> GoalBounds:
    sv = ServoSettings(joint="theta4", id=3, model=1020, mode=mode, ratio=ratio)
    return GoalBounds.of([sv], np.array([-np.pi / 2]), np.array([np.pi / 2]), lambda sid: limits, [0.0])


def test_goal_bounds_refuse_what_cannot_be_sent_and_never_wrap():
    b = _bounds()
    assert b.check(np.array([2048.0])).dtype == np.int64
    assert b.check(np.array([1024.0]))[0] == 1024 and b.check(np.array([3072.0]))[0] == 3072
    for bad in (3100.0, 1000.0, np.nan, np.inf, -np.inf, 1e30, -2_000_793_744.0):
        with pytest.raises(GoalOutOfRange, match="theta4: goal"):
            b.check(np.array([bad]))
    assert b.check(np.array([4000.0]), hold=True)[0] == 4000  # where the shaft is: its mode alone
    with pytest.raises(GoalOutOfRange):
        b.check(np.array([5000.0]), hold=True)
    assert issubclass(GoalOutOfRange, BenchError)


def test_a_servos_own_position_limits_narrow_what_its_joint_may_need():
    with pytest.raises(BackendSetupError, match="servo ID 3, theta4: .* takes 1,500 to 2,600"):
        _bounds(limits=(1500, 2600))  # the servo's Min/Max Position Limit, as read from it
    assert 3700 < _bounds(ratio=0.6).hi[0] < 3800  # a smaller ratio: more ticks, still in range
    with pytest.raises(BackendSetupError, match="extended_position mode takes -1,048,575"):
        _bounds(ratio=1e-4, mode="extended_position")


def test_transmission_problem_passes_the_lab_table():
    cfg = load_trial_config(LAB)
    for row in get_robot(cfg.robot).chain.rows:
        sv = cfg.backend.servos[row.name]
        assert transmission_problem(row.name, sv.mode, sv.ratio, sv.offset, row.lower, row.upper) is None
    assert "must be finite" in transmission_problem("d9", "position", float("nan"), 0.0, 0.0, 0.1)
