"""Physical faults: what pushes on a joint, drags it or holds it, in the joint's own dynamics.

Seed 000's trials met the robot's surroundings: a drape or a cable catching a link, the needle
meeting tissue, a gearbox whose friction grows as it wears. These wrappers hand such a change to
the physics where the backend has it, at the time the trial's clock says (seconds from the first
read, as :class:`~bench.faults.ultrasonic.UltrasonicStuck`'s), and the servos fight it as they
would on the rig:

- :class:`Contact`: an external torque (N·m) or force (N) on a joint
  (:class:`~drivers.capabilities.ExternalLoad`: PyBullet's joints, the servo-model sim's plant,
  the emulated rig's plant through its fault hooks);
- :class:`FrictionDrift`: a joint's friction growing from its identified value to ``factor``
  times it (:class:`~drivers.capabilities.FrictionScaled`: the servo core's friction law, in the
  servo-model sim and the emulated rig);
- :class:`Stuck`: a joint that stops following, its servo keeping the goal it had (wrapper level,
  on every backend).

A backend without what a fault needs is refused in one line before anything moves; a load or a
friction scale set is taken back when the stack closes (an emulated rig outlives its trial).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence, TypeVar

import numpy as np

from bench.faults.base import FaultWrapper
from drivers import Actuators, BackendSetupError, JointState
from drivers.capabilities import EmulatorHooks, ExternalLoad, FrictionScaled, find_capability, members

__all__ = ["Contact", "FrictionDrift", "Stuck", "contact_efforts", "physical_target", "require_physical"]

C = TypeVar("C")

#: Per capability: what a fault needing it is told to use instead, when the backend lacks it.
_INSTEAD = {
    ExternalLoad: "a simulator (PyBullet's ideal motors or the servo-model sim) or the emulated rig "
                  "(--emulate): the bench cannot push on a real rig's joints",
    FrictionScaled: "the servo-model sim (backend.servo_model: datasheet or a model file, as in "
                    "sim_target1_servo.yaml) or the emulated rig (--emulate), whose joints run the servo "
                    "core's friction",
}


def physical_target(actuators: Actuators, capability: type[C]) -> C | None:
    """The layer that applies ``capability`` to the physics: the backend's own (a simulator), else
    the emulated rig's fault hooks the backend carries (:class:`~drivers.capabilities.EmulatorHooks`)."""
    found = find_capability(actuators, capability)
    if found is not None:
        return found
    layer = find_capability(actuators, EmulatorHooks)
    hooks = layer.fault_hooks if layer is not None else None
    return hooks if isinstance(hooks, capability) else None


def require_physical(actuators: Actuators, capability: type[C], fault: str) -> C:
    """:func:`physical_target`, or one line naming the fault, the backend and what to use instead."""
    target = physical_target(actuators, capability)
    if target is None:
        backend = type(actuators.unwrapped).__name__
        if backend == "PyBulletActuators":
            backend += " (PyBullet's ideal motors, no servo friction)"
        raise BackendSetupError(f"{fault} needs a backend with {members(capability)}: {backend} has none; "
                                f"use {_INSTEAD[capability]}")
    return target


def contact_efforts(params: Mapping[str, Any], joints: Sequence[str], kinds: Sequence[str]) -> list[float]:
    """Each joint's effort (N·m on a revolute joint, N on a prismatic one), and the position it must
    pass given for each kind hit when one is; ValueError saying what is missing."""
    efforts = []
    for name, kind in zip(joints, kinds):
        key, what = ("torque_nm", "the torque (N·m)") if kind == "revolute" else ("force_n", "the force (N)")
        if params.get(key) is None:
            raise ValueError(f"{kind} joint {name} needs {key}, {what} that pushes on it")
        efforts.append(float(params[key]))
    passes = {"revolute": params.get("past_deg"), "prismatic": params.get("past_mm")}
    if any(v is not None for v in passes.values()):
        for name, kind in zip(joints, kinds):
            if passes[kind] is None:
                raise ValueError(f"past_deg and past_mm start each kind of joint; {kind} joint {name} "
                                 f"needs {'past_deg' if kind == 'revolute' else 'past_mm'} too")
    return efforts


class _Timed(FaultWrapper):
    """A fault on the trial's clock: seconds from the first read."""

    def __init__(self, actuators: Actuators, joints: Sequence[str]) -> None:
        super().__init__(actuators)
        self.joints = list(joints)
        self._j = self._index(self.joints)
        self._t0: float | None = None

    def _elapsed(self, t: float) -> float:
        if self._t0 is None:
            self._t0 = t
        return t - self._t0


