"""The ``cameras:`` section of a trial config: the two views that measure the needle from outside
(seed 000, section 5: a front view and a top view), each a device or URL on the real rig and a
rendering of the scene on the sim and the emulated rig (bench.cameras, drivers/camera)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional, Union

from pydantic import Field, field_validator, model_validator

from bench.config.base import Strict

__all__ = ["CameraConfig", "CamerasConfig"]

_CAMERA_NAME = r"^[A-Za-z][A-Za-z0-9_-]{0,31}$"
Vec3 = tuple[float, float, float]


class CameraIntrinsicsConfig(Strict):
    """The lens: focal lengths and principal point (pixels) and OpenCV's distortion coefficients."""

    fx_px: float = Field(gt=0, le=1e5, description="focal length along x (pixels)")
    fy_px: float = Field(gt=0, le=1e5, description="focal length along y (pixels)")
    cx_px: float = Field(description="principal point, x (pixels, pixel centres at integers)")
    cy_px: float = Field(description="principal point, y (pixels)")
    distortion: list[float] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0],
        description="k1, k2, p1, p2[, k3[, k4, k5, k6]] (OpenCV's model)")

    @field_validator("distortion")
    @classmethod
    def _known_length(cls, v: list[float]) -> list[float]:
        if len(v) not in (4, 5, 8):
            raise ValueError(f"distortion takes 4, 5 or 8 coefficients (OpenCV's model), not {len(v)}")
        if any(abs(c) > 10 for c in v):
            raise ValueError("distortion coefficients beyond ±10 are not a lens")
        return v


class CameraPoseConfig(Strict):
    """Where the camera stands in the robot's (bed's) frame and what it looks at (mm)."""

    position_mm: Vec3 = Field(description="the camera's centre (mm, bed frame)")
    look_at_mm: Vec3 = Field(description="the point on the image's centre line (mm, bed frame)")

    @model_validator(mode="after")
    def _looks_somewhere(self) -> "CameraPoseConfig":
        gap = sum((a - b) ** 2 for a, b in zip(self.position_mm, self.look_at_mm)) ** 0.5
        if gap < 10.0:
            raise ValueError("look_at_mm must be at least 10 mm from position_mm")
        return self


class EmulatedLensConfig(Strict):
    """What the emulated camera adds to the rendered image."""

    noise: float = Field(default=2.0, ge=0, le=50, description="sensor noise (σ, grey levels of 255)")
    blur_px: float = Field(default=0.7, ge=0, le=10, description="Gaussian blur (σ, pixels)")


class CameraConfig(Strict):
    """One camera: the device it is on the rig, its image size and exposure, its lens and pose."""

    name: str = Field(pattern=_CAMERA_NAME, description="front, top, … (names the frames saved)")
    device: Union[int, str] = Field(
        default=0, description="the real camera: a device index (0 = /dev/video0) or a URL "
                               "(an IP camera's stream, e.g. http://…/video.mjpg)")
    resolution: tuple[int, int] = Field(default=(1280, 720), description="width, height (pixels)")
    exposure: Optional[float] = Field(
        default=None, description="the real camera's exposure, in its driver's units "
                                  "(CAP_PROP_EXPOSURE); none: the camera's own")
    intrinsics: CameraIntrinsicsConfig = Field(description="the lens (from a calibration)")
    pose: CameraPoseConfig = Field(description="where it stands and looks (bed frame, mm)")
    emulated: EmulatedLensConfig = Field(default=EmulatedLensConfig(),
                                         description="the emulated camera's noise and blur")

    @field_validator("device")
    @classmethod
    def _device(cls, v: Union[int, str]) -> Union[int, str]:
        if isinstance(v, int) and not 0 <= v <= 63:
            raise ValueError(f"device index {v} is not 0-63")
        if isinstance(v, str) and not v.strip():
            raise ValueError("device must be an index or a URL, not empty")
        return v

    @model_validator(mode="after")
    def _principal_point_inside(self) -> "CameraConfig":
        w, h = self.resolution
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ValueError(f"resolution {w}x{h} is not 16-8192 pixels a side")
        i = self.intrinsics
        if not (0 <= i.cx_px < w and 0 <= i.cy_px < h):
            raise ValueError(f"intrinsics: the principal point ({i.cx_px:g}, {i.cy_px:g}) is outside "
                             f"the {w}x{h} image")
        return self


class CamerasConfig(Strict):
    """Two cameras that measure the needle's tip from the fiducial on its holder."""

    views: list[CameraConfig] = Field(min_length=2, max_length=2,
                                      description="the two views (seed 000: front and top)")
    source: Literal["auto", "emulated", "capture"] = Field(
        default="auto", description="auto: rendered on the sim and the emulated rig, captured on the "
                                    "real rig; emulated or capture to choose")
    pixel_sigma: float = Field(default=0.3, gt=0, le=20,
                               description="the calibration's pixel error (rms, pixels), carried "
                                           "into the tip's uncertainty")
    calibration: Optional[Path] = Field(
        default=None, description="a file from `hilbench cameras calibrate`: the intrinsics and poses "
                                  "measured with (relative: beside the config, else the shipped data's); "
                                  "none: those above")

    @field_validator("views")
    @classmethod
    def _distinct(cls, v: list[CameraConfig]) -> list[CameraConfig]:
        names = [c.name for c in v]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must differ: {names}")
        return v
