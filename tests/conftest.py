"""Shared fixtures: the arc-and-train model, a headless PyBullet world and a cold emulated rig;
and the order the test files start in."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

#: The longest test files (a minute or more each, mostly the emulated rig's trials in real time),
#: started first: the suite runs on two workers, each file whole on one (README, the test
#: command), and a long file started last would leave one worker alone for its last minutes.
LONGEST_FIRST = ("test_servo_model.py", "test_compare.py", "test_identify.py", "test_identify_worn.py", "test_stop_unconfirmed.py",
                 "test_lab_tools.py", "test_signals.py", "test_cli_hostile_bus.py", "test_campaign.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each file's own order kept


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