class Contact(_Timed):
    """From ``start`` s (and, with ``past``, once the joint's measured position is at or beyond that
    value as seen from where it was at the first read: it passed it, whichever way it travelled),
    for ``duration`` s (to the end by default), ``effort`` (N·m or N per joint) pushes on the joints."""

    def __init__(self, actuators: Actuators, joints: Sequence[str], effort: Sequence[float],
                 start: float = 0.0, duration: float = math.inf, past: Sequence[float] | None = None) -> None:
        super().__init__(actuators, joints)
        self._load = require_physical(actuators, ExternalLoad, "contact")
        self.effort = np.asarray(effort, dtype=float)
        self.start, self.duration = float(start), float(duration)
        self.past = None if past is None else np.asarray(past, dtype=float)
        self._side: np.ndarray | None = None  # the side of ``past`` each joint started on
        self.started = np.full(len(self.joints), np.nan)  # when each joint's contact began (trial s)
        self._on = np.zeros(len(self.joints), dtype=bool)

    def read(self) -> JointState:
        st = self.actuators.read()
        t = self._elapsed(st.time)
        q = st.position[self._j]
        if self.past is not None and self._side is None:
            self._side = np.sign(q - self.past)
        waiting = np.isnan(self.started) & (t >= self.start)
        if self.past is not None:  # at the value, or on its other side from the start
            waiting &= (self._side == 0) | (np.sign(q - self.past) != self._side)
        self.started[waiting] = t
        on = ~np.isnan(self.started) & (t < self.started + self.duration)
        for k in np.flatnonzero(on != self._on):
            self._load.set_external_effort(int(self._j[k]), float(self.effort[k]) if on[k] else 0.0)
        self._on = on
        return st

    def close(self) -> None:
        try:
            for k in np.flatnonzero(self._on):  # the rig outlives the trial: its joints freed
                self._load.set_external_effort(int(self._j[k]), 0.0)
            self._on[:] = False
        finally:
            super().close()


class FrictionDrift(_Timed):
    """From ``start`` s, the joints' friction grows linearly over ``ramp`` s (0: at once) from its
    identified value to ``factor`` × it, then stays; set again at each read while it grows."""

    def __init__(self, actuators: Actuators, joints: Sequence[str], factor: float, start: float = 0.0,
                 ramp: float = 0.0) -> None:
        super().__init__(actuators, joints)
        self._friction = require_physical(actuators, FrictionScaled, "friction_drift")
        self.factor, self.start, self.ramp = float(factor), float(start), float(ramp)
        self.scale = 1.0  # the scale the joints have now

    def scale_at(self, t: float) -> float:
        """The friction scale ``t`` s into the trial."""
        if t < self.start:
            return 1.0
        done = 1.0 if self.ramp == 0.0 else min(1.0, (t - self.start) / self.ramp)
        return 1.0 + (self.factor - 1.0) * done

    def read(self) -> JointState:
        st = self.actuators.read()
        self._set(self.scale_at(self._elapsed(st.time)))
        return st

    def _set(self, scale: float) -> None:
        if scale != self.scale:
            for j in self._j:
                self._friction.set_friction_scale(int(j), scale)
            self.scale = scale

    def close(self) -> None:
        try:
            self._set(1.0)  # the rig outlives the trial: its friction as identified again
        finally:
            super().close()


class Stuck(_Timed):
    """From ``start`` s for ``duration`` s (to the end by default), the joints' servos keep the goal
    they had then, whatever they are sent (their feed-forward velocity zero)."""

    def __init__(self, actuators: Actuators, joints: Sequence[str], start: float = 0.0,
                 duration: float = math.inf) -> None:
        super().__init__(actuators, joints)
        self.start, self.duration = float(start), float(duration)
        self.held: np.ndarray | None = None  # the goals kept (SI), once stuck
        self._sent: np.ndarray | None = None  # the last goals the backend received

    def read(self) -> JointState:
        st = self.actuators.read()
        self._elapsed(st.time)
        if self._sent is None:  # enabled, a servo holds where it is: that is its goal until commanded
            self._sent = st.position.copy()
        return st

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        t = self._elapsed(self.now())
        if self.start <= t < self.start + self.duration:
            if self.held is None:
                before = self._sent if self._sent is not None else position
                self.held = before[self._j].copy()
            position = position.copy()
            position[self._j] = self.held
            if velocity is not None:
                velocity = velocity.copy()
                velocity[self._j] = 0.0
        self._sent = position.copy()
        self.actuators.command(position, velocity)
