"""Communication faults: status packets dropped, late or corrupted.

Two levels. When the backend talks to the bench's servo-bus emulator it
offers the emulator's bus faults (:class:`~drivers.capabilities.EmulatorHooks`),
and the fault is injected on the wire — the real driver then meets the lost,
delayed or corrupted packets itself (:class:`EmulatorStatusFault`). On any
other backend the wrapper-level versions stand in: a dropped joint status
returns that joint's last sample flagged ``stale:<joint>`` (and a backend's
host loop is told, :class:`~drivers.capabilities.HostLoop`); a late one
returns an older sample flagged ``late:<joint>``. Either builds a new reading:
the one received is the backend's own. CRC corruption exists only on the
wire, so it needs the emulator.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from bench.faults.base import FaultWrapper
from drivers import Actuators, BackendSetupError, JointState
from drivers.capabilities import EmulatorHooks, HostLoop, find_capability

__all__ = ["DroppedStatus", "EmulatorStatusFault", "LateStatus", "emulator_fault_target"]


def emulator_fault_target(actuators: Actuators, field: str) -> Any | None:
    """The backend's ``fault_hooks`` if they have ``field`` (e.g. ``BusFaults.drop_prob``), else None."""
    layer = find_capability(actuators, EmulatorHooks)
    hooks = layer.fault_hooks if layer is not None else None
    return hooks if hooks is not None and hasattr(hooks, field) else None


class EmulatorStatusFault(FaultWrapper):
    """Sets one bus-fault field of the emulator while the stack lives; restores it on close."""

    def __init__(self, actuators: Actuators, field: str, value: float) -> None:
        super().__init__(actuators)
        target = emulator_fault_target(actuators, field)
        if target is None:
            raise BackendSetupError(
                f"{type(self.unwrapped).__name__} has no emulator hook {field!r}: status-packet "
                "faults at the bus level need the emulated Dynamixel backend (--emulate)")
        self.field = field
        self._target = target
        self._saved = getattr(target, field)
        setattr(target, field, value)

    def close(self) -> None:
        try:
            setattr(self._target, self.field, self._saved)
        finally:
            super().close()


class DroppedStatus(FaultWrapper):
    """Each read, each targeted joint's status is lost with probability ``prob``:
    the joint keeps its last value (position, velocity, effort), flagged stale.

    A backend with a host loop closed on its own readings (:class:`~drivers.capabilities.HostLoop`:
    the train's, on the ultrasonic sensor) is told which joints were lost, so its loop holds
    instead of steering on a reading the bench saw as stale."""

    def __init__(self, actuators: Actuators, joints: np.ndarray, prob: float,
                 rng: np.random.Generator) -> None:
        super().__init__(actuators)
        self.joints = np.asarray(joints, dtype=int)
        self.prob = float(prob)
        self._rng = rng
        self._last: JointState | None = None
        self._loop = find_capability(actuators, HostLoop)
        self.dropped = 0

    def read(self) -> JointState:
        st = self.actuators.read()
        lost = self.joints[self._rng.random(self.joints.size) < self.prob]
        if self._last is not None and lost.size:
            names = self.joint_names
            lost_names = [names[j] for j in lost]
            st = JointState(st.time, _with(st.position, lost, self._last.position),
                            _with(st.velocity, lost, self._last.velocity),
                            _with(st.effort, lost, self._last.effort),
                            st.flags + tuple(f"stale:{n}" for n in lost_names))
            self.dropped += lost.size
            if self._loop is not None:  # the backend's own loop must not steer on what was lost
                self._loop.status_lost(lost_names)
        self._last = st
        return st


def _with(values: np.ndarray, joints: np.ndarray, old: np.ndarray) -> np.ndarray:
    """A new array: ``values`` with ``joints`` taken from ``old`` (the reading received stays as it was)."""
    out = values.copy()
    out[joints] = old[joints]
    return out


class LateStatus(FaultWrapper):
    """Each read, each targeted joint's status arrives late with probability ``prob``:
    its values are those of the newest sample at least ``delay`` s old, flagged late."""

    def __init__(self, actuators: Actuators, joints: np.ndarray, prob: float, delay: float,
                 rng: np.random.Generator) -> None:
        super().__init__(actuators)
        self.joints = np.asarray(joints, dtype=int)
        self.prob = float(prob)
        self.delay = float(delay)
        self._rng = rng
        self._history: deque[JointState] = deque()

    def _old_sample(self, now: float) -> JointState | None:
        old = None
        for s in self._history:  # oldest first
            if s.time <= now - self.delay + 1e-12:
                old = s
            else:
                break
        if old is None and self._history:
            old = self._history[0]
        return old

    def read(self) -> JointState:
        fresh = self.actuators.read()
        late = self.joints[self._rng.random(self.joints.size) < self.prob]
        old = self._old_sample(fresh.time)
        self._history.append(fresh)
        while len(self._history) > 1 and self._history[1].time <= fresh.time - self.delay:
            self._history.popleft()
        if old is None or not late.size:
            return fresh
        names = self.joint_names
        return JointState(fresh.time, _with(fresh.position, late, old.position),
                          _with(fresh.velocity, late, old.velocity), _with(fresh.effort, late, old.effort),
                          fresh.flags + tuple(f"late:{names[j]}" for j in late))
