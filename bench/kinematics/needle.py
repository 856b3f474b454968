"""What every needle robot is asked for and reports, in one vocabulary.

Angles follow the bed frame of the README: the *insertion angle* is measured in
the axial plane (X = const) from the downward vertical (−Z) towards +Y; the
*tilt* leans the needle out of that plane towards +X. A needle at angle a and
tilt b points along ``(sin b, cos b·sin a, −cos b·cos a)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Protocol, runtime_checkable

import numpy as np

from bench.kinematics.dh import JointRows
from drivers.errors import UnreachableError


def needle_direction(angle: float, tilt: float = 0.0) -> np.ndarray:
    return np.array([np.sin(tilt), np.cos(tilt) * np.sin(angle), -np.cos(tilt) * np.cos(angle)])


def angles_of(direction: np.ndarray) -> tuple[float, float]:
    """(insertion angle, tilt) of a unit needle direction."""
    d = np.asarray(direction, dtype=float)
    return float(np.arctan2(d[1], -d[2])), float(np.arcsin(np.clip(d[0], -1.0, 1.0)))


@dataclass(frozen=True)
class NeedlePose:
    """Entry point and tip (m, bed frame), insertion angle and tilt (rad), depth (m)."""

    entry: np.ndarray
    tip: np.ndarray
    direction: np.ndarray
    angle: float
    depth: float
    out_of_plane: float  # the tilt; zero for the arc-and-train robot whenever eqs 7-9 hold


@dataclass(frozen=True)
class NeedleTarget:
    """What the radiologist asks for: entry point (m), depth (m), angle and tilt (rad)."""

    entry: np.ndarray
    depth: float
    angle: float
    tilt: float = 0.0

    @property
    def direction(self) -> np.ndarray:
        return needle_direction(self.angle, self.tilt)

    @property
    def tip(self) -> np.ndarray:
        return np.asarray(self.entry, dtype=float) + self.depth * self.direction


def pose_from_axis(entry: np.ndarray, axis: np.ndarray, depth: float) -> NeedlePose:
    angle, tilt = angles_of(axis)
    return NeedlePose(entry=entry, tip=entry + depth * axis, direction=axis, angle=angle,
                      depth=depth, out_of_plane=tilt)


@runtime_checkable
class NeedleRobot(Protocol):
    """What the bench asks of every robot it knows: joints, forward kinematics to the needle, IK.

    ``chain.rows`` gives each joint's (name, kind, lower, upper, home) in SI units.
    """

    name: str
    chain: JointRows

    @property
    def joint_names(self) -> list[str]: ...

    def joint_vector(self, values: Mapping[str, float]) -> np.ndarray: ...

    def needle(self, q: np.ndarray) -> NeedlePose: ...

    def ik(self, target: NeedleTarget) -> np.ndarray: ...
