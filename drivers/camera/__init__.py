"""Cameras: a second kind of sensor beside the servos' encoders and the ultrasonic sensor.

A :class:`Camera` grabs a :class:`Frame` (an 8-bit BGR image and the time it was taken) and
knows its :class:`Intrinsics` (pixels, focal lengths, principal point, OpenCV's distortion
coefficients). Two backends, as the actuators have:

- :mod:`drivers.camera.capture`: OpenCV's ``VideoCapture`` on a device index or a URL (an IP
  camera's stream), with the resolution and exposure set from the config;
- :mod:`drivers.camera.emulated`: PyBullet's software renderer (TinyRenderer, no display) of the
  robot and its room from the camera's pose, with the lens's distortion, blur and noise added.

Poses follow OpenCV: a point ``X`` in the world (m) is ``R @ X + t`` in the camera's frame
(x right, y down, z along the view). Nothing here knows of trials or of what is measured: the
metrology (detection, triangulation, calibration) is in ``bench.cameras``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from drivers.errors import CameraError

__all__ = ["Camera", "CameraError", "CameraPose", "Frame", "Intrinsics", "look_at"]


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera with OpenCV's distortion model (k1, k2, p1, p2[, k3]); pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        return np.asarray(self.distortion, dtype=float)


@dataclass(frozen=True)
class CameraPose:
    """World to camera: ``x_cam = rotation @ x_world + translation`` (m)."""

    rotation: np.ndarray
    translation: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        """The camera's centre in the world (m)."""
        return -self.rotation.T @ self.translation

    def projection(self, intrinsics: Intrinsics) -> np.ndarray:
        """The 3 × 4 projection matrix K [R | t]."""
        return intrinsics.matrix @ np.hstack([self.rotation, self.translation.reshape(3, 1)])


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> CameraPose:
    """The pose of a camera at ``position`` looking at ``target`` (m), the image's up towards ``up``."""
    c, g = np.asarray(position, dtype=float), np.asarray(target, dtype=float)
    z = g - c
    if np.linalg.norm(z) < 1e-9:
        raise CameraError("a camera cannot look at its own position")
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-6:  # looking along `up`: the image's up is the world's Y
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.vstack([x, y, z])
    return CameraPose(rot, -rot @ c)


@dataclass(frozen=True)
class Frame:
    """One image (H × W × 3, uint8, BGR as OpenCV keeps it) and when it was taken (s)."""

    camera: str
    image: np.ndarray = field(repr=False)
    time: float


@runtime_checkable
class Camera(Protocol):
    """What every camera backend offers: a name, its intrinsics, a frame on demand, a close."""

    name: str
    intrinsics: Intrinsics

    def grab(self) -> Frame: ...

    def close(self) -> None: ...
