"""Trial configurations (``hil_configs/*.yaml``) as pydantic models.

A bad file fails with one line naming the field path and what is wrong, before
anything is built or moves. Units in the files are the ones people read: mm
and degrees for targets, SI for joint limits and gains.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Optional, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

REPO_ROOT = Path(__file__).resolve().parent.parent


class ConfigError(ValueError):
    """A configuration file that cannot be used; the message names the field."""


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TargetConfig(Strict):
    """The needle target in the bed frame (README): entry point, depth and angle."""

    x_mm: float
    y_mm: float
    z_mm: float
    depth_mm: float = Field(ge=0)
    angle_deg: float
    tilt_deg: float = 0.0


class JointOverride(Strict):
    """Per-joint limits that replace the robot model's (SI units)."""

    effort: Optional[float] = Field(default=None, gt=0)
    velocity: Optional[float] = Field(default=None, gt=0)


class PyBulletBackendConfig(Strict):
    kind: Literal["pybullet"] = "pybullet"
    physics_hz: float = Field(default=1000.0, gt=0)
    position_gain: float = Field(default=1.0, gt=0, le=1.0)
    velocity_gain: float = Field(default=1.0, ge=0, le=2.0)
    solver_iterations: int = Field(default=10, ge=1, le=200)
    gantry_in_physics: bool = False
    safe_stop: Literal["hold", "off"] = "hold"
    joints: dict[str, JointOverride] = Field(default_factory=dict)


class PlanConfig(Strict):
    """home -> entry pose -> insertion along the needle axis -> (retract)."""

    trajectory: Literal["lspb", "ruckig", "ruckig-online"] = "lspb"
    velocity_scale: float = Field(default=0.5, gt=0, le=1.0)
    acceleration_scale: float = Field(default=2.0, gt=0, description="amax = vmax × this (1/s)")
    jerk_scale: float = Field(default=20.0, gt=0, description="jmax = amax × this (1/s), ruckig only")
    settle_s: float = Field(default=0.5, ge=0)
    retract: bool = True


class AcceptanceConfig(Strict):
    """Seed 000's limits: 5 mm in each of X, Y, Z and depth, 1° in angle."""

    position_mm: float = Field(default=5.0, gt=0)
    angle_deg: float = Field(default=1.0, gt=0)


class TrialConfig(Strict):
    name: str
    robot: Literal["arc-train"] = "arc-train"
    urdf_dir: Path = Path("urdf")
    control_hz: float = Field(default=500.0, gt=0)
    seed: int = 0
    target: TargetConfig
    plan: PlanConfig = PlanConfig()
    acceptance: AcceptanceConfig = AcceptanceConfig()
    backend: Annotated[Union[PyBulletBackendConfig], Field(discriminator="kind")] = PyBulletBackendConfig()

    # Where the file came from, to resolve relative paths; not part of the file.
    source: Optional[Path] = Field(default=None, exclude=True)

    @model_validator(mode="after")
    def _joint_names_known(self) -> "TrialConfig":
        from bench.robots import get_robot

        names = get_robot(self.robot).joint_names
        unknown = sorted(set(getattr(self.backend, "joints", {})) - set(names))
        if unknown:
            raise ValueError(f"backend.joints: unknown joint(s) {unknown}; {self.robot} has {names}")
        return self

    @property
    def control_period(self) -> float:
        return 1.0 / self.control_hz

    def resolve(self, path: Path) -> Path:
        """A path from the config, relative to the repository root if not absolute."""
        path = Path(path)
        if path.is_absolute():
            return path
        return REPO_ROOT / path

    @property
    def robot_urdf(self) -> Path:
        return self.resolve(self.urdf_dir) / f"{self.robot.replace('-', '_')}.urdf"


def _format_error(path: Path, err: ValidationError) -> str:
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"]
    if first["type"] == "extra_forbidden":
        msg = "unknown field"
    extra = f" (and {err.error_count() - 1} more)" if err.error_count() > 1 else ""
    return f"{path}: {where}: {msg}{extra}"


def load_trial_config(path: Path | str, overrides: dict | None = None) -> TrialConfig:
    """Read and validate a trial config; raise ConfigError with one clear line."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {e}".replace("\n", " ")) from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of fields at the top level")
    data.update(overrides or {})
    try:
        return TrialConfig.model_validate({**data, "source": path})
    except ValidationError as e:
        raise ConfigError(_format_error(path, e)) from None
