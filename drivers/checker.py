"""The contract every backend and every wrapper around one must keep, checked in one call
(in the spirit of Gymnasium's ``utils.env_checker``): the same checks run on the PyBullet
backend, the servo-model simulator, the emulated Dynamixel backend and each fault wrapper, so
a new backend or wrapper is held to the rules the bench relies on.

:func:`check_actuators` moves the joints only to where they already are (a command of the
present position, an effort limit set to the value it has, no external load, the friction as
identified), so it is safe on a rig that holds still.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from drivers import (
    ActuatorError,
    Actuators,
    BenchError,
    CommandError,
    JointLimits,
    JointState,
    NotEnabledError,
)
from drivers.capabilities import (
    CAPABILITIES,
    BlockExecution,
    BusTiming,
    EffortLimited,
    EmulatorHooks,
    ExternalLoad,
    FrictionScaled,
    HostLoop,
    JointKinds,
    LinkPoses,
    PositionReset,
    SafeStopReport,
    SensedEncoder,
    ServoInfo,
    StartWarnings,
    TruePosition,
    find_capability,
    layers,
)
from drivers.errors import ContractViolation

__all__ = ["ContractViolation", "check_actuators"]

#: An edit no reading could hold: if it shows up anywhere, the edit got through.
EDIT = 1.0e3


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


def _read(act: Actuators, n: int, when: str) -> JointState:
    """``act.read()``, checked; a read that fails other than as the bench reports failures is a finding
    (a wrapper writing into the read-only reading it received fails here)."""
    try:
        st = act.read()
    except BenchError:
        raise
    except Exception as e:  # noqa: BLE001 - the unexpected exception is the finding
        raise ContractViolation(f"read() {when} raised {type(e).__name__}: {e}") from e
    if not isinstance(st, JointState):
        raise ContractViolation(f"read() {when} returned {type(st).__name__}, not JointState")
    _require(isinstance(st.time, float) and math.isfinite(st.time), f"read() {when}: time {st.time!r}")
    for name in ("position", "velocity", "effort"):
        arr = getattr(st, name)
        _require(isinstance(arr, np.ndarray) and arr.shape == (n,), f"read() {when}: {name} shape "
                 f"{getattr(arr, 'shape', None)}, expected ({n},)")
    _require(bool(np.isfinite(st.position).all()), f"read() {when}: position not finite {st.position}")
    return st


def _edit(st: JointState) -> list[str]:
    """Try every way of editing a reading; the ways that got through."""
    got_through = []
    for name in ("position", "velocity", "effort"):
        arr = getattr(st, name)
        try:
            arr[0] = arr[0] + EDIT
            got_through.append(f"{name}[0] = …")
        except ValueError:
            pass
        try:
            arr.flags.writeable = True
            arr[0] = arr[0] + EDIT
            got_through.append(f"{name}.flags.writeable = True")
        except ValueError:
            pass
        try:
            setattr(st, name, arr + EDIT)
            got_through.append(f"reading.{name} = …")
        except (dataclasses.FrozenInstanceError, AttributeError):
            pass
    return got_through


def _check_reading_is_immutable(act: Actuators, n: int, when: str) -> None:
    """Editing a returned reading, or trying to, changes neither the next read() nor the backend."""
    st = _read(act, n, when)
    before = float(st.position[0])
    got_through = _edit(st)
    tried = ", ".join(got_through) or "every edit refused"
    after = _read(act, n, f"after editing the reading read {when}")
    _require(abs(after.position[0] - before) < EDIT / 2,
             f"editing the reading read {when} ({tried}) changed the next read()")
    truth = find_capability(act, TruePosition)
    if truth is not None:
        q = np.asarray(truth.true_position(), dtype=float)
        _require(q.shape == (n,) and bool(np.isfinite(q).all()), f"true_position() is {q!r}")
        _require(abs(q[0] - before) < EDIT / 2,
                 f"editing the reading read {when} ({tried}) changed the backend's true_position()")
    _require(not got_through, f"the reading read {when} can be edited ({', '.join(got_through)}): a "
             "reading must be immutable once returned (build a new JointState instead)")


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
    stack = list(layers(act))
    _require(stack[-1] is backend, "the wrapper stack does not end at unwrapped")
    for layer in stack[:-1]:  # a capability on a wrapper would let its call go around the layers beneath
        offered = [cap.__name__ for cap in CAPABILITIES if isinstance(layer, cap)]
        _require(not offered, f"the wrapper {type(layer).__name__} offers {', '.join(offered)}: wrappers "
                 "offer no capability; it is found on the backend through the stack")
    return n


def _check_idle_capabilities(act: Actuators, n: int) -> None:
    """The capabilities the actuators offer, each used as the bench uses it, before enable()."""
    names = list(act.joint_names)
    kinds = find_capability(act, JointKinds)
    if kinds is not None:
        k = list(kinds.joint_kinds)
        _require(len(k) == n and set(k) <= {"revolute", "prismatic"}, f"joint_kinds {k!r}")
    servos = find_capability(act, ServoInfo)
    if servos is not None:
        info = servos.servo_info()
        _require(isinstance(info, list) and all(isinstance(d, dict) and d.get("joint") in names for d in info),
                 f"servo_info() must be a dict per servo naming its joint, got {info!r}")
    warned = find_capability(act, StartWarnings)
    if warned is not None:
        w = warned.start_warnings
        _require(isinstance(w, list) and all(isinstance(x, str) for x in w), f"start_warnings {w!r}")
    hooks = find_capability(act, EmulatorHooks)
    if hooks is not None:
        _require(hooks.fault_hooks is not None, "fault_hooks is None: a backend without hooks has none")
    _check_physical(find_capability(act, ExternalLoad), find_capability(act, FrictionScaled), n,
                    "the backend")
    fault_hooks = hooks.fault_hooks if hooks is not None else None  # an emulated rig's plant, through them
    _check_physical(fault_hooks if isinstance(fault_hooks, ExternalLoad) else None,
                    fault_hooks if isinstance(fault_hooks, FrictionScaled) else None, n, "its emulator hooks")
    poses = find_capability(act, LinkPoses)
    if poses is not None:
        try:
            poses.link_pose("no such link")
        except BenchError:
            pass
        else:
            raise ContractViolation("link_pose() of an unknown link was accepted")
    effort = find_capability(act, EffortLimited)
    if effort is not None:
        before = np.array(act.limits.effort, dtype=float)
        try:
            effort.set_effort_limit(0, float(before[0]))
        except BenchError:
            pass  # refused for this joint (its servo cannot limit current): one line says why
        _require(np.array_equal(np.asarray(act.limits.effort, dtype=float), before),
                 "set_effort_limit(0, its present limit) changed limits.effort")
    reset = find_capability(act, PositionReset)
    if reset is not None:
        backend: Actuators = reset  # type: ignore[assignment] - the layer offering it: the backend
        q = _read(backend, n, "before reset_position()").position  # its own reading, under any fault
        reset.reset_position(q)
        _require(bool(np.allclose(_read(backend, n, "after reset_position()").position, q, atol=1e-9)),
                 "reset_position(present position) moved the joints")


def _check_physical(load: ExternalLoad | None, friction: FrictionScaled | None, n: int, where: str) -> None:
    """A load and a friction scale that change nothing (none, as identified) are taken; a joint that
    is not one, or a value that is not finite, is refused in one line (BenchError) before it reaches
    the physics."""
    calls = []
    if load is not None:
        calls.append(("set_external_effort", load.set_external_effort, 0.0))
    if friction is not None:
        calls.append(("set_friction_scale", friction.set_friction_scale, 1.0))
    for name, call, unchanged in calls:
        call(0, unchanged)
        for joint, value in ((n, unchanged), (-1, unchanged), (0, math.nan)):
            try:
                call(joint, value)
            except BenchError:
                continue
            raise ContractViolation(f"{name}({joint}, {value}) on {where} was accepted: "
                                    "not a joint, or not a value")


def _check_active_capabilities(act: Actuators, n: int, q: np.ndarray) -> None:
    """The capabilities that need enabled actuators; none moves the joints."""
    reset = find_capability(act, PositionReset)
    if reset is not None:
        try:
            reset.reset_position(q)
        except ActuatorError:
            pass
        else:
            raise ContractViolation("reset_position() while enabled was accepted: the robot would jump")
    loop = find_capability(act, HostLoop)
    if loop is not None:  # told by joint name, as DroppedStatus tells it; the next command still goes
        try:
            loop.status_lost(list(act.joint_names))
        except Exception as e:  # noqa: BLE001 - any exception is the finding
            raise ContractViolation(f"status_lost(joint names) raised {type(e).__name__}: {e}") from e
    enc = find_capability(act, SensedEncoder)
    if enc is not None and enc.encoder_joint is not None:  # what the servo read at the last read
        _require(enc.encoder_joint in act.joint_names,
                 f"encoder_joint {enc.encoder_joint!r} is not one of the joints {list(act.joint_names)}")
        _read(act, n, "for the encoder's reading")
        got = enc.encoder_position()
        _require(isinstance(got, float) and math.isfinite(got),
                 f"encoder_position() after a read is {got!r}, not a position")
    bus = find_capability(act, BusTiming)
    if bus is not None:  # a read is a bus transaction: its time shows in the next take, then none
        bus.bus_time()
        _read(act, n, "to time the bus")
        took, again = bus.bus_time(), bus.bus_time()
        _require(isinstance(took, float) and math.isfinite(took) and took > 0,
                 f"bus_time() after a read is {took!r}: a read on the bus takes time")
        _require(again == 0.0, f"bus_time() right after a take is {again!r}: it counts from the last take")
    blocks = find_capability(act, BlockExecution)
    if blocks is act:  # the runner's fast path: only ever on the outermost layer
        states = blocks.execute_block(q[None, :], np.zeros((1, n)), np.array([act.now() + 0.002]))
        _require(np.shape(states.position) == (1, n) and np.shape(states.time) == (1,),
                 f"execute_block() of one cycle gave {np.shape(states.position)} positions")
        _require(not np.asarray(states.position).flags.writeable, "execute_block() states are writable: a "
                 "caller's edit would change what rewind() restores")
        st = blocks.rewind(0)
        _require(isinstance(st, JointState) and st.time == float(states.time[0])
                 and np.array_equal(st.position, states.position[0]),
                 "rewind(0) did not return the state read at the block's first cycle")


def check_actuators(act: Actuators) -> None:
    """Run the contract checks on fresh, not yet enabled actuators; closes them at the end.

    Raises :class:`ContractViolation` naming the first broken rule.
    """
    n = _check_static(act)
    _require(not act.enabled, "enabled before enable()")
    st = _read(act, n, "before enable()")
    _check_reading_is_immutable(act, n, "before enable()")
    _check_idle_capabilities(act, n)
    _refuses(act, NotEnabledError, "command() before enable()", st.position)
    act.enable()
    _require(act.enabled, "enable() did not enable")
    st = _read(act, n, "after enable()")
    q = st.position.copy()
    _refuses(act, CommandError, "a command of the wrong length", np.zeros(n + 1))
    _refuses(act, CommandError, "a command with NaN", np.where(np.arange(n) == 0, np.nan, q))
    _refuses(act, CommandError, "a command with inf", np.where(np.arange(n) == n - 1, np.inf, q))
    _refuses(act, CommandError, "a velocity of the wrong length", q, np.zeros(n - 1 if n > 1 else 2))
    _check_active_capabilities(act, n, q)
    t0 = act.now()
    act.command(q, np.zeros(n))
    act.wait_until(t0 + 0.01)
    t1 = act.now()
    _require(t1 >= t0 + 0.01 - 1e-9, f"wait_until({t0 + 0.01:.4f}) returned at now() = {t1:.4f}")
    st = _read(act, n, "after a command")
    _require(st.time >= t0 - 1e-9, f"read().time {st.time} went back before now() {t0}")
    _check_reading_is_immutable(act, n, "while enabled")
    act.disable()
    _require(not act.enabled, "disable() left the actuators enabled")
    report = find_capability(act, SafeStopReport)
    if report is not None:
        said = report.safe_stop_report
        _require(isinstance(said, str) and bool(said), f"safe_stop_report after disable() is {said!r}: "
                 "it must say how the joints were left")
    _refuses(act, NotEnabledError, "command() after disable()", q)
    act.close()
    act.close()  # idempotent
    try:
        act.enable()
    except ActuatorError:
        pass
    else:
        raise ContractViolation("enable() after close() was accepted")
