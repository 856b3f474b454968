"""The base every fault derives from, and the joint kinds faults need.

A :class:`FaultWrapper` is a :class:`drivers.ActuatorsWrapper` (the wrapper base beside the
``Actuators`` contract, as ``gymnasium.Wrapper`` beside ``Env``) that makes the actuators behave
like imperfect hardware; a recorder such as :class:`bench.core.truth.GroundTruth` wraps the
same way without being a fault.
"""

from __future__ import annotations

from functools import lru_cache

from bench.kinematics.registry import ROBOTS
from drivers import Actuators, ActuatorsWrapper, BackendSetupError
from drivers.capabilities import JointKinds, find_capability

__all__ = ["FaultWrapper", "joint_kinds", "kinds_for_names"]


class FaultWrapper(ActuatorsWrapper):
    """A fault: forwards everything to ``actuators``; a subclass changes one behaviour."""


@lru_cache(maxsize=None)
def kinds_for_names(joint_names: tuple[str, ...]) -> tuple[str, ...] | None:
    """Joint kinds (``revolute``/``prismatic``) of the known robot with these joints, if any."""
    for factory in ROBOTS.values():
        robot = factory()
        if tuple(robot.joint_names) == joint_names:
            return tuple(r.kind for r in robot.chain.rows)
    return None


def joint_kinds(actuators: Actuators) -> list[str]:
    """Kinds of the actuators' joints: from the backend if it says, else from the robot model."""
    backend = find_capability(actuators, JointKinds)
    kinds = backend.joint_kinds if backend is not None else None
    if kinds is None:
        kinds = kinds_for_names(tuple(actuators.joint_names))
    if kinds is None:
        raise BackendSetupError(
            f"cannot tell revolute from prismatic joints among {list(actuators.joint_names)}: "
            "the backend has no joint_kinds and no known robot has these joints")
    return list(kinds)
