"""Shared fixtures: the arc-and-train model, a headless PyBullet world and a cold emulated rig."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def arc_train():
    from bench.kinematics.arc_train import ArcTrainRobot

    return ArcTrainRobot()


@pytest.fixture
def cold_rig():
    """The lab's emulated rig with its servos powering up torque off, and the config pointed at it."""
    from bench.config.models import load_trial_config  # the rig's fixtures only
    from bench.paths import REPO_ROOT
    from bench.rig.emulated import EmulatedRig

    cfg = load_trial_config(REPO_ROOT / "hil_configs" / "lab_real.yaml")
    cfg = cfg.model_copy(update={"emulator": cfg.emulator.model_copy(update={"start_torque_on": False})})
    with EmulatedRig(cfg) as r:
        yield r, r.retarget(cfg)
