"""Servo physics over the datasheet, in one schema for the emulated rig's hidden physics
(``emulator.servo_physics``) and the simulator's servo model files (``backend.servo_model: FILE``)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Optional

from pydantic import Field, ValidationError

from bench.config.base import ConfigError, Strict, describe_validation_error, read_yaml_mapping
from bench.kinematics.registry import ROBOTS, get_robot

__all__ = ["LogSource", "ServoModelFile", "ServoPhysics", "load_servo_model_file", "physics_for"]


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


def physics_for(entries: Mapping[str, ServoPhysics], joint: str) -> dict[str, float]:
    """The physics ``entries`` set for ``joint``: its own entry over ``all``, unset keys left out."""
    out: dict[str, float] = {}
    for key in ("all", joint):
        if key in entries:
            out.update(entries[key].model_dump(exclude_none=True))
    return out


class LogSource(Strict):
    """One trial log a model was identified from."""

    run: str = Field(max_length=4096, description="the run directory")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="SHA-256 of its trial.npz")


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
    notes: list[str] = Field(default_factory=list, max_length=100,
                             description="where the numbers came from (logs, fit, by hand)")

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
    names = get_robot(model.robot).joint_names if model.robot in ROBOTS else None
    if names is None:
        raise ConfigError(f"{path}: robot: unknown robot {model.robot!r}")
    unknown = sorted(set(model.joints) - set(names) - {"all"})
    if unknown:
        raise ConfigError(f"{path}: joints: unknown joint(s) {unknown}; {model.robot} has {names} (or all)")
    return model
