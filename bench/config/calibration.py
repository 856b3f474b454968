"""Calibration files: what ``hilbench calibrate`` measured, in a form trials load and record.

A calibration file (YAML, one per calibration run, dated) holds for one config:

* ``servos``: joint zero offsets, each servo's ``offset`` (the joint value at
  tick 2048, rad or m) that replaces the config's — present when the offsets
  were kept as a config override;
* ``homing_offsets``: the shaft-angle shifts written to the servos' Homing
  Offset registers instead — a record only, nothing to apply;
* ``ultrasonic``: the sensor's reading at d2 = 0 and its scale (mm of reading
  per mm of d2), which replace the config's ``standoff_mm``, with the stops
  they were fitted to and the fit's residual.

A trial config names it with ``calibration: PATH``; a trial reads it once
(:func:`applied_calibration`), the Dynamixel backend applies that content and
the trial's record keeps its path and that same content.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Literal, Optional, Protocol

import yaml
from pydantic import Field, ValidationError

from bench.config.base import ConfigError, Strict, describe_validation_error, read_yaml_mapping
from bench.config.crossref import transmission_refusal
from bench.kinematics.registry import get_robot

__all__ = ["CalibratedConfig", "CalibrationFile", "ServoCalibration", "UltrasonicCalibration", "UltrasonicStop",
           "applied_calibration", "calibration_of", "calibration_path", "calibration_record", "check_calibration",
           "load_calibration",
           "save_calibration"]


class CalibratedConfig(Protocol):
    """What the calibration needs of a trial config (``bench.config.models.TrialConfig``):
    written here so this module does not import the models, which import it."""

    robot: str
    source: Optional[Path]
    calibration: Optional[Path]
    backend: Any  # the backend section: ``kind``, ``servos`` and ``ultrasonic`` are read

    def resolve(self, path: Path) -> Path: ...


class ServoCalibration(Strict):
    """One joint's zero: ``offset`` replaces the config's; ``change`` is offset − config offset."""

    offset: float
    change: float = 0.0


class UltrasonicStop(Strict):
    """One stop of the train: arc angle from the servo, the d2 it gives, the mean reading."""

    epsilon_rad: float
    d2_mm: float
    distance_mm: float
    samples: int = Field(ge=1)


class UltrasonicCalibration(Strict):
    """measured distance = offset_mm + scale · d2 (mm), fitted over the stops."""

    offset_mm: float
    scale: float = Field(gt=0)
    residual_mm: float = Field(ge=0, description="RMS of the fit's residuals")
    max_residual_mm: float = Field(default=0.0, ge=0)
    stops: list[UltrasonicStop] = Field(default_factory=list)

    def d2(self, distance_m: float) -> float:
        """The train's d2 (m) for a sensor reading (m)."""
        return (distance_m * 1e3 - self.offset_mm) / self.scale * 1e-3


class CalibrationFile(Strict):
    config_name: str
    config_file: Optional[str] = None
    robot: str = "arc-train"
    created: str  # ISO 8601, local time with offset
    joint_offsets: Literal["config", "homing", "none"] = "config"
    servos: dict[str, ServoCalibration] = Field(default_factory=dict)
    homing_offsets: dict[str, float] = Field(default_factory=dict, description="shaft rad")
    ultrasonic: Optional[UltrasonicCalibration] = None

    def offset(self, joint: str, configured: float) -> float:
        """The joint's zero offset: calibrated if this file has one, else as configured."""
        s = self.servos.get(joint)
        return s.offset if s is not None else configured

    def d2(self, distance_m: float, standoff_m: float) -> float:
        """The train's d2 (m) for an ultrasonic reading, calibrated if this file has the sensor."""
        if self.ultrasonic is None:
            return distance_m - standoff_m
        return self.ultrasonic.d2(distance_m)


def load_calibration(path: Path | str) -> CalibrationFile:
    """Read and validate a calibration file; ConfigError with one line otherwise."""
    path = Path(path)
    data = read_yaml_mapping(path, "calibration file", ConfigError)
    try:
        return CalibrationFile.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, CalibrationFile, path)) from None


_HEADER = """\
# Calibration of {name} by `hilbench calibrate` ({created}).
# Use it in a trial config with:   calibration: {path}
# servos: joint zero offsets replacing each servo's `offset` (rad or m at tick 2048);
# homing_offsets: shaft-angle shifts written to the servos' Homing Offset registers (rad);
# ultrasonic: reading = offset_mm + scale * d2 (mm), fitted over the stops.
"""


def save_calibration(cal: CalibrationFile, path: Path) -> Path:
    """Write the file atomically (a crash never leaves half a calibration behind)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = yaml.safe_dump(cal.model_dump(mode="json"), sort_keys=False)
    text = _HEADER.format(name=cal.config_name, created=cal.created, path=path) + body
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def calibration_path(config: CalibratedConfig) -> Optional[Path]:
    return config.resolve(config.calibration) if config.calibration is not None else None


def calibration_of(config: CalibratedConfig) -> Optional[CalibrationFile]:
    """The calibration a config names, or None."""
    path = calibration_path(config)
    return load_calibration(path) if path is not None else None


def calibration_record(calibration: Optional[CalibrationFile], path: Optional[Path]) -> Optional[dict]:
    """Path and content of the calibration a trial applied, for its record (nothing is read)."""
    if calibration is None:
        return None
    return {"path": str(path), "content": calibration.model_dump(mode="json")}


def applied_calibration(config: CalibratedConfig) -> Optional[CalibrationFile]:
    """The calibration a trial of this config applies, read once: the content checked when the
    config was loaded (:func:`bench.config.models.load_trial_config` keeps it), else read and
    checked now. None for a config that names none, or for a simulator (nothing to apply)."""
    path = calibration_path(config)
    if path is None or config.backend.kind != "dynamixel":
        return None
    kept = getattr(config, "_calibration_read", None)
    if kept is not None and kept[0] == path:
        return kept[1]
    return check_calibration(config)


def check_calibration(config: CalibratedConfig) -> CalibrationFile:
    """Read the config's calibration and refuse one that cannot apply to it (ConfigError, one
    line); the calibration as read."""
    where = f"{config.source}: calibration" if config.source else "calibration"
    if config.backend.kind != "dynamixel":
        raise ConfigError(f"{where}: applies to the dynamixel backend, not {config.backend.kind}")
    try:
        cal = calibration_of(config)
    except ConfigError as e:
        raise ConfigError(f"{where}: {e}") from None
    assert cal is not None
    if cal.robot != config.robot:
        raise ConfigError(f"{where}: {config.calibration} is for robot {cal.robot}, not {config.robot}")
    unknown = sorted(set(cal.servos) - set(config.backend.servos))
    if unknown:
        raise ConfigError(f"{where}: {config.calibration} has offsets for unknown joint(s) {unknown}")
    rows = {r.name: r for r in get_robot(config.robot).chain.rows}
    for name, zero in cal.servos.items():  # a zero that puts the joint's range beyond its servo's
        sv = config.backend.servos[name]
        problem = transmission_refusal(name, sv.mode, sv.ratio, zero.offset, rows[name])
        if problem:
            raise ConfigError(f"{where}: {config.calibration}: {problem}")
    if cal.ultrasonic is not None and config.backend.ultrasonic is None:
        raise ConfigError(f"{where}: {config.calibration} calibrates an ultrasonic sensor the "
                          f"config does not have (backend.ultrasonic)")
    return cal
