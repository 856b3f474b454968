"""The parallel robot's parameters, joint and pose names, and the needle's two universal joints (eq 4)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

DEG = np.pi / 180.0

JOINT_NAMES = ("q1", "q2", "q3", "q4", "q5")
POSE_NAMES = ("X_E", "Y_E", "Z_E", "psi", "theta")
_ANGULAR_JOINT = 2  # q3 is the only revolute actuator


# ---------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ParaBrachyParams:
    """Geometric parameters (m) and joint strokes of the robot.

    The paper lists d, b, c, l1, l2, l3, lc, h, dx, e but prints no values.
    The defaults size the robot for a needle tip target in a patient on a CT
    bed. The tip workspace is ``WORKSPACE_CENTRE`` ± 6 cm in X and Y (12 cm
    wide), ± 3 cm in Z (6 cm of travel), ψ within ± 30° of −60° and θ from
    10° to 40°; over it (the default :class:`WorkspaceGrid`) every pose is
    reachable inside the strokes and every factor of det A and det B stays
    away from zero:

    * h = 0.15 m tip to C2 (the needle below the lower joint: depth in the
      patient plus clearance above the skin), lc = 0.10 m between the two
      joints on the needle holder;
    * the CYL-U column stands at X = dx = 0.52 m, on the +X side of the
      needle, the q5 guide at X = e = 0 on the other side. The paper's
      design restriction r_A < dx − e holds for every r_A the CYL-U can make
      (b + d = 0.50 m < 0.52 m), which removes the particular case of type-2
      case 6 (ψ = π/2, X_E = e) from the whole joint space;
    * b = 0.10 m, d = 0.40 m: over the workspace r_A runs from 0.21 to
      0.48 m and link d stays 20°–74° from the horizontal, away from type-1
      cases 1 and 2 (d parallel / perpendicular to OZ); b > 0 rules out
      type-1 case 3 (r_A = 0);
    * c = 0.38 m: link c stays 16°–55° from OY (type-1 case 4 is c ⟂ OY)
      and at least 30° from the needle's horizontal projection (type-2
      case 6); θ ≥ 10° keeps type-2 case 5 (θ = 0) out;
    * l1 = l2 = 0.05 m vertical joint offsets; l3 = 0 (column on Y = 0) and
      e = 0, so eqs 1–3 hold exactly as printed;
    * strokes cover the joint ranges the workspace needs (q1 0.21–0.33 m,
      q2 0.35–0.71 m, q3 143°–202°, q4 0.03–0.13 m, q5 −0.45 to −0.12 m)
      with margin.
    """

    d: float = 0.40
    b: float = 0.10
    c: float = 0.38
    l1: float = 0.05
    l2: float = 0.05
    l3: float = 0.0
    lc: float = 0.10
    h: float = 0.15
    dx: float = 0.52
    e: float = 0.0
    q_min: tuple[float, float, float, float, float] = (0.15, 0.20, 120.0 * DEG, -0.05, -0.60)
    q_max: tuple[float, float, float, float, float] = (0.40, 0.80, 220.0 * DEG, 0.20, 0.00)

    def __post_init__(self) -> None:
        for name in ("d", "c", "lc", "h"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"ParaBrachyParams.{name} must be a positive length in m, got {value!r}")
        for name in ("b", "l1", "l2", "l3", "dx", "e"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise ValueError(f"ParaBrachyParams.{name} must be finite, got {value!r}")
        if len(self.q_min) != 5 or len(self.q_max) != 5:
            raise ValueError(
                f"q_min and q_max need 5 values each, got {len(self.q_min)} and {len(self.q_max)}"
            )
        for j, (lo, hi) in enumerate(zip(self.q_min, self.q_max)):
            if not lo < hi:
                raise ValueError(f"stroke of {JOINT_NAMES[j]} is empty: q_min = {lo!r} >= q_max = {hi!r}")

    @property
    def length_scale(self) -> float:
        """h + lc: turns angles into tip-sized lengths so A and B have one unit."""
        return self.h + self.lc

    def as_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


DEFAULT_PARAMS = ParaBrachyParams()

#: Centre of the default needle workspace: tip position (m) and ψ, θ (rad).
WORKSPACE_CENTRE = np.array([0.25, -0.06, 0.0, -60.0 * DEG, 25.0 * DEG])


# ---------------------------------------------------------------------------
# Small helpers
# ---------------------------------------------------------------------------


def _as_last5(values: ArrayLike, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 5:
        raise ValueError(f"{what} must have 5 components in its last axis, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{what}{list(idx)} is not finite: {float(arr[idx])}")
    return arr


def _mode_signs(mode: Sequence[int]) -> tuple[float, float]:
    if len(mode) != 2 or any(m not in (-1, 1) for m in mode):
        raise ValueError(f"working_mode must be two signs (±1, ±1), got {tuple(mode)!r}")
    return float(mode[0]), float(mode[1])


def insertion_direction(psi: ArrayLike, theta: ArrayLike) -> np.ndarray:
    """The unit insertion direction w = (sin θ cos ψ, sin θ sin ψ, −cos θ), shape (…, 3)."""
    psi, th = np.asarray(psi, dtype=float), np.asarray(theta, dtype=float)
    return np.stack([np.sin(th) * np.cos(psi), np.sin(th) * np.sin(psi), -np.cos(th)], axis=-1)


def needle_points(pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> tuple[np.ndarray, np.ndarray]:
    """C1 and C2 (…, 3) of eq 4: the two universal joints on the needle."""
    x = np.asarray(pose, dtype=float)
    w = insertion_direction(x[..., 3], x[..., 4])
    tip = x[..., :3]
    c1 = tip - (params.h + params.lc) * w
    c2 = tip - params.h * w
    return c1, c2
