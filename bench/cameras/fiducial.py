"""The fiducial on the needle holder: six coloured balls fixed to the needle's carriage (the
``d10`` link, which carries the needle), at known offsets from the needle's axis.

The holder's frame is the ``d10`` link's: the needle runs along its +Z from the origin to the tip
(the needle's length, 100 mm). Seen in both views, the balls give that frame's pose, and the tip
and the needle's direction follow from it. The balls stand 40 mm off the axis in four directions and
at three heights, so that the three a pose needs are seen whole from most places.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.kinematics.arc_train import ArcTrainParams
from drivers.camera.emulated import Fiducial

__all__ = ["BALLS", "HOLDER_LINK", "Ball", "emulated_fiducials", "tip_in_holder"]

HOLDER_LINK = "d10_link"


@dataclass(frozen=True)
class Ball:
    """One ball: its name, centre in the holder's frame (m), radius (m), colour and hue (°, HSV)."""

    name: str
    offset: tuple[float, float, float]
    radius: float
    rgb: tuple[float, float, float]
    hue_deg: float


BALLS = (
    Ball("magenta", (0.040, 0.0, -0.020), 0.004, (1.0, 0.0, 1.0), 300.0),
    Ball("yellow", (0.040, 0.0, 0.020), 0.004, (1.0, 1.0, 0.0), 60.0),
    Ball("cyan", (-0.040, 0.0, -0.020), 0.004, (0.0, 1.0, 1.0), 180.0),
    Ball("orange", (-0.040, 0.0, 0.020), 0.004, (1.0, 0.5, 0.0), 30.0),
    Ball("violet", (0.0, 0.040, 0.0), 0.004, (0.6, 0.0, 1.0), 276.0),
    Ball("lime", (0.0, -0.040, 0.0), 0.004, (0.5, 1.0, 0.0), 90.0),
)


def tip_in_holder(params: ArcTrainParams = ArcTrainParams()) -> tuple[np.ndarray, np.ndarray]:
    """The tip (m) and the needle's direction in the holder's frame."""
    return np.array([0.0, 0.0, params.needle_length]), np.array([0.0, 0.0, 1.0])


def emulated_fiducials(balls=BALLS) -> list[Fiducial]:
    """The balls as the emulated cameras' scene draws them."""
    return [Fiducial(b.name, HOLDER_LINK, b.offset, b.radius, (*b.rgb, 1.0)) for b in balls]
