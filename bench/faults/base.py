"""The wrapper every fault derives from: an ``Actuators`` around an ``Actuators``.

Like ``gymnasium.Wrapper``, a :class:`FaultWrapper` forwards the whole
contract to the actuators it wraps, so a fault only overrides the call it
changes (``read`` for a sensor fault, ``command`` for a servo fault), faults
stack in any order, and the same fault runs on the simulator and on the real
bus. ``unwrapped`` reaches the backend under the stack, for the extras it
implements (the Protocols of :mod:`drivers.capabilities`: EffortLimited, EmulatorHooks...);
nothing else is forwarded implicitly (Gymnasium dropped ``__getattr__``
forwarding for the same reason: a typo must not reach the hardware).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np

from bench.kinematics.registry import ROBOTS
from drivers import Actuators, BackendSetupError, JointLimits, JointState, validate_command
from drivers.capabilities import JointKinds, find_capability

__all__ = ["FaultWrapper", "joint_kinds", "kinds_for_names"]


class FaultWrapper:
    """Forwards everything to ``actuators``; subclasses change one behaviour."""

    def __init__(self, actuators: Actuators) -> None:
        self.actuators = actuators

    # -- the Actuators contract, forwarded --------------------------------------
    @property
    def joint_names(self) -> Sequence[str]:
        return self.actuators.joint_names

    @property
    def limits(self) -> JointLimits:
        return self.actuators.limits

    @property
    def enabled(self) -> bool:
        return self.actuators.enabled

    def enable(self) -> None:
        self.actuators.enable()

    def disable(self) -> None:
        self.actuators.disable()

    def read(self) -> JointState:
        return self.actuators.read()

    def command(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Refuse a bad command as a backend would (CommandError), then hand it to :meth:`_command`."""
        position, velocity = validate_command(position, velocity, len(self.joint_names))
        self._command(position, velocity)

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        """What this fault does to a valid command; the default passes it on."""
        self.actuators.command(position, velocity)

    def now(self) -> float:
        return self.actuators.now()

    def wait_until(self, t: float) -> None:
        self.actuators.wait_until(t)

    def close(self) -> None:
        self.actuators.close()

    def __enter__(self) -> "FaultWrapper":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the stack ----------------------------------------------------------------
    @property
    def unwrapped(self) -> Actuators:
        """The backend under every wrapper: where its declared extras are called."""
        return self.actuators.unwrapped

    def __repr__(self) -> str:
        return f"<{type(self).__name__}{self.actuators!r}>"

    # -- helpers for subclasses ----------------------------------------------------
    def _index(self, joints: Sequence[str]) -> np.ndarray:
        names = list(self.joint_names)
        missing = [j for j in joints if j not in names]
        if missing:
            raise BackendSetupError(f"{type(self).__name__}: unknown joint(s) {missing}; "
                                     f"the actuators have {names}")
        return np.array([names.index(j) for j in joints], dtype=int)


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
