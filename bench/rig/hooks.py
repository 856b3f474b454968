"""An emulated rig's fault hooks, as a backend built on its bus carries them (``fault_hooks``,
:class:`~drivers.capabilities.EmulatorHooks`): the bus's status-packet faults, and the plant's
physical faults — a contact's torque on a joint (:class:`~drivers.capabilities.ExternalLoad`) and
a joint's friction scaled (:class:`~drivers.capabilities.FrictionScaled`) — and where the plant's
joints truly are (``true_position``: what the rig's rendered cameras see, whatever its encoders read).

In this process (:class:`RigHooks`) they change the bus and the plant under the bus's lock; for an
emulator in a child process (:class:`RemoteRigHooks`) each change travels as one JSON line on its
stdin, which :func:`follow_commands` applies there through the child's own :class:`RigHooks`.
"""

from __future__ import annotations

import json
import sys
from typing import Any, Callable, TextIO

import numpy as np

from drivers.capabilities import checked_joint
from drivers.emulator import DynamixelBusEmulator
from drivers.errors import BackendSetupError, BenchError

__all__ = ["BUS_FAULT_FIELDS", "RemoteRigHooks", "RigHooks", "follow_commands"]

#: The bus faults a hooks object sets (the fields of drivers.emulator.BusFaults a fault wrapper uses).
BUS_FAULT_FIELDS = ("drop_prob", "corrupt_crc_prob", "delay_s", "silent")
#: The plant's faults as a command names them, and the hooks' method that applies each.
PLANT_FAULTS = {"external_effort": "set_external_effort", "friction_scale": "set_friction_scale"}


class RigHooks:
    """The fault hooks of an emulated rig this process serves: its bus's faults (the fields of
    ``bus.faults``, read and set through here) and its plant's, each changed under the bus's lock."""

    def __init__(self, bus: DynamixelBusEmulator) -> None:
        object.__setattr__(self, "_bus", bus)

    def __getattr__(self, name: str) -> Any:
        if name in BUS_FAULT_FIELDS:
            return getattr(self._bus.faults, name)
        raise AttributeError(name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in BUS_FAULT_FIELDS:
            raise AttributeError(f"unknown bus fault {name!r}; known: {BUS_FAULT_FIELDS}")
        with self._bus.lock:
            setattr(self._bus.faults, name, value)

    def set_external_effort(self, joint: int, effort: float) -> None:
        """A contact's torque (N·m) or force (N) on the plant's joint, from its next physics step."""
        self._bus.disturb(lambda plant: plant.set_external_effort(joint, effort))

    def true_position(self) -> np.ndarray:
        """The plant's joint values now (rad or m, the robot's joint order): where a camera sees them."""
        with self._bus.lock:
            return np.array(self._bus.plant.joint_position(), dtype=float)

    def set_friction_scale(self, joint: int, scale: float) -> None:
        """The plant's joint's friction as a multiple of the emulated servo's own."""
        self._bus.disturb(lambda plant: plant.set_friction_scale(joint, scale))


class RemoteRigHooks:
    """The fault hooks of an emulator in another process: setting a bus fault, a joint's load or its
    friction scale sends it there, and asking where the joints truly are asks it (``send``: one
    command, a JSON-ready dict, returning the child's answer; ``joint_count``: the plant's joints, so
    that a bad call is refused here, where it was made)."""

    def __init__(self, send: Callable[[dict], dict], joint_count: int) -> None:
        object.__setattr__(self, "_send", send)
        object.__setattr__(self, "_joint_count", joint_count)
        object.__setattr__(self, "_values", {"drop_prob": 0.0, "corrupt_crc_prob": 0.0,
                                             "delay_s": 0.0, "silent": False})

    def __getattr__(self, name: str) -> Any:
        try:
            return self.__dict__["_values"][name]
        except KeyError:
            raise AttributeError(name) from None

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in BUS_FAULT_FIELDS:
            raise AttributeError(f"unknown bus fault {name!r}; known: {BUS_FAULT_FIELDS}")
        self._values[name] = value
        self._send({"faults": {name: value}})

    def set_external_effort(self, joint: int, effort: float) -> None:
        self._send_plant("external_effort", joint, effort)

    def set_friction_scale(self, joint: int, scale: float) -> None:
        self._send_plant("friction_scale", joint, scale)

    def true_position(self) -> np.ndarray:
        answer = self._send({"truth": True}).get("true_position")
        if not isinstance(answer, list) or len(answer) != self._joint_count:
            raise BackendSetupError(f"the emulated rig did not say where its joints are (answered {answer!r})")
        return np.array(answer, dtype=float)

    def _send_plant(self, what: str, joint: int, value: float) -> None:
        """Refused here what the child's plant would refuse out of sight (it answers nothing back)."""
        j = checked_joint(joint, self._joint_count, value, PLANT_FAULTS[what])
        self._send({"plant": {what: [j, float(value)]}})


def follow_commands(rig_hooks: RigHooks, bus: DynamixelBusEmulator, stream: TextIO,
                    applied: Callable[[int, dict], None] | None = None) -> None:
    """Apply JSON lines such as ``{"faults": {"drop_prob": 0.05}}``, ``{"plant": {"external_effort":
    [3, 0.3]}}`` or ``{"unplug": true}`` to the running rig; a line it cannot apply is said on stderr
    and skipped, and the rig goes on. A line's ``"seq"`` is told to ``applied`` once the line is
    done (applied or refused), so the parent knows a fault is in the plant before it goes on, with
    the answer to a question (``{"truth": true}``: ``{"true_position": [...]}``, the joints now)."""
    for line in stream:
        seq = None
        answer: dict = {}
        try:
            cmd = json.loads(line)
            seq = cmd.get("seq")
            for field_name, value in cmd.get("faults", {}).items():
                if field_name in BUS_FAULT_FIELDS:
                    setattr(rig_hooks, field_name, value)
            for what, (joint, value) in cmd.get("plant", {}).items():
                if what in PLANT_FAULTS:
                    getattr(rig_hooks, PLANT_FAULTS[what])(joint, value)
            if cmd.get("truth") is True:
                answer = {"true_position": rig_hooks.true_position().tolist()}
        except (json.JSONDecodeError, BenchError, TypeError, ValueError, AttributeError) as e:
            print(f"emulator: command {line.strip()!r} not applied: {e}", file=sys.stderr, flush=True)
            cmd = {}
        if cmd.get("unplug"):
            bus.unplug()
        if cmd.get("replug"):
            bus.replug()
        if applied is not None and isinstance(seq, int):
            applied(seq, answer)