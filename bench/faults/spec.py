"""Faults as declared in a trial config, validated, and stacked around a backend.

A trial config lists faults by name with parameters in readable units and
the joints they hit::

    faults:
      - {name: deadband, joints: all, tol_deg: 0.29}
      - {name: torque_limit, joints: [theta5], scale: 0.2}

:func:`parse_faults` checks names, parameters, values and joints before
anything is built (errors list what is valid); :func:`apply_faults` wraps
the backend, first fault innermost (next to the backend), each fault drawing
from its own generator keyed by its name and rank, so adding or removing
one fault never changes another's draws.
"""

from __future__ import annotations

import math
import zlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bench.faults.base import joint_kinds, kinds_for_names
from bench.faults.comms import DroppedStatus, EmulatorStatusFault, LateStatus, emulator_fault_target
from bench.faults.physical import Contact, FrictionDrift, Stuck, contact_efforts, require_physical
from bench.faults.tolerance import Backlash, Bias, Deadband, Noise, Quantisation
from bench.faults.torque import TorqueLimit, check_effort_limit
from bench.faults.ultrasonic import UltrasonicDropout, UltrasonicNoise, UltrasonicStuck
from bench.kinematics.arc_train import PINION_RADIUS
from bench.kinematics.transmission import SERVO_TOL_DEG, slide_tolerance_m, transmissions_for_names
from drivers import Actuators, BackendSetupError
from drivers.capabilities import ExternalLoad, FrictionScaled
from drivers.dynamixel.control_table import x_series_table
from drivers.dynamixel.units import TICKS_PER_REV

__all__ = ["FAULTS", "FaultDef", "FaultSpec", "Param", "apply_faults", "fault_names", "parse_faults"]

_TO_SI = {"deg": math.pi / 180.0, "mm": 1e-3, "ms": 1e-3, "s": 1.0, "N·m": 1.0, "N": 1.0, "": 1.0}
# The prismatic joints are rack-and-pinion on the same servos: a servo angle maps to
# PINION_RADIUS of travel per radian.
PINION_RADIUS_MM = PINION_RADIUS * 1e3
SELECTORS = ("all", "revolute", "prismatic")


@dataclass(frozen=True)
class Param:
    """One parameter of a fault, in the unit the YAML uses; ``kind`` limits it to
    revolute or prismatic joints."""

    name: str
    default: Any
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] | None = None
    integer: bool = False
    kind: str | None = None
    optional: bool = False

    def check(self, value: Any, where: str) -> Any:
        if value is None and self.optional:
            return None
        if self.choices is not None:
            if value not in self.choices:
                raise ValueError(f"{where}: {self.name} must be one of {', '.join(self.choices)}; "
                                 f"got {value!r}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where}: {self.name} must be a number"
                             f"{' (' + self.unit + ')' if self.unit else ''}, got {value!r}")
        if self.integer and float(value) != int(value):
            raise ValueError(f"{where}: {self.name} must be a whole number, got {value!r}")
        v = int(value) if self.integer else float(value)
        if not math.isfinite(v) and not (v == math.inf and self.hi is None):
            raise ValueError(f"{where}: {self.name} must be finite, got {value!r}")
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            raise ValueError(f"{where}: {self.name} must be {'>' if self.lo_open else '>='} "
                             f"{self.lo:g}, got {value!r}")
        if self.hi is not None and v > self.hi:
            raise ValueError(f"{where}: {self.name} must be <= {self.hi:g}, got {value!r}")
        return v

    def si(self, value: Any) -> Any:
        return value * _TO_SI[self.unit] if isinstance(value, (int, float)) else value


@dataclass(frozen=True)
class FaultSpec:
    """A validated fault: its name, the joints it hits and its parameters (YAML units)."""

    name: str
    joints: tuple[str, ...]
    params: Mapping[str, Any] = field(default_factory=dict)
    selector: Any = "all"  # the joints as written (``all``, a kind, or names)

    def si(self, key: str) -> Any:
        """A parameter converted to SI (rad, m, s)."""
        return FAULTS[self.name].param(key).si(self.params[key])

    def as_dict(self) -> dict[str, Any]:
        """The spec as it would be written in YAML (defaults filled in)."""
        out: dict[str, Any] = {"name": self.name}
        if FAULTS[self.name].joints != "train":
            out["joints"] = self.selector
        out.update(self.params)
        return out


Builder = Callable[[Actuators, FaultSpec, np.ndarray, list, np.random.Generator], Actuators]
#: Parameters checked against the joints hit and their kinds (ValueError saying what is wrong).
Validator = Callable[[Mapping[str, Any], Sequence[str], Sequence[str]], Any]


