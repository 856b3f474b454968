"""The actuator contract in SI units: joint limits, a state sample, the protocol and the base class.

What :mod:`drivers` re-exports (``from drivers import Actuators``); kept apart from the
package's ``__init__`` so that importing an error class (:mod:`drivers.errors`) does not
import numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from drivers.errors import ActuatorError, CommandError, NotEnabledError

__all__ = ["Actuators", "ActuatorsBase", "JointLimits", "JointState", "validate_command"]


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, arrays ordered like ``Actuators.joint_names``."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def clip(self, position: np.ndarray) -> np.ndarray:
        return np.clip(position, self.lower, self.upper)


@dataclass
class JointState:
    """One sample of every joint: time (s) and SI arrays ordered like ``joint_names``."""

    time: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    # Optional per-sample flags a backend may raise (e.g. "stale:train").
    flags: tuple[str, ...] = field(default_factory=tuple)

    def copy(self) -> "JointState":
        return JointState(
            self.time, self.position.copy(), self.velocity.copy(), self.effort.copy(), self.flags
        )


@runtime_checkable
class Actuators(Protocol):
    """The one interface through which the bench drives a robot."""

    @property
    def joint_names(self) -> Sequence[str]: ...

    @property
    def limits(self) -> JointLimits: ...

    @property
    def enabled(self) -> bool: ...

    def enable(self) -> None:
        """Power the joints (torque on) holding their present position."""

    def disable(self) -> None:
        """Bring the joints to the configured safe state (torque off or hold)."""

    def read(self) -> JointState:
        """Latest measured state; never blocks longer than one bus transaction."""

    def command(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Set goal positions (and optional feed-forward velocities)."""

    def now(self) -> float:
        """The backend's clock in seconds (sim time, or a monotonic wall clock)."""

    def wait_until(self, t: float) -> None:
        """Advance to time ``t``: sim steps physics, real hardware sleeps."""

    def close(self) -> None:
        """Safe stop and release every resource; idempotent."""

    @property
    def unwrapped(self) -> "Actuators":
        """The backend itself, under any wrappers (Gymnasium's ``Env.unwrapped``)."""

    def __enter__(self) -> "Actuators": ...

    def __exit__(self, *exc: object) -> None: ...


def validate_command(position: np.ndarray, velocity: np.ndarray | None, n: int,
                     probe: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The command as float arrays of ``n`` joints, or :class:`CommandError` before it goes anywhere.

    One rule for backends and wrappers alike; ``probe`` (ones, length ``n``) makes the finite
    check one dot product, since the sum is NaN or inf iff an entry is.
    """
    position = np.asarray(position, dtype=float)
    if position.shape != (n,):
        raise CommandError(f"command position has shape {position.shape}, expected ({n},)")
    if not math.isfinite(position.dot(np.ones(n) if probe is None else probe)):
        raise CommandError(f"command position is not finite: {position}")
    if velocity is not None:
        velocity = np.asarray(velocity, dtype=float)
        if velocity.shape != (n,):
            raise CommandError(f"command velocity has shape {velocity.shape}, expected ({n},)")
    return position, velocity


class ActuatorsBase:
    """Shared lifecycle for backends: the enable guard and the safe-stop context.

    Subclasses implement ``_enable``, ``_disable``, ``_command`` and ``_close``;
    this class enforces the order (``OrderEnforcing`` in Gymnasium's terms) and
    the shape of commands, so every backend refuses bad calls the same way.
    """

    @property
    def unwrapped(self) -> "ActuatorsBase":
        return self


    _enabled: bool = False
    _closed: bool = False

    @property
    def _n_joints(self) -> int:
        n = self.__dict__.get("_n_cached")
        if n is None:
            n = self.__dict__["_n_cached"] = len(self.joint_names)  # type: ignore[attr-defined]
        return n

    @property
    def _finite_probe(self) -> np.ndarray:
        z = self.__dict__.get("_finite_probe_cached")
        if z is None:
            z = self.__dict__["_finite_probe_cached"] = np.ones(self._n_joints)
        return z

    @property
    def enabled(self) -> bool:
        return self._enabled

    def enable(self) -> None:
        if self._closed:
            raise ActuatorError(f"{type(self).__name__} is closed; create a new one")
        self._enable()
        self._enabled = True

    def disable(self) -> None:
        if self._enabled and not self._closed:
            try:
                self._disable()
            finally:
                self._enabled = False

    def command(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        if not self._enabled:
            raise NotEnabledError(
                f"{type(self).__name__}.command() before enable(): call enable() first"
            )
        position, velocity = validate_command(position, velocity, self._n_joints, self._finite_probe)
        self._command(position, velocity)

    def close(self) -> None:
        if self._closed:
            return
        try:
            self.disable()
        finally:
            self._closed = True
            self._close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- to implement -------------------------------------------------------
    def _enable(self) -> None:
        raise NotImplementedError

    def _disable(self) -> None:
        raise NotImplementedError

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError
