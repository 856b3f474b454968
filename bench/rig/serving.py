"""The emulated rigs this process serves, by the port of their servo bus, and what kind of rig a
config drives.

An emulated rig registers its bus port and its fault hooks while it serves; the backend
builder (:func:`bench.rig.backends.make_backend`) attaches those hooks to any backend it
builds on that port, so a bus-level fault reaches the wire whoever asked for the trial
(``trial --emulate``, ``compare --emulate``, a campaign on an emulated rig). The same
registry says what a record calls the rig: ``sim``, ``emulated`` or ``real``.
"""

from __future__ import annotations

import threading
from typing import Any, Literal, Optional

__all__ = ["RigKind", "attach", "detach", "bus_rig_kind", "hooks_for", "rig_kind"]

RigKind = Literal["sim", "emulated", "real"]

_LOCK = threading.Lock()
_HOOKS: dict[str, Any] = {}


def attach(port: str, hooks: Any) -> None:
    """``port`` is an emulated bus whose faults ``hooks`` sets (drop_prob, delay_s...)."""
    with _LOCK:
        _HOOKS[str(port)] = hooks


def detach(port: str) -> None:
    with _LOCK:
        _HOOKS.pop(str(port), None)


def hooks_for(port: Optional[str]) -> Any:
    """The fault hooks of the emulated bus on ``port`` (None: not an emulated bus)."""
    with _LOCK:
        return _HOOKS.get(str(port)) if port is not None else None


def rig_kind(config) -> RigKind:
    """``sim`` for a simulator backend, ``emulated`` for a Dynamixel backend on a bus this
    process emulates, else ``real``."""
    b = config.backend
    if b.kind != "dynamixel":
        return "sim"
    return "emulated" if hooks_for(b.port) is not None else "real"


def bus_rig_kind(kind: Optional[str], servos: list[dict]) -> Optional[str]:
    """What the record calls a rig once its servos answered: ``emulated`` when every servo said
    so (an emulator served from another terminal too: drivers.dynamixel.identity), else ``kind``."""
    if servos and all(s.get("emulated") for s in servos):
        return "emulated"
    return kind