@dataclass(frozen=True)
class FaultDef:
    """A fault the bench knows: its parameters, default joints and how to build it."""

    name: str
    summary: str
    params: tuple[Param, ...]
    build: Builder
    joints: str = "all"  # default selector; "" = must be given; "train" = the ultrasonic joint only
    check: Callable[[Actuators, FaultSpec], None] | None = None
    validate: Validator | None = None

    def param(self, key: str) -> Param:
        return next(p for p in self.params if p.name == key)

    @property
    def valid_parameters(self) -> list[str]:
        keys = [p.name for p in self.params]
        return sorted(keys + ([] if self.joints == "train" else ["joints"]))


# ---------------------------------------------------------------------------
# Builders: spec -> wrapper
# ---------------------------------------------------------------------------


def _per_joint(spec: FaultSpec, idx: np.ndarray, kinds: list, n: int, deg_key: str | None,
               mm_key: str | None) -> np.ndarray:
    """An SI amount for every joint: the revolute one on revolute targets, the prismatic one
    on prismatic targets, zero elsewhere."""
    out = np.zeros(n)
    for j in idx:
        key = deg_key if kinds[j] == "revolute" else mm_key
        if key is not None:
            out[j] = spec.si(key)
    return out


def _deadband(act, spec, idx, kinds, rng):
    """``tol_deg`` is the servo's: a revolute joint strays by it through its transmission (the
    train, on the arc's rack, by R_pinion/R_arc of it); ``tol_mm`` is a slide's travel."""
    tol = _per_joint(spec, idx, kinds, len(kinds), "tol_deg", "tol_mm")
    ratio = transmissions_for_names(act.joint_names, kinds)
    return Deadband(act, np.where(np.asarray(kinds) == "revolute", tol * ratio, tol), rng)


def _bias(act, spec, idx, kinds, rng):
    return Bias(act, _per_joint(spec, idx, kinds, len(kinds), "bias_deg", "bias_mm"))


def _backlash(act, spec, idx, kinds, rng):
    play = _per_joint(spec, idx, kinds, len(kinds), "play_deg", "play_mm")
    side = spec.params["engaged"]
    engaged = np.ones(len(kinds))
    if side == "backward":
        engaged[:] = -1.0
    elif side == "random":
        engaged[idx] = rng.choice([-1.0, 1.0], size=idx.size)
    return Backlash(act, play, engaged)


def _quantisation(act, spec, idx, kinds, rng):
    step = np.zeros(len(kinds))
    for j in idx:
        step[j] = (2 * math.pi / spec.params["ticks_per_rev"] if kinds[j] == "revolute"
                   else spec.si("step_mm"))
    return Quantisation(act, step)


def _noise(act, spec, idx, kinds, rng):
    return Noise(act, _per_joint(spec, idx, kinds, len(kinds), "std_deg", "std_mm"), rng)


def _torque_limit(act, spec, idx, kinds, rng):
    return TorqueLimit(act, spec.joints, spec.params["scale"])


def _on_bus(act, spec, field_name: str, whole_bus: bool) -> bool:
    level = spec.params.get("level", "bus")
    if level == "wrapper":
        return False
    hook = emulator_fault_target(act, field_name) is not None
    if level == "bus":
        return True  # EmulatorStatusFault refuses clearly if the hook is missing
    return hook and whole_bus


def _dropped_status(act, spec, idx, kinds, rng):
    if _on_bus(act, spec, "drop_prob", idx.size == len(kinds)):
        return EmulatorStatusFault(act, "drop_prob", spec.params["prob"])
    return DroppedStatus(act, idx, spec.params["prob"], rng)


def _late_status(act, spec, idx, kinds, rng):
    p = spec.params
    if _on_bus(act, spec, "delay_s", idx.size == len(kinds) and p["prob"] == 1.0):
        return EmulatorStatusFault(act, "delay_s", spec.si("delay_ms"))
    return LateStatus(act, idx, p["prob"], spec.si("delay_ms"), rng)


def _corrupt_crc(act, spec, idx, kinds, rng):
    return EmulatorStatusFault(act, "corrupt_crc_prob", spec.params["prob"])


def _ultrasonic_dropout(act, spec, idx, kinds, rng):
    return UltrasonicDropout(act, spec.params["prob"], rng)


def _ultrasonic_stuck(act, spec, idx, kinds, rng):
    p = spec.params
    return UltrasonicStuck(act, p["at_s"], math.inf if p["for_s"] is None else p["for_s"])


def _ultrasonic_noise(act, spec, idx, kinds, rng):
    return UltrasonicNoise(act, spec.si("std_mm"), rng)


