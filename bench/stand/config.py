"""A test-stand config: the stand (mass, arm), its servo's port, the excitation (BAM's
trajectories at P gains) and the emulated stand's hidden physics for a rehearsal."""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

from pydantic import Field, ValidationError

from bench.config.base import ConfigError, Strict, describe_validation_error, read_yaml_mapping
from bench.config.servo_model import ServoPhysics

__all__ = ["StandConfig", "load_stand_config"]


class StandRun(Strict):
    """One run of the excitation: a trajectory at a Position P Gain."""

    trajectory: Literal["sin_sin", "lift_and_drop", "up_and_down", "sin_time_square"] = Field(
        description="one of BAM's four 6 s trajectories")
    kp: int = Field(ge=1, le=16383, description="the Position P Gain register for the run")


class StandEmulator(Strict):
    """The emulated stand (``--emulate``): the servo's hidden physics and its supply."""

    physics: ServoPhysics = Field(default_factory=ServoPhysics,
                                  description="hidden servo physics (model-file keys)")
    supply_v: float = Field(default=7.0, gt=3.5, le=7.0, description="the emulated supply at no load (V)")
    source_ohm: float = Field(default=0.0, ge=0.0, le=2.0,
                              description="its source resistance (Ω): the supply sags by this times the motor current")


class StandConfig(Strict):
    """A test stand and the runs that excite it."""

    name: str = Field(default="stand", pattern=r"^[A-Za-z0-9_.-]{1,64}$",
                      description="the run directory's stem")
    motor: Literal["xl330"] = Field(default="xl330", description="the servo (BAM's name)")
    mass_kg: float = Field(gt=0, le=10, description="the mass on the arm (kg)")
    length_m: float = Field(gt=0, le=1, description="the mass's distance from the shaft (m)")
    port: str = Field(default="/dev/ttyUSB0", max_length=4096, description="the servo's serial port")
    baud: Literal[1_000_000] = Field(default=1_000_000, description="bus speed (bps), as BAM's recordings")
    servo_id: int = Field(default=1, ge=0, le=252, description="the servo's ID")
    vin: float = Field(default=7.4, gt=0, le=30, description="the nominal supply written in each log (V)")
    period_s: float = Field(default=0.005, ge=0.002, le=0.05, description="the recording period (s)")
    runs: list[StandRun] = Field(min_length=1, max_length=64, description="the excitation, run after run")
    emulator: StandEmulator = Field(default_factory=StandEmulator,
                                    description="the emulated stand (--emulate)")


def load_stand_config(path: Path | str) -> StandConfig:
    """A stand config, or ConfigError with one line saying what is wrong in it."""
    path = Path(path)
    data = read_yaml_mapping(path, "test-stand config", ConfigError)
    try:
        return StandConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, StandConfig, path)) from None
