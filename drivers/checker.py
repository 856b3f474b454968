"""The contract every backend and every wrapper around one must keep, checked in one call
(in the spirit of Gymnasium's ``utils.env_checker``): the same checks run on the PyBullet
backend, the emulated Dynamixel backend and each fault wrapper, so a new backend or wrapper
is held to the rules the bench relies on.

:func:`check_actuators` moves the joints only to where they already are (a command of the
present position), so it is safe on a rig that holds still.
"""

from __future__ import annotations

import math

import numpy as np

from drivers import (
    ActuatorError,
    Actuators,
    CommandError,
    JointLimits,
    JointState,
    NotEnabledError,
)
from drivers.capabilities import (
    EffortLimited,
    EmulatorHooks,
    JointKinds,
    LinkPoses,
    PositionReset,
    ServoInfo,
    TruePosition,
    find_capability,
    layers,
)
from drivers.errors import ContractViolation

__all__ = ["ContractViolation", "check_actuators"]

CAPABILITIES = (EffortLimited, EmulatorHooks, JointKinds, LinkPoses, PositionReset, ServoInfo, TruePosition)


def _require(ok: bool, what: str) -> None:
    if not ok:
        raise ContractViolation(what)


def _refuses(act: Actuators, error: type[BaseException], what: str, *args) -> None:
    try:
        act.command(*args)
    except error:
        return
    except Exception as e:  # noqa: BLE001 - the wrong exception is the finding
        raise ContractViolation(f"{what}: raised {type(e).__name__} ({e}), expected {error.__name__}") from e
    raise ContractViolation(f"{what}: accepted, expected {error.__name__}")


def _check_state(st: object, n: int, when: str) -> JointState:
    _require(isinstance(st, JointState), f"read() {when} returned {type(st).__name__}, not JointState")
    assert isinstance(st, JointState)
    _require(isinstance(st.time, float) and math.isfinite(st.time), f"read() {when}: time {st.time!r}")
    for name in ("position", "velocity", "effort"):
        arr = getattr(st, name)
        _require(isinstance(arr, np.ndarray) and arr.shape == (n,), f"read() {when}: {name} shape "
                 f"{getattr(arr, 'shape', None)}, expected ({n},)")
    _require(bool(np.isfinite(st.position).all()), f"read() {when}: position not finite {st.position}")
    return st


def _check_static(act: Actuators) -> int:
    _require(isinstance(act, Actuators), f"{type(act).__name__} does not implement the Actuators protocol")
    names = list(act.joint_names)
    _require(bool(names) and all(isinstance(n, str) and n for n in names), f"joint_names {names!r}")
    _require(len(set(names)) == len(names), f"joint_names repeat a name: {names}")
    n = len(names)
    lim = act.limits
    _require(isinstance(lim, JointLimits), f"limits is {type(lim).__name__}, not JointLimits")
    for field in ("lower", "upper", "velocity", "effort"):
        arr = np.asarray(getattr(lim, field))
        _require(arr.shape == (n,), f"limits.{field} shape {arr.shape}, expected ({n},)")
    _require(bool(np.all(np.asarray(lim.lower) <= np.asarray(lim.upper))), "limits.lower above limits.upper")
    _require(bool(np.all(np.asarray(lim.velocity) > 0)), "limits.velocity must be positive")
    _require(bool(np.all(np.asarray(lim.effort) > 0)), "limits.effort must be positive")
    backend = act.unwrapped
    _require(getattr(backend, "actuators", None) is None, "unwrapped is itself a wrapper")
    _require(backend.unwrapped is backend, "the backend's unwrapped is not the backend")
    _require(list(layers(act))[-1] is backend, "the wrapper stack does not end at unwrapped")
    for cap in CAPABILITIES:  # no layer fakes or hides a capability: each is where it is implemented
        found = find_capability(act, cap)
        _require(found is None or isinstance(found, cap), f"{cap.__name__} found on a layer without it")
    return n


def check_actuators(act: Actuators) -> None:
    """Run the contract checks on fresh, not yet enabled actuators; closes them at the end.

    Raises :class:`ContractViolation` naming the first broken rule.
    """
    n = _check_static(act)
    _require(not act.enabled, "enabled before enable()")
    st = _check_state(act.read(), n, "before enable()")
    _refuses(act, NotEnabledError, "command() before enable()", st.position)
    act.enable()
    _require(act.enabled, "enable() did not enable")
    st = _check_state(act.read(), n, "after enable()")
    q = st.position.copy()
    _refuses(act, CommandError, "a command of the wrong length", np.zeros(n + 1))
    _refuses(act, CommandError, "a command with NaN", np.where(np.arange(n) == 0, np.nan, q))
    _refuses(act, CommandError, "a command with inf", np.where(np.arange(n) == n - 1, np.inf, q))
    _refuses(act, CommandError, "a velocity of the wrong length", q, np.zeros(n - 1 if n > 1 else 2))
    for error in (CommandError, NotEnabledError):
        _require(issubclass(error, ActuatorError), f"{error.__name__} is not an ActuatorError")
    t0 = act.now()
    act.command(q, np.zeros(n))
    act.wait_until(t0 + 0.01)
    t1 = act.now()
    _require(t1 >= t0 + 0.01 - 1e-9, f"wait_until({t0 + 0.01:.4f}) returned at now() = {t1:.4f}")
    st = _check_state(act.read(), n, "after a command")
    _require(st.time >= t0 - 1e-9, f"read().time {st.time} went back before now() {t0}")
    act.disable()
    _require(not act.enabled, "disable() left the actuators enabled")
    _refuses(act, NotEnabledError, "command() after disable()", q)
    act.close()
    act.close()  # idempotent
    try:
        act.enable()
    except ActuatorError:
        pass
    else:
        raise ContractViolation("enable() after close() was accepted")
