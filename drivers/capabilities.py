"""What a backend offers beyond the :class:`~drivers.Actuators` contract, as runtime-checkable
Protocols, declared by having the method (as ros2_control declares its interfaces).

Callers look a capability up through the wrapper stack explicitly, outermost layer first
(Gymnasium's ``get_wrapper_attr``), with :func:`find_capability` or :func:`require_capability`
and nothing else (no ``getattr`` probing): wrappers (:class:`drivers.ActuatorsWrapper`) forward
nothing implicitly and offer no capability of their own, so a capability is found exactly where
it is implemented, and a missing one is refused in one line naming it. :data:`CAPABILITIES`
lists them all; :mod:`drivers.checker` checks each one a backend offers.
"""

from __future__ import annotations

from typing import Any, Iterator, Protocol, Sequence, TypeVar, runtime_checkable

import numpy as np

from drivers import Actuators, BackendSetupError, JointState

__all__ = ["CAPABILITIES", "BlockExecution", "BusTiming", "EffortLimited", "EmulatorHooks", "ExternalLoad",
           "FrictionScaled", "HostLoop", "JointKinds", "LinkPoses", "PositionReset", "SafeStopReport",
           "SensedEncoder", "ServoInfo", "StartWarnings", "TruePosition",
           "checked_joint", "find_capability", "layers", "members", "require_capability"]

C = TypeVar("C")


@runtime_checkable
class EffortLimited(Protocol):
    """Per-joint effort (torque or force) limits that can be lowered at run time (N·m or N)."""

    def set_effort_limit(self, joint: int, effort: float) -> None: ...


@runtime_checkable
class ExternalLoad(Protocol):
    """An external torque or force on a joint (N·m or N, signed as the joint), felt by its dynamics from
    the next physics step until set again (0: none)."""

    def set_external_effort(self, joint: int, effort: float) -> None: ...


@runtime_checkable
class FrictionScaled(Protocol):
    """A joint's friction as a multiple of its identified value (1: as identified), every term of the
    servo core's friction law at once."""

    def set_friction_scale(self, joint: int, scale: float) -> None: ...


@runtime_checkable
class ServoInfo(Protocol):
    """The servos behind the joints: IDs, models, firmware, modes (recorded with every trial)."""

    def servo_info(self) -> list[dict]: ...


@runtime_checkable
class JointKinds(Protocol):
    """Which joints are revolute and which prismatic, from the backend's own model."""

    @property
    def joint_kinds(self) -> list[str]: ...


@runtime_checkable
class LinkPoses(Protocol):
    """World pose of a named link (the simulator knows where everything is)."""

    def link_pose(self, link_name: str) -> tuple[np.ndarray, np.ndarray]: ...


@runtime_checkable
class PositionReset(Protocol):
    """Teleport the joints to a configuration (simulation only)."""

    def reset_position(self, q: np.ndarray) -> None: ...


@runtime_checkable
class TruePosition(Protocol):
    """Where the joints really are, beyond what a sensor reports (a simulator's ground truth)."""

    def true_position(self) -> np.ndarray: ...


@runtime_checkable
class EmulatorHooks(Protocol):
    """The emulated bus's fault settings (drop, delay, corrupt, silence), set on the backend of an
    emulated rig only; real hardware and the simulator have none."""

    fault_hooks: Any


@runtime_checkable
class BlockExecution(Protocol):
    """Many control cycles per call, and a rewind to any of them (the simulator): the runner's fast path.

    ``execute_block`` runs row k as ``read(); command(position[k], velocity[k]); wait_until(ends[k])``
    would and returns the states read (arrays with a row per cycle: ``time``, ``position``,
    ``velocity``, ``effort``, read-only); ``rewind(k)`` puts the robot back as it was read at cycle
    k. The runner uses it only when the outermost layer has it: a wrapper must see every cycle.
    """

    def execute_block(self, position: np.ndarray, velocity: np.ndarray, ends: np.ndarray) -> Any: ...

    def rewind(self, cycle: int) -> JointState: ...


