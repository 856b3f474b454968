"""BAM's published servo models (Rhoban's "Better Actuator Models", Apache-2.0) as the bench's
servo parameters: its motor (Kt = Ke, R, armature), its friction laws m1–m6 and its choices
(no current limit, the nominal supply, the stand's angle offset).

BAM's friction budget is ``friction_base`` plus, per law, Stribeck (``friction_stribeck`` fading
as e^{-|ω/dtheta_stribeck|^alpha}), load-dependent (m3: ``load_friction_base``·|τ_e − τ_m|; m4
adds ``load_friction_stribeck`` at rest; m5, m6: separate motor and external coefficients; m6
quadratic terms) and viscous ``friction_viscous``·|ω|: the fields of
:class:`~drivers.servo.model.ServoParams` hold each of them (``bam/model.py`` of BAM).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from bench.stand.errors import StandError
from bench.stand.logs import MOTORS
from drivers.servo import ServoParams

__all__ = ["BAM_LAWS", "bam_params", "is_bam_file"]

#: BAM's laws -> the parameters each one's file must hold (beyond kt, R, armature, q_offset).
BAM_LAWS = {
    "m1": ("friction_base", "friction_viscous"),
    "m2": ("friction_base", "friction_stribeck", "dtheta_stribeck", "alpha", "friction_viscous"),
    "m3": ("friction_base", "load_friction_base", "friction_viscous"),
    "m4": ("friction_base", "friction_stribeck", "load_friction_base", "load_friction_stribeck",
           "dtheta_stribeck", "alpha", "friction_viscous"),
    "m5": ("friction_base", "friction_stribeck", "load_friction_motor", "load_friction_external",
           "load_friction_motor_stribeck", "load_friction_external_stribeck", "dtheta_stribeck", "alpha",
           "friction_viscous"),
    "m6": ("friction_base", "friction_stribeck", "load_friction_motor", "load_friction_external",
           "load_friction_motor_stribeck", "load_friction_external_stribeck", "load_friction_motor_quad",
           "load_friction_external_quad", "dtheta_stribeck", "alpha", "friction_viscous"),
}


def is_bam_file(path: Path) -> bool:
    """Whether ``path`` looks like one of BAM's parameter files (JSON with ``model`` and ``actuator``)."""
    if path.suffix.lower() != ".json" or not path.is_file():
        return False
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(data, dict) and "model" in data and "actuator" in data


def bam_params(path: Path) -> tuple[ServoParams, float, str]:
    """(servo parameters of one servo, the stand's angle offset in rad, the law) of a BAM file."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise StandError(f"{path}: not a BAM parameter file ({e})") from None
    law, actuator = data.get("model"), data.get("actuator")
    if law not in BAM_LAWS:
        raise StandError(f"{path}: model: unknown BAM law {law!r}; known: {', '.join(BAM_LAWS)}")
    if actuator not in MOTORS:
        raise StandError(f"{path}: actuator: {actuator!r} is not a servo the bench models; known: "
                         f"{', '.join(sorted(MOTORS))}")
    v: dict[str, float] = {}
    for key in ("kt", "R", "armature") + BAM_LAWS[law]:
        value = data.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise StandError(f"{path}: {key}: missing or not a finite number ({value!r})")
        v[key] = float(value)
    offset = float(data.get("q_offset", 0.0))
    stribeck = "friction_stribeck" in v
    directional = "load_friction_motor" in v
    load = v.get("load_friction_base", 0.0)
    load_s = v.get("load_friction_stribeck", 0.0)
    p = ServoParams.datasheet([MOTORS[actuator]]).with_(
        kt=v["kt"], ke=v["kt"], resistance=v["R"], current_limit=math.inf, armature=v["armature"],
        coulomb=v["friction_base"], viscous=v["friction_viscous"],
        stribeck=v["friction_base"] + v["friction_stribeck"] if stribeck else 0.0,
        stribeck_velocity=v.get("dtheta_stribeck", 0.1), stribeck_alpha=v.get("alpha", 2.0),
        load_motor=v["load_friction_motor"] if directional else load,
        load_external=v["load_friction_external"] if directional else load,
        load_stribeck_motor=v["load_friction_motor_stribeck"] if directional else load_s,
        load_stribeck_external=v["load_friction_external_stribeck"] if directional else load_s,
        load_quad_motor=v.get("load_friction_motor_quad", 0.0),
        load_quad_external=v.get("load_friction_external_quad", 0.0))
    return p, offset, law