def _contact(act, spec, idx, kinds, rng):
    p = spec.params
    hit = [kinds[j] for j in idx]
    try:
        effort = contact_efforts(p, spec.joints, hit)
    except ValueError as e:  # a robot the parser could not check: the backend's kinds say it here
        raise BackendSetupError(f"contact: {e}") from None
    past = None
    if p["past_deg"] is not None or p["past_mm"] is not None:
        past = [spec.si("past_deg" if k == "revolute" else "past_mm") for k in hit]
    duration = math.inf if p["for_s"] is None else p["for_s"]
    return Contact(act, spec.joints, effort, p["from_s"], duration, past)


def _friction_drift(act, spec, idx, kinds, rng):
    p = spec.params
    return FrictionDrift(act, spec.joints, p["factor"], p["from_s"], p["over_s"])


def _stuck(act, spec, idx, kinds, rng):
    p = spec.params
    return Stuck(act, spec.joints, p["from_s"], math.inf if p["for_s"] is None else p["for_s"])


# ---------------------------------------------------------------------------
# Capability checks made before any wrapper is built
# ---------------------------------------------------------------------------


def _check_torque(act: Actuators, spec: FaultSpec) -> None:
    check_effort_limit(act)


def _check_hook(field_name: str) -> Callable[[Actuators, FaultSpec], None]:
    def check(act: Actuators, spec: FaultSpec) -> None:
        if spec.params.get("level", "bus") != "bus":
            return
        if emulator_fault_target(act, field_name) is None:
            backend = act.unwrapped
            raise BackendSetupError(
                f"{spec.name} needs a backend with emulator hooks (the emulated Dynamixel backend, "
                f"--emulate); {type(backend).__name__} has none"
                + ("" if spec.name == "corrupt_crc" else "; use level: wrapper or auto"))
    return check


def _check_physical(capability: type) -> Callable[[Actuators, FaultSpec], None]:
    def check(act: Actuators, spec: FaultSpec) -> None:
        require_physical(act, capability, spec.name)
    return check


def _check_late_bus(act: Actuators, spec: FaultSpec) -> None:
    _check_hook("delay_s")(act, spec)
    if spec.params["level"] == "bus" and spec.params["prob"] != 1.0:
        raise BackendSetupError("late_status on the bus delays every status packet: "
                                 f"use prob: 1 or level: wrapper (got prob {spec.params['prob']})")


_PROB = dict(lo=0.0, hi=1.0)
_FROM = Param("from_s", 0.0, "s", lo=0.0)
_FOR = Param("for_s", None, "s", lo=0.0, lo_open=True, optional=True)
_LEVEL = Param("level", "auto", choices=("auto", "wrapper", "bus"))

