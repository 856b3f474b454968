"""The robots the bench knows, by the name the CLI and configs use: one registry for every verb.

Every robot answers ``robot``, ``fk``, ``ik`` and ``accuracy`` (the :class:`NeedleRobot`
protocol). A trial also needs a URDF to simulate and a servo table to drive; the robots
without them say why in :data:`TRIAL_REFUSALS`.
"""

from __future__ import annotations

from typing import Callable, Optional

from bench.kinematics.arc_train import ArcTrainRobot
from bench.kinematics.needle import NeedleRobot
from bench.kinematics.para_brachy import ParaBrachyRobot
from bench.kinematics.zerobot import ZerobotRobot

__all__ = ["ROBOTS", "TRIAL_REFUSALS", "TRIAL_ROBOTS", "get_robot", "robot_names", "trial_refusal"]

ROBOTS: dict[str, Callable[[], NeedleRobot]] = {
    "arc-train": ArcTrainRobot,
    "zerobot": ZerobotRobot,
    "para-brachy": ParaBrachyRobot,
}

#: Why ``trial`` cannot run a robot the kinematics know.
TRIAL_REFUSALS: dict[str, str] = {
    "zerobot": "zerobot is modelled for kinematics and gantry contact (seed 002) but has no servo table, "
               "trajectory plan or interlock set; trials run the arc-and-train robot",
    "para-brachy": "para-brachy is a kinematic model of a parallel mechanism (seed 003) with no URDF to "
                   "simulate and no servos to drive; trials run the arc-and-train robot",
}

TRIAL_ROBOTS: tuple[str, ...] = tuple(n for n in ROBOTS if n not in TRIAL_REFUSALS)


def robot_names() -> list[str]:
    """Every robot name the bench accepts, sorted."""
    return sorted(ROBOTS)


def get_robot(name: str) -> NeedleRobot:
    """A robot's kinematic model by name; unknown names list the valid ones."""
    try:
        factory = ROBOTS[name]
    except KeyError:
        raise KeyError(f"unknown robot {name!r}; known robots: {', '.join(robot_names())}") from None
    return factory()


def trial_refusal(name: str) -> Optional[str]:
    """Why ``trial`` cannot run ``name`` (None when it can)."""
    if name not in ROBOTS:
        return f"unknown robot {name!r}; trials run {', '.join(TRIAL_ROBOTS)}"
    return TRIAL_REFUSALS.get(name)
