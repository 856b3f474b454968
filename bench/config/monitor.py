"""The ``monitor:`` section of a trial config: the twin that runs beside the trial (bench.monitor)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, ValidationInfo, field_validator

from bench.config.base import Strict, beside_of, from_record
from bench.config.servo_model import load_servo_model_file
from bench.paths import resolve_named

__all__ = ["MonitorConfig"]


class MonitorConfig(Strict):
    """The servo model stepped beside the trial, and what an alarm does."""

    model: str = Field(default="datasheet", max_length=4096,
                       description="datasheet: the servo table's models and gains; or a servo model file "
                                   "from `hilbench identify` (relative: beside the config, else the "
                                   "shipped data's)")
    action: Literal["warn", "stop"] = Field(
        default="warn", description="warn: record each alarm and go on; stop: the safe stop at the first")

    @field_validator("model")
    @classmethod
    def _known_model(cls, v: str, info: ValidationInfo) -> str:
        if v == "datasheet" or from_record(info):
            return v  # a record's config names the file its trial read; it is not read again
        path = resolve_named(v, beside_of(info))
        if not path.is_file():
            raise ValueError(f"monitor.model {v!r} is neither datasheet nor a servo model file (not found: {path})")
        load_servo_model_file(path)  # refused here, with the file's own line, if it is wrong
        return v
