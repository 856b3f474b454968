"""The robots the bench knows, by the name the CLI and configs use."""

from __future__ import annotations

from typing import Callable

from bench.kinematics.arc_train import ArcTrainRobot
from bench.kinematics.zerobot import ZerobotRobot

ROBOTS: dict[str, Callable[[], object]] = {
    "arc-train": ArcTrainRobot,
    "zerobot": ZerobotRobot,
}


def get_robot(name: str):
    """A robot's kinematic model by name; unknown names list the valid ones."""
    try:
        factory = ROBOTS[name]
    except KeyError:
        raise KeyError(f"unknown robot {name!r}; known robots: {', '.join(sorted(ROBOTS))}") from None
    return factory()
