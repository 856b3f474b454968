"""Shared fixtures: the arc-and-train model and a headless PyBullet world."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def arc_train():
    from bench.kinematics.arc_train import ArcTrainRobot

    return ArcTrainRobot()
