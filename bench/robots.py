"""The robots the bench knows, by the name the CLI and configs use."""

from __future__ import annotations

from typing import Callable

from bench.kinematics.arc_train import ArcTrainRobot

ROBOTS: dict[str, Callable[[], object]] = {
    "arc-train": ArcTrainRobot,
}


def get_robot(name: str):
    """A robot's kinematic model by name; unknown names list the valid ones."""
    try:
        factory = ROBOTS[name]
    except KeyError:
        raise KeyError(f"unknown robot {name!r}; known robots: {', '.join(sorted(ROBOTS))}") from None
    return factory()