FAULTS: dict[str, FaultDef] = {f.name: f for f in (
    FaultDef("deadband", "a servo settles anywhere within ±tol of its goal (a new draw every move; "
             "tol_deg through each joint's transmission: the train ±tol·10/200 of arc)",
             (Param("tol_deg", SERVO_TOL_DEG, "deg", lo=0.0, kind="revolute"),
              Param("tol_mm", slide_tolerance_m() * 1e3, "mm", lo=0.0,
                    kind="prismatic")), _deadband),
    FaultDef("bias", "encoder offset: reads truth + bias, so the goal is reached at goal − bias",
             (Param("bias_deg", 0.0, "deg", kind="revolute"),
              Param("bias_mm", 0.0, "mm", kind="prismatic")), _bias),
    FaultDef("backlash", "play in a slide's rack (or a joint's gears): after a reversal the output trails "
             "the motor by the play, and the encoder, on the motor, does not see it (the cameras do)",
             (Param("play_mm", 0.5, "mm", lo=0.0, kind="prismatic"),
              Param("play_deg", 0.0, "deg", lo=0.0, kind="revolute"),
              Param("engaged", "forward", choices=("forward", "backward", "random"))),
             _backlash, joints="prismatic"),
    FaultDef("quantisation", "goal and present position in whole encoder ticks",
             (Param("ticks_per_rev", TICKS_PER_REV, lo=2, integer=True, kind="revolute"),
              Param("step_mm", round(PINION_RADIUS_MM * x_series_table()["Present Position"].scale, 6), "mm",
                    lo=0.0, lo_open=True, kind="prismatic")), _quantisation),
    FaultDef("noise", "Gaussian measurement noise on read positions",
             (Param("std_deg", 0.05, "deg", lo=0.0, kind="revolute"),
              Param("std_mm", 0.05, "mm", lo=0.0, kind="prismatic")), _noise),
    FaultDef("torque_limit", "a joint's available torque or force scaled down (it lags or stalls)",
             (Param("scale", 0.5, lo=0.0, lo_open=True, hi=1.0),), _torque_limit, joints="",
             check=_check_torque),
    FaultDef("dropped_status", "status packets lost: a joint keeps its last value, flagged stale",
             (Param("prob", 0.05, **_PROB), _LEVEL), _dropped_status, check=_check_hook("drop_prob")),
    FaultDef("late_status", "status packets late: a joint reports an older sample, flagged late",
             (Param("prob", 0.05, **_PROB), Param("delay_ms", 2.0, "ms", lo=0.0, lo_open=True), _LEVEL),
             _late_status, check=_check_late_bus),
    FaultDef("corrupt_crc", "status packets with a wrong CRC (emulated bus only)",
             (Param("prob", 0.05, **_PROB),), _corrupt_crc, check=_check_hook("corrupt_crc_prob")),
    FaultDef("ultrasonic_dropout", "the train's distance reading missing: last one held, flagged stale",
             (Param("prob", 0.1, **_PROB),), _ultrasonic_dropout, joints="train"),
    FaultDef("ultrasonic_stuck", "the train's distance reading frozen (no flag)",
             (Param("at_s", 0.0, "s", lo=0.0), Param("for_s", None, "s", lo=0.0, optional=True)),
             _ultrasonic_stuck, joints="train"),
    FaultDef("ultrasonic_noise", "Gaussian noise on the train's distance d2, seen as its arc angle",
             (Param("std_mm", 1.0, "mm", lo=0.0),), _ultrasonic_noise, joints="train"),
    FaultDef("contact", "an external torque (revolute) or force (prismatic) on a joint from from_s, or "
             "once it passes past_deg/past_mm, for for_s or to the end: its servo fights it (sags, lags)",
             (Param("torque_nm", None, "N·m", lo=-100.0, hi=100.0, kind="revolute", optional=True),
              Param("force_n", None, "N", lo=-1000.0, hi=1000.0, kind="prismatic", optional=True), _FROM, _FOR,
              Param("past_deg", None, "deg", kind="revolute", optional=True),
              Param("past_mm", None, "mm", kind="prismatic", optional=True)),
             _contact, joints="", check=_check_physical(ExternalLoad), validate=contact_efforts),
    FaultDef("friction_drift", "a joint's friction (every level of the servo model's law) growing from its "
             "identified value to factor × it over over_s from from_s, then staying",
             (Param("factor", 2.0, lo=0.0, hi=20.0), _FROM, Param("over_s", 0.0, "s", lo=0.0)),
             _friction_drift, joints="", check=_check_physical(FrictionScaled)),
    FaultDef("stuck", "a joint that stops following from from_s (for for_s or to the end): its servo "
             "keeps the goal it had then", (_FROM, _FOR), _stuck, joints=""),
)}


def fault_names() -> list[str]:
    return sorted(FAULTS)


# ---------------------------------------------------------------------------
# Parsing
# ---------------------------------------------------------------------------


def _resolve_joints(selector: Any, names: list[str], kinds: Sequence[str] | None, where: str,
                    ) -> tuple[str, ...]:
    valid = f"joints are {', '.join(names)}, or one of {', '.join(SELECTORS)}"
    if isinstance(selector, str) and selector in SELECTORS:
        if selector == "all":
            return tuple(names)
        if kinds is None:
            raise ValueError(f"{where}: joints: {selector!r} needs the joint kinds, unknown for "
                             f"{names}; name the joints")
        return tuple(n for n, k in zip(names, kinds) if k == selector)
    items = [selector] if isinstance(selector, str) else selector
    if not isinstance(items, (list, tuple)) or not items or not all(isinstance(i, str) for i in items):
        raise ValueError(f"{where}: joints must be a joint name or a list of them; {valid}; "
                         f"got {selector!r}")
    unknown = [i for i in items if i not in names]
    if unknown:
        raise ValueError(f"{where}: unknown joint{'s' if len(unknown) > 1 else ''} "
                         f"{', '.join(repr(u) for u in unknown)}; {valid}")
    if len(set(items)) != len(items):
        raise ValueError(f"{where}: joints lists a joint twice: {items}")
    return tuple(n for n in names if n in items)


