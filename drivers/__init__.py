"""The actuator contract every backend honours, in SI units.

An :class:`Actuators` is to the bench what ``gymnasium.Env`` is to an agent: a
small protocol (read, command, enable, disable, clocks, close) that the runner,
the fault wrappers and the analysis rely on, and that knows nothing of
trajectories, trials or reports. Positions are in rad (revolute) or m
(prismatic), velocities in rad/s or m/s, efforts in N·m or N. Ticks, raw
currents and sensor counts never leave ``drivers/``.

Lifecycle (after ros2_control's hardware interface): a backend starts
*inactive* (``read()`` works, ``command()`` raises :class:`NotEnabledError`),
becomes *active* on ``enable()`` and returns to inactive on ``disable()``.
Leaving the context manager, normally or by exception, brings the hardware to
a safe stop (torque off or hold, per configuration) and closes it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from drivers.errors import (
    ActuatorError,
    BackendSetupError,
    BenchError,
    CommandError,
    CommunicationError,
    HardwareFault,
    NotEnabledError,
)

if TYPE_CHECKING:
    from drivers.contract import (Actuators, ActuatorsBase, ActuatorsWrapper, JointLimits, JointState,
                                  frozen_array, validate_command)

__all__ = [
    "frozen_array",
    "validate_command",
    "Actuators",
    "ActuatorsBase",
    "ActuatorsWrapper",
    "ActuatorError",
    "BackendSetupError",
    "BenchError",
    "CommandError",
    "CommunicationError",
    "HardwareFault",
    "JointLimits",
    "JointState",
    "NotEnabledError",
]

#: Names served from :mod:`drivers.contract` on first use: the errors above import no numpy,
#: so the command line can catch them before (or without) loading any backend.
_CONTRACT = frozenset({"Actuators", "ActuatorsBase", "ActuatorsWrapper", "JointLimits", "JointState",
                       "frozen_array", "validate_command"})


def __getattr__(name: str) -> Any:
    if name in _CONTRACT:
        # PEP 562 lazy attribute: loaded on first use, so the errors alone stay light (no numpy)
        return getattr(importlib.import_module("drivers.contract"), name)
    raise AttributeError(f"module 'drivers' has no attribute {name!r}")
