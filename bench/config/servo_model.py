"""Servo physics over the datasheet, in one schema for the emulated rig's hidden physics
(``emulator.servo_physics``) and the simulator's servo model files (``backend.servo_model: FILE``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Mapping, Optional, Sequence

from pydantic import Field, ValidationError

from bench.config.base import ConfigError, Strict, describe_validation_error, read_yaml_mapping
from bench.kinematics.registry import ROBOTS, get_robot
from drivers.servo import ServoParams

__all__ = ["FIELD_KEYS", "LogSource", "STAND_JOINT", "STAND_ROBOT", "ServoModelFile", "ServoPhysics",
           "StandSetup", "apply_physics", "load_servo_model_file", "physics_for"]

#: The one-servo test stand (a pendulum on a servo's horn) as a "robot" a model file may name.
STAND_ROBOT = "test-stand"
STAND_JOINT = "pendulum"


class ServoPhysics(Strict):
    """Hidden physics of an emulated servo (unset: today's values), at its output shaft."""

    coulomb_nm: Optional[float] = Field(default=None, ge=0, le=10, description="Coulomb friction (N·m)")
    viscous_nms: Optional[float] = Field(default=None, ge=0, le=100,
                                         description="viscous friction (N·m·s/rad)")
    stribeck_nm: Optional[float] = Field(default=None, ge=0, le=10,
                                         description="breakaway friction at rest, the Stribeck peak (N·m)")
    stribeck_velocity_rads: Optional[float] = Field(default=None, gt=0, le=100,
                                                    description="speed where the Stribeck peak fades (rad/s)")
    armature_kgm2: Optional[float] = Field(default=None, gt=0, le=10,
                                           description="reflected rotor inertia (kg·m²)")
    kt_scale: Optional[float] = Field(default=None, gt=0, le=10,
                                      description="factor on the motor constant (Kt and Ke)")
    ke_scale: Optional[float] = Field(default=None, gt=0, le=10,
                                      description="further factor on the back-EMF constant Ke alone")
    resistance_ohm: Optional[float] = Field(default=None, gt=0, le=1000,
                                            description="the motor's winding resistance (Ω)")
    stribeck_alpha: Optional[float] = Field(default=None, ge=0.5, le=20,
                                            description="exponent of the Stribeck curve e^{-|ω/ω_s|^α} (2)")
    load_friction: Optional[float] = Field(
        default=None, ge=0, le=5,
        description="friction per N·m the gearbox carries, |τ_load − τ_motor| (BAM m3); sets both sides")
    load_friction_motor: Optional[float] = Field(default=None, ge=0, le=5,
                                                 description="load friction on the motor's torque alone")
    load_friction_external: Optional[float] = Field(default=None, ge=0, le=5,
                                                    description="load friction on the load's torque alone")
    load_stribeck: Optional[float] = Field(
        default=None, ge=0, le=5, description="extra load friction at rest, fading as the Stribeck peak")
    load_stribeck_motor: Optional[float] = Field(default=None, ge=0, le=5,
                                                 description="load friction at rest on the motor's torque")
    load_stribeck_external: Optional[float] = Field(default=None, ge=0, le=5,
                                                    description="load friction at rest on the load's torque")
    load_quadratic_motor: Optional[float] = Field(default=None, ge=0, le=5,
                                                  description="friction at rest per (N·m)² of motor torque")
    load_quadratic_external: Optional[float] = Field(default=None, ge=0, le=5,
                                                     description="friction at rest per (N·m)² of load torque")


#: Model-file keys -> the ServoParams field each sets as given.
FIELD_KEYS = {"coulomb_nm": "coulomb", "viscous_nms": "viscous", "stribeck_nm": "stribeck",
              "stribeck_velocity_rads": "stribeck_velocity", "armature_kgm2": "armature",
              "resistance_ohm": "resistance", "stribeck_alpha": "stribeck_alpha",
              "load_friction_motor": "load_motor", "load_friction_external": "load_external",
              "load_stribeck_motor": "load_stribeck_motor", "load_stribeck_external": "load_stribeck_external",
              "load_quadratic_motor": "load_quad_motor", "load_quadratic_external": "load_quad_external"}
#: Keys that set both sides of the load friction unless a side is given.
_BOTH_SIDES = {"load_friction": ("load_friction_motor", "load_friction_external"),
               "load_stribeck": ("load_stribeck_motor", "load_stribeck_external")}


def apply_physics(params: ServoParams, per_joint: Sequence[Mapping[str, float]]) -> ServoParams:
    """``params`` with each joint's physics (model-file keys) set; what a joint leaves unset keeps
    its value. Kt and Ke scale by ``kt_scale``, Ke further by ``ke_scale``."""
    expanded = []
    for physics in per_joint:
        d = dict(physics)
        for key, sides in _BOTH_SIDES.items():
            if key in d:
                for side in sides:
                    d.setdefault(side, d[key])
        expanded.append(d)
    changes = {field: [p.get(key, getattr(params, field)[j]) for j, p in enumerate(expanded)]
               for key, field in FIELD_KEYS.items()}
    scaled = params.with_(**changes).with_motor_scale([p.get("kt_scale", 1.0) for p in expanded])
    return scaled.with_(ke=scaled.ke * [p.get("ke_scale", 1.0) for p in expanded])


class StandSetup(Strict):
    """What a test-stand model knows of the stand beside the servo."""

    gravity_offset_rad: float = Field(default=0.0, ge=-0.5, le=0.5,
                                      description="the stand's zero from hanging plumb (rad)")


def physics_for(entries: Mapping[str, ServoPhysics], joint: str) -> dict[str, float]:
    """The physics ``entries`` set for ``joint``: its own entry over ``all``, unset keys left out."""
    out: dict[str, float] = {}
    for key in ("all", joint):
        if key in entries:
            out.update(entries[key].model_dump(exclude_none=True))
    return out


class LogSource(Strict):
    """One trial log a model was identified from."""

    run: str = Field(max_length=4096, description="the run directory (or the test-stand log)")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="SHA-256 of its trial.npz (or of the log)")