def parse_fault(raw: Mapping[str, Any], joint_names: Sequence[str], where: str = "fault") -> FaultSpec:
    """One fault from its YAML mapping; ValueError naming the bad name, parameter or joint."""
    names = list(joint_names)
    if not isinstance(raw, Mapping):
        raise ValueError(f"{where}: expected a mapping like {{name: deadband, joints: all}}, got {raw!r}")
    name = raw.get("name")
    if name not in FAULTS:
        what = "missing 'name'" if name is None else f"unknown fault {name!r}"
        raise ValueError(f"{where}: {what}; valid faults: {', '.join(fault_names())}")
    fdef = FAULTS[name]
    where = f"{where} ({name})"
    unknown = sorted(set(raw) - {"name"} - set(fdef.valid_parameters))
    if unknown:
        raise ValueError(f"{where}: unknown parameter{'s' if len(unknown) > 1 else ''} "
                         f"{', '.join(repr(u) for u in unknown)}; valid parameters of {name}: "
                         f"{', '.join(fdef.valid_parameters)}")
    kinds = kinds_for_names(tuple(names))
    if fdef.joints == "train":
        if "train" not in names:
            raise ValueError(f"{where}: needs the ultrasonic-measured joint 'train'; joints are "
                             f"{', '.join(names)}")
        selector: Any = "train"
        joints: tuple[str, ...] = ("train",)
    else:
        if "joints" not in raw and not fdef.joints:
            raise ValueError(f"{where}: joints must be given (e.g. joints: [{names[-1]}]); "
                             f"joints are {', '.join(names)}, or one of {', '.join(SELECTORS)}")
        selector = raw.get("joints", fdef.joints)
        joints = _resolve_joints(selector, names, kinds, where)
        if not joints:
            raise ValueError(f"{where}: joints: {selector!r} selects no joint of {names}")
    params = {p.name: p.check(raw[p.name], where) if p.name in raw else p.default for p in fdef.params}
    if kinds is not None:
        hit = {kinds[names.index(j)] for j in joints}
        for p in fdef.params:
            if p.kind and p.name in raw and p.kind not in hit:
                raise ValueError(f"{where}: {p.name} applies to {p.kind} joints, and none of "
                                 f"{list(joints)} is {p.kind}")
    if name == "corrupt_crc" and len(joints) != len(names):
        raise ValueError(f"{where}: CRC faults act on the whole bus; joints must be all")
    if fdef.validate is not None and kinds is not None:
        try:
            fdef.validate(params, joints, [kinds[names.index(j)] for j in joints])
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
    return FaultSpec(name, joints, params, selector if isinstance(selector, str) else list(selector))


def parse_faults(specs: Sequence[Mapping[str, Any]] | None, joint_names: Sequence[str]) -> list[FaultSpec]:
    """Validate a config's ``faults:`` list; ValueError naming the first bad entry."""
    if specs is None:
        return []
    if not isinstance(specs, (list, tuple)):
        raise ValueError(f"faults: expected a list of faults, got {specs!r}")
    return [s if isinstance(s, FaultSpec) else parse_fault(s, joint_names, f"faults[{i}]")
            for i, s in enumerate(specs)]


# ---------------------------------------------------------------------------
# Stacking
# ---------------------------------------------------------------------------


def _root_sequence(rng: np.random.Generator) -> np.random.SeedSequence:
    seq = getattr(rng.bit_generator, "seed_seq", None)
    if isinstance(seq, np.random.SeedSequence):
        return seq
    return np.random.SeedSequence(int(rng.integers(2 ** 63)))


def fault_generator(rng: np.random.Generator, name: str, rank: int) -> np.random.Generator:
    """The generator of the ``rank``-th fault called ``name``: keyed, not positional."""
    root = _root_sequence(rng)
    key = (zlib.crc32(name.encode()), rank)
    return np.random.default_rng(np.random.SeedSequence(root.entropy, spawn_key=root.spawn_key + key))


def apply_faults(actuators: Actuators, specs: Sequence[FaultSpec | Mapping[str, Any]],
                 rng: np.random.Generator) -> Actuators:
    """Wrap ``actuators`` in the faults, first one innermost; refuse before wrapping anything
    when the backend lacks what a fault needs (BackendSetupError naming both)."""
    parsed = parse_faults(list(specs), actuators.joint_names)
    for spec in parsed:
        check = FAULTS[spec.name].check
        if check is not None:
            check(actuators, spec)
    kinds = joint_kinds(actuators) if parsed else []
    names = list(actuators.joint_names)
    ranks: Counter[str] = Counter()
    act = actuators
    for spec in parsed:
        idx = np.array([names.index(j) for j in spec.joints], dtype=int)
        gen = fault_generator(rng, spec.name, ranks[spec.name])
        ranks[spec.name] += 1
        act = FAULTS[spec.name].build(act, spec, idx, kinds, gen)
    return act
