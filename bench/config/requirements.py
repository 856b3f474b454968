"""Requirements: named Signal Temporal Logic formulas over a trial's logged signals.

A trial config or a campaign spec may list ``requirements:``, each ``{name, formula}`` with an
optional ``scale`` (how much margin counts as "a lot" when a search compares requirements in
different units; default 1 of the requirement's unit). The formula is STL as rtamt reads it
(``always``, ``eventually``, ``until``, bounded ``always[0:0.5]`` in seconds, ``and``, ``or``,
``not``, ``abs(...)``, comparisons with numbers) over the signals of :func:`signal_names`.
Without ``requirements:`` a trial is judged by :func:`default_requirements`: the acceptance
limits at the end of the insertion and the gantry clearance at all times.

The signals, in the units their names end in (mm, deg; current in A, effort as the backend
reads it):

- the placement at the end of the insertion, the same value at every sample (seed 000 reads it
  as the median of the insertion's last 0.1 s): ``tip_dx_mm``, ``tip_dy_mm``, ``tip_dz_mm``,
  ``entry_dx_mm``, ``entry_dy_mm``, ``entry_dz_mm``, ``depth_dev_mm``, ``angle_dev_deg`` — where
  the backend knows where the joints really are (the simulators) from that truth, else measured;
  ``measured_`` before any of them: always from the readings;
- every sample: ``gantry_clearance_mm`` (a lower bound of the robot's distance to the CT gantry),
  ``track_<joint>_deg`` / ``track_<joint>_mm`` (|measured − commanded|), ``effort_<joint>``
  (the joint's torque, force or current as read), ``twin_z_<joint>`` (the twin's residual in
  σ, a monitored trial only).

Validation refuses, in one line naming the requirement, a formula rtamt cannot parse or one
that names a signal the trial does not log.
"""

from __future__ import annotations

import re
import warnings
from typing import Sequence

from pydantic import BaseModel, ConfigDict, Field, field_validator

__all__ = ["PLACEMENT_SIGNALS", "REQUIREMENTS_HELP", "Requirement", "check_requirements", "default_requirements",
           "formula_signals", "formula_unit", "is_temporal", "rtamt_module", "signal_names", "signal_unit"]

REQUIREMENTS_HELP = ("named STL formulas over the trial's signals, each with its robustness (docs/campaigns.md, "
                     "Requirements); default: the acceptance limits at the end of the insertion and the "
                     "20 mm gantry clearance at all times")
#: The placement at the end of the insertion (truth where known), in mm and degrees.
PLACEMENT_SIGNALS = ("tip_dx_mm", "tip_dy_mm", "tip_dz_mm", "entry_dx_mm", "entry_dy_mm", "entry_dz_mm",
                     "depth_dev_mm", "angle_dev_deg")
#: rtamt's temporal operators: a formula with none reads one sample only (its value at an instant
#: is a function of the signals at that instant).
_TEMPORAL = frozenset("always eventually historically once since until unless rise fall prev next "
                      "G F H O S U X P R W".split())
#: Words of rtamt's STL that are not signals.
_KEYWORDS = _TEMPORAL | frozenset("and or not implies iff xor abs sqrt exp pow true false in out".split())
_IDENT = re.compile(r"(?<![\w.])([A-Za-z_][A-Za-z0-9_]*)")
_NUMBER_EXP = re.compile(r"(?<![\w.])(?:\d+\.?\d*|\.\d+)[eE][+-]?\d+")  # a number in e-notation, not a name