class ServoModelFile(Strict):
    """A servo model file: the physics of a rig's servos over their datasheet, per joint or ``all``
    (a joint's own entry wins), in the units of ``emulator.servo_physics``. An identified file
    also carries each value's standard error, what the logs could not tell, and the logs."""

    robot: str = Field(description="the robot whose servos these are")
    joints: dict[str, ServoPhysics] = Field(default_factory=dict, max_length=32,
                                            description="physics by joint name or all")
    uncertainty: dict[str, dict[str, float]] = Field(
        default_factory=dict, max_length=32,
        description="one standard error per joint and key, in the key's unit (identified files)")
    unobservable: dict[str, list[str]] = Field(
        default_factory=dict, max_length=32,
        description="per joint, the keys the logs could not tell (kept at the datasheet's value)")
    sources: list[LogSource] = Field(default_factory=list, max_length=1000,
                                     description="the trial logs the model was identified from")
    twin_sigma: dict[str, Annotated[float, Field(ge=0, le=1)]] = Field(
        default_factory=dict, max_length=32,
        description="per joint, the spread (σ, rad or m) of the twin's residual on the logs the model "
                    "was identified from: what the monitor divides by (identified files)")
    twin_sigma_current: dict[str, Annotated[float, Field(ge=0, le=10)]] = Field(
        default_factory=dict, max_length=32,
        description="per joint, the spread (σ, A at the motor) of the twin's current residual on those "
                    "logs (identified files)")
    notes: list[str] = Field(default_factory=list, max_length=100,
                             description="where the numbers came from (logs, fit, by hand)")
    servo: Optional[str] = Field(default=None, max_length=64,
                                 description="the servo model the physics are over (test stand: XL330-M288)")
    supply: Literal["measured", "nominal"] = Field(
        default="measured",
        description="drive the motor with a log's measured supply voltage, or the nominal")
    stand: Optional[StandSetup] = Field(default=None, description="the test stand's own figures (test-stand)")

    def physics_of(self, joint: str) -> dict[str, float]:
        """The physics set for ``joint``: its own entry over ``all``, unset keys left out."""
        return physics_for(self.joints, joint)


def load_servo_model_file(path: Path | str) -> ServoModelFile:
    """A servo model file, or ConfigError with one line saying what is wrong in it."""
    path = Path(path)
    data = read_yaml_mapping(path, "servo model file", ConfigError)
    try:
        model = ServoModelFile.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, ServoModelFile, path)) from None
    names = ([STAND_JOINT] if model.robot == STAND_ROBOT
             else get_robot(model.robot).joint_names if model.robot in ROBOTS else None)
    if names is None:
        raise ConfigError(f"{path}: robot: unknown robot {model.robot!r}")
    unknown = sorted(set(model.joints) - set(names) - {"all"})
    if unknown:
        raise ConfigError(f"{path}: joints: unknown joint(s) {unknown}; {model.robot} has {names} (or all)")
    return model
