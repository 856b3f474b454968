"""The servo tolerance has one value per joint (seed 000 section 6: the actuators hold ±0.29°),
derived once through each joint's transmission and used alike by the accuracy budget, the
comparison's settling bands and the deadband fault."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.accuracy.poses import default_tolerances
from bench.compare.tracking import default_band
from bench.faults import Deadband, apply_faults
from bench.kinematics.registry import get_robot
from bench.kinematics.transmission import servo_tolerances
from test_faults import Kinematic


def test_train_tolerance_is_the_servos_through_the_pinion_on_the_arc():
    robot = get_robot("arc-train")
    tol = dict(zip(robot.joint_names, servo_tolerances(robot)))
    assert math.degrees(tol["train"]) == pytest.approx(0.29 * 10 / 200)  # ±0.0145° of arc, not ±0.29°
    assert math.degrees(tol["theta5"]) == pytest.approx(0.29)
    assert tol["d9"] == pytest.approx(math.radians(0.29) * 0.010)


def test_budget_bands_and_deadband_fault_agree_on_every_joint():
    robot = get_robot("arc-train")
    truth = servo_tolerances(robot)
    np.testing.assert_array_equal(default_tolerances(robot), truth)
    np.testing.assert_array_equal(default_band(robot), truth)
    act = apply_faults(Kinematic(), [{"name": "deadband", "joints": "all"}], np.random.default_rng(0))
    assert isinstance(act, Deadband)
    np.testing.assert_allclose(act.tol, truth, rtol=1e-12)


def test_a_deadband_of_other_degrees_reaches_the_train_through_its_transmission():
    robot = get_robot("arc-train")
    act = apply_faults(Kinematic(), [{"name": "deadband", "joints": ["train", "theta4"], "tol_deg": 1.0}],
                       np.random.default_rng(0))
    names = list(robot.joint_names)
    assert math.degrees(act.tol[names.index("theta4")]) == pytest.approx(1.0)
    assert math.degrees(act.tol[names.index("train")]) == pytest.approx(1.0 * 10 / 200)
    assert act.tol[names.index("theta5")] == 0.0