class Requirement(BaseModel):
    """One named STL formula; its robustness is in the units of the signals it compares."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", description="letters, digits, . _ -")
    formula: str = Field(min_length=1, max_length=2000,
                         description="STL over the trial's signals (docs/campaigns.md, Requirements)")
    scale: float = Field(default=1.0, gt=0, le=1e6,
                         description="a margin of this much (in the formula's units) counts as 1 when a "
                                     "search compares requirements")

    @field_validator("formula")
    @classmethod
    def _parses(cls, value: str) -> str:
        error = _parse_error(value)
        if error:
            raise ValueError(f"not an STL formula rtamt reads: {error}")
        return value


def formula_signals(formula: str) -> list[str]:
    """The signal names a formula uses, in order of first use."""
    text = _NUMBER_EXP.sub("0", formula)
    out: list[str] = []
    for m in _IDENT.finditer(text):
        word = m.group(1)
        if word not in _KEYWORDS and word not in out:
            out.append(word)
    return out


def is_temporal(formula: str) -> bool:
    """Whether a formula has a temporal operator (or a bounded interval): without one its
    robustness at a sample reads that sample alone."""
    text = _NUMBER_EXP.sub("0", formula)
    return "[" in formula or any(m.group(1) in _TEMPORAL for m in _IDENT.finditer(text))


def rtamt_module():
    """rtamt, imported on first use (0.1 s a config without requirements never pays), its parser's
    DeprecationWarnings (antlr4's typing.io) kept out of the bench's output."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import rtamt  # deferred: its parser's import is 0.1 s, and only a requirement needs it
    return rtamt


def _parse_error(formula: str) -> str:
    """rtamt's complaint about a formula ('' when it parses), every name declared a float."""
    spec = rtamt_module().StlDiscreteTimeOfflineSpecification()
    for name in formula_signals(formula):
        spec.declare_var(name, "float")
    spec.spec = formula
    try:
        spec.parse()
    except Exception as e:  # rtamt raises its own exception types, and ANTLR's
        text = str(e).replace("RTAMT Exception:", "").replace("<INVALID>, ", "")
        return " ".join(text.split())[:160] or type(e).__name__
    return ""


def signal_names(joints: Sequence[str], kinds: Sequence[str]) -> list[str]:
    """Every signal a trial of a robot with these joints (``revolute``/``prismatic``) logs."""
    out = list(PLACEMENT_SIGNALS) + [f"measured_{s}" for s in PLACEMENT_SIGNALS] + ["gantry_clearance_mm"]
    for j, k in zip(joints, kinds):
        out.append(f"track_{j}_{'mm' if k == 'prismatic' else 'deg'}")
    out += [f"effort_{j}" for j in joints] + [f"twin_z_{j}" for j in joints]
    return out


def formula_unit(formula: str) -> str:
    """The unit of a formula's robustness: its signals' (mm, deg, σ), "" when they have none or differ."""
    units = {signal_unit(s) for s in formula_signals(formula)}
    return units.pop() if len(units) == 1 else ""


def signal_unit(name: str) -> str:
    """The unit a signal's name ends in."""
    for suffix, unit in (("_mm", "mm"), ("_deg", "deg")):
        if name.endswith(suffix):
            return unit
    return "σ" if name.startswith("twin_z_") else ""


def check_requirements(reqs: Sequence[Requirement], robot: object, where: str = "requirements") -> None:
    """ValueError in one line for a repeated name or a signal a trial of ``robot`` does not log."""
    joints = list(robot.joint_names)  # type: ignore[attr-defined]
    kinds = [r.kind for r in robot.chain.rows]  # type: ignore[attr-defined]
    known = set(signal_names(joints, kinds))
    seen: set[str] = set()
    for i, r in enumerate(reqs):
        if r.name in seen:
            raise ValueError(f"{where}.{i} ({r.name}): the name is used twice")
        seen.add(r.name)
        unknown = [s for s in formula_signals(r.formula) if s not in known]
        if unknown:
            raise ValueError(f"{where}.{i} ({r.name}): unknown signal {unknown[0]!r} in {r.formula!r}; "
                             f"signals: the placement {', '.join(PLACEMENT_SIGNALS)} (measured_ before "
                             f"any: from the readings), gantry_clearance_mm, track_<joint>_deg|mm, "
                             f"effort_<joint>, twin_z_<joint>; joints {', '.join(joints)}")


def default_requirements(position_mm: float = 5.0, angle_deg: float = 1.0,
                         gantry_mm: float = 20.0) -> list[Requirement]:
    """The acceptance limits at the end of the insertion (seed 000: 5 mm per axis and depth, 1°)
    and the gantry clearance at all times (seed 001: 20 mm)."""
    p, a = f"{position_mm:g}", f"{angle_deg:g}"
    per_axis = lambda what: " and ".join(f"abs({what}_d{x}_mm) <= {p}" for x in "xyz")  # noqa: E731
    return [
        Requirement(name="tip", formula=per_axis("tip"), scale=position_mm),
        Requirement(name="entry", formula=per_axis("entry"), scale=position_mm),
        Requirement(name="depth", formula=f"abs(depth_dev_mm) <= {p}", scale=position_mm),
        Requirement(name="angle", formula=f"abs(angle_dev_deg) <= {a}", scale=angle_deg),
        Requirement(name="gantry", formula=f"always(gantry_clearance_mm >= {gantry_mm:g})", scale=gantry_mm),
    ]
