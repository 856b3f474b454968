"""The actuator contract in SI units: joint limits, a state sample, the protocol and the base class.

What :mod:`drivers` re-exports (``from drivers import Actuators``); kept apart from the
package's ``__init__`` so that importing an error class (:mod:`drivers.errors`) does not
import numpy.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from drivers.errors import ActuatorError, BackendSetupError, CommandError, NotEnabledError

__all__ = ["Actuators", "ActuatorsBase", "ActuatorsWrapper", "JointLimits", "JointState", "frozen_array",
           "validate_command"]


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, arrays ordered like ``Actuators.joint_names``."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def clip(self, position: np.ndarray) -> np.ndarray:
        return np.clip(position, self.lower, self.upper)


def frozen_array(values: object) -> np.ndarray:
    """``values`` as a float array no one can write to, nor make writable again.

    Its memory is an immutable ``bytes`` copy, so neither the caller who built it nor a
    reader who sets ``flags.writeable`` can change it; an array already frozen is reused.
    Runs for every reading: the common inputs (a float array, a tuple of floats) go straight.
    """
    kind = type(values)
    if kind is np.ndarray:
        a: np.ndarray = values  # type: ignore[assignment]
        if a.base.__class__ is bytes and not a.flags.writeable:
            return a
        if a.dtype == np.float64:
            out = _from_bytes(a.tobytes())
            return out if a.ndim == 1 else out.reshape(a.shape)
    elif kind is tuple or kind is list:
        try:
            return _from_bytes(array("d", values).tobytes())  # type: ignore[arg-type]
        except TypeError:  # not a flat sequence of numbers: numpy's general path below
            pass
    a = np.asarray(values, dtype=float)
    out = _from_bytes(a.tobytes())
    return out if a.ndim == 1 else out.reshape(a.shape)


_from_bytes = np.frombuffer


@dataclass(frozen=True, eq=False, init=False)
class JointState:
    """One sample of every joint: time (s) and SI arrays ordered like ``joint_names``.

    Immutable once built: the arrays are read-only copies (:func:`frozen_array`) and the fields
    cannot be reassigned, so a backend may keep the reading it returned (the train's host loop
    steers by it) and no wrapper or caller can change what the backend saw. A wrapper that
    changes a value builds a new ``JointState``.
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    # Optional per-sample flags a backend may raise (e.g. "stale:train").
    flags: tuple[str, ...] = ()

    def __init__(self, time: float, position: object, velocity: object, effort: object,
                 flags: Sequence[str] = ()) -> None:
        put = object.__setattr__
        put(self, "time", time)
        put(self, "position", frozen_array(position))
        put(self, "velocity", frozen_array(velocity))
        put(self, "effort", frozen_array(effort))
        put(self, "flags", flags if type(flags) is tuple else tuple(flags))

    def copy(self) -> "JointState":
        """The reading itself: it is immutable, so a copy would be the same values."""
        return self


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


class ActuatorsWrapper:
    """An ``Actuators`` around an ``Actuators`` (``gymnasium.Wrapper``): forwards the whole contract.

    A subclass overrides the one call it changes (``read`` for a sensor fault, ``_command`` for
    a servo fault, ``read`` again for a recorder), so wrappers stack in any order and run the same
    on the simulator and on the real bus. Nothing beyond the contract is forwarded: a capability
    (:mod:`drivers.capabilities`) is looked up through the stack where it is implemented, and a
    typo never reaches the hardware (Gymnasium dropped ``__getattr__`` forwarding for that reason).
    A wrapper never writes into the reading it received (it is immutable); it builds a new one.
    """

    def __init__(self, actuators: Actuators) -> None:
        self.actuators = actuators

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
        """What this wrapper does to a valid command; the default passes it on."""
        self.actuators.command(position, velocity)

    def now(self) -> float:
        return self.actuators.now()

    def wait_until(self, t: float) -> None:
        self.actuators.wait_until(t)

    def close(self) -> None:
        self.actuators.close()

    def __enter__(self) -> "ActuatorsWrapper":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def unwrapped(self) -> Actuators:
        """The backend under every wrapper."""
        return self.actuators.unwrapped

    def __repr__(self) -> str:
        return f"<{type(self).__name__}{self.actuators!r}>"

    def _index(self, joints: Sequence[str]) -> np.ndarray:
        """Indices of ``joints``; an unknown name is refused naming the joints there are."""
        names = list(self.joint_names)
        missing = [j for j in joints if j not in names]
        if missing:
            raise BackendSetupError(f"{type(self).__name__}: unknown joint(s) {missing}; "
                                     f"the actuators have {names}")
        return np.array([names.index(j) for j in joints], dtype=int)