@runtime_checkable
class SafeStopReport(Protocol):
    """How the backend left the joints at its last safe stop (read back where it can), for the log."""

    @property
    def safe_stop_report(self) -> str | None: ...


@runtime_checkable
class StartWarnings(Protocol):
    """What the backend warned about while starting (a slow USB latency timer...), for the record."""

    @property
    def start_warnings(self) -> list[str]: ...


@runtime_checkable
class HostLoop(Protocol):
    """A host loop closed on the backend's own readings (the train's, on its sensor), told when the
    bench lost a status the backend read, so the loop holds instead of steering on it."""

    def status_lost(self, joints: Sequence[str]) -> None: ...


@runtime_checkable
class SensedEncoder(Protocol):
    """The servo's own reading of the joint the backend reports through another sensor (the train's
    pinion encoder, where its position comes from the ultrasonic sensor), in joint units (m or rad),
    as of the last read: what the servo's physics did, apart from the sensor's noise.

    ``encoder_joint`` is None when no joint is read through another sensor."""

    @property
    def encoder_joint(self) -> str | None: ...

    def encoder_position(self) -> float: ...


@runtime_checkable
class BusTiming(Protocol):
    """A backend on a bus, paced by the wall clock: its clock is real time, so each control cycle
    has a deadline, and it times its own bus transactions where they happen.

    ``bus_time()`` is the seconds (SI) spent in bus transactions since the last call (0.0 for
    none): the runner takes it once a cycle, as ros2_control times a hardware interface's read and
    write. A simulator, whose clock runs as fast as the CPU allows, has no deadline and offers none.
    """

    def bus_time(self) -> float: ...


#: Every capability a backend may offer, as the checker goes through them.
CAPABILITIES: tuple[type, ...] = (BlockExecution, BusTiming, EffortLimited, EmulatorHooks, ExternalLoad,
                                  FrictionScaled, HostLoop, JointKinds, LinkPoses, PositionReset,
                                  SafeStopReport, SensedEncoder, ServoInfo, StartWarnings, TruePosition)


def layers(actuators: Actuators) -> Iterator[Actuators]:
    """The stack from the outermost wrapper down to the backend (wrappers keep theirs in ``.actuators``)."""
    layer: Any = actuators
    while layer is not None:
        yield layer
        layer = getattr(layer, "actuators", None)


def find_capability(actuators: Actuators, capability: type[C]) -> C | None:
    """The outermost layer of the stack implementing ``capability``, or None."""
    for layer in layers(actuators):
        if isinstance(layer, capability):
            return layer
    return None


def require_capability(actuators: Actuators, capability: type[C], what: str) -> C:
    """The layer implementing ``capability``; else one line saying ``what`` needs it and which backend lacks it."""
    found = find_capability(actuators, capability)
    if found is None:
        raise BackendSetupError(f"{what} needs a backend with {members(capability)} ({capability.__name__}: "
                                 f"{_summary(capability)}); {type(actuators.unwrapped).__name__} has none")
    return found


def checked_joint(joint: int, n: int, value: float, what: str) -> int:
    """``joint`` as an index of ``n`` joints, or one line (BackendSetupError) saying why a capability's
    call was refused: an index that is not a joint, or a value that is not finite."""
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or not 0 <= joint < n:
        raise BackendSetupError(f"{what}: joint {joint!r} is not a joint index (0 to {n - 1})")
    if not np.isfinite(value):
        raise BackendSetupError(f"{what}: {value!r} for joint {joint} is not finite")
    return int(joint)


def members(capability: type) -> str:
    """The names a capability asks for, as a message shows them."""
    names = [k for k in vars(capability) if not k.startswith("_")]
    names += [k for k in vars(capability).get("__annotations__", {}) if k not in names]
    return ", ".join(names) or capability.__name__


def _summary(capability: type) -> str:
    return (capability.__doc__ or "").strip().split("\n")[0].rstrip(".").lower()
