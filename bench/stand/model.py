"""The servo model a test-stand rollout runs: the datasheet, a bench servo model file or one of
BAM's parameter files, as one servo's parameters and how the stand drives them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.config.base import ConfigError
from bench.config.servo_model import STAND_JOINT, STAND_ROBOT, apply_physics, load_servo_model_file
from bench.stand.bam import bam_params, is_bam_file
from bench.stand.errors import StandError
from bench.stand.logs import MOTORS
from bench.stand.simulate import Slots
from drivers.dynamixel.control_table import supported_models
from drivers.servo import ServoParams

__all__ = ["StandModel", "load_stand_model", "slots_for"]


@dataclass(frozen=True)
class StandModel:
    """One servo's parameters (one slot), the stand's gravity offset (rad) and whether the log's
    measured supply drives the motor (BAM's models take the nominal ``vin``)."""

    name: str
    params: ServoParams
    gravity_offset: float = 0.0
    measured_supply: bool = True


def load_stand_model(spec: str | Path, model_number: int = MOTORS["xl330"]) -> StandModel:
    """``datasheet``, one of BAM's parameter files (JSON) or a bench servo model file (YAML) for
    the stand's servo; StandError in one line when it is none of them or does not load."""
    if str(spec) == "datasheet":
        return StandModel("datasheet", ServoParams.datasheet([model_number]))
    path = Path(spec)
    if not path.is_file():
        raise StandError(f"{path}: no such model file (give a servo model file, a BAM parameter file "
                         "or datasheet)")
    if is_bam_file(path):
        params, offset, law = bam_params(path)
        return StandModel(f"BAM {law} ({path.name})", params, offset, measured_supply=False)
    try:
        model = load_servo_model_file(path)
    except ConfigError as e:
        raise StandError(str(e)) from None
    if model.robot != STAND_ROBOT and not {STAND_JOINT, "all"} & set(model.joints):
        raise StandError(f"{path}: joints: {model.robot}'s model has no entry the stand can take "
                         f"({STAND_JOINT} or all)")
    if model.servo is not None:  # the file's own servo over the logs' motor
        by_name = {name: number for number, name in supported_models().items()}
        if model.servo not in by_name:
            raise StandError(f"{path}: servo: unknown servo model {model.servo!r}; "
                             f"known: {', '.join(sorted(by_name))}")
        model_number = by_name[model.servo]
    params = apply_physics(ServoParams.datasheet([model_number]), [model.physics_of(STAND_JOINT)])
    offset = model.stand.gravity_offset_rad if model.stand is not None else 0.0
    return StandModel(path.name, params, offset, measured_supply=model.supply == "measured")


def slots_for(model: StandModel, logs: int) -> Slots:
    """One slot per log, all under ``model``."""
    p = model.params
    repeated = {f: np.repeat(getattr(p, f), logs) for f in ServoParams.__dataclass_fields__}
    return Slots(log=np.arange(logs), params=ServoParams(**repeated),
                 gravity_offset=np.full(logs, model.gravity_offset),
                 measured_supply=np.full(logs, model.measured_supply))
