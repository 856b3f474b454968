"""``result.json`` as the readers of a run directory check it (``runs``, ``report``): its schema.

The trial writes the file (:func:`bench.core.result.write_result_json`); these models say what a
reader relies on in it, and keep every other field as it is.
"""

from __future__ import annotations

from typing import Optional

from pydantic import BaseModel, ConfigDict, Field, StrictBool

__all__ = ["CameraRow", "RequirementRow", "ResultFile"]


class RequirementRow(BaseModel):
    """One requirement's robustness as ``result.json`` holds it (mm or degrees, None: no value)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    name: str
    formula: str
    robustness: Optional[float] = None
    holds: StrictBool


class CameraRow(BaseModel):
    """The cameras' figures as ``result.json`` holds them (mm; None: not measured)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    encoder_gap_mm: Optional[float] = None
    flag: Optional[StrictBool] = None
    problem: str = Field("", max_length=2000)


class ResultFile(BaseModel):
    """``result.json`` as ``runs`` reads it: the verdict, the two deviations, the requirements and
    the cameras' gap."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    requirements: list[RequirementRow] = Field(default_factory=list, max_length=64)
    camera: Optional[CameraRow] = None

    passed: StrictBool
    completed: StrictBool
    reason: str
    tip_deviation_mm: Optional[list[float]] = Field(None, min_length=3, max_length=3)
    angle_deviation_deg: Optional[float] = None
    depth_deviation_mm: Optional[float] = None
