"""Section 3's singularities: type 1 (det B = 0) and type 2 (det A = 0), classified and constructed."""

from __future__ import annotations

import enum
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.batch import wrap_angle
from bench.kinematics.para_brachy.geometric import dgm, igm
from bench.kinematics.para_brachy.jacobians import _broadcast, constraint
from bench.kinematics.para_brachy.model import (
    DEFAULT_PARAMS,
    DEG,
    WORKSPACE_CENTRE,
    ParaBrachyParams,
    _as_last5,
    insertion_direction,
    needle_points,
)

# ---------------------------------------------------------------------------
# Singularities (section 3)
# ---------------------------------------------------------------------------


class SingularityCase(str, enum.Enum):
    """The paper's singular configurations, numbered as in its section 3.

    Type 1 (det B = 0, eq 8; the robot loses a DOF):
      case 1 — √(d² − (q2 − q1)²) = 0: link d parallel to OZ, CYL-U blocked
               (det B not computable: the q1, q2 columns of B are infinite);
      case 2 — q2 − q1 = 0: link d perpendicular to OZ, q2 has no first-order
               effect on r_A;
      case 3 — √(d² − (q2 − q1)²) + b = 0, i.e. r_A = 0: A1 on the q3 axis,
               q3 moves nothing (possible only if b ≤ 0);
      case 4 — q5 − Y_E + h sin ψ sin θ = 0, i.e. Y_A2 = q5: link c
               perpendicular to OY, the q5 slide has no first-order effect.
    Type 2 (det A = 0; the robot gains a DOF):
      case 5 — sin θ = 0: lc parallel to OZ (Z_C1 − Z_C2 = lc), the radius
               √(lc² − (Z_C1 − Z_C2)²) of eq 2 vanishes and the needle can tilt
               along the circle of link c;
      case 6 — P sin ψ − Q cos ψ = 0: link c collinear with GE' (ψ = ψ2, the
               separation between the two assembly modes of the DGM);
      case 6 particular — ψ = π/2 with X_E = e (α = 0), removed at the design
               stage by r_A < dx − e.
    Type 3 (architecture, both A and B singular).
    """

    TYPE1_CASE1 = "type1.case1"
    TYPE1_CASE2 = "type1.case2"
    TYPE1_CASE3 = "type1.case3"
    TYPE1_CASE4 = "type1.case4"
    TYPE2_CASE5 = "type2.case5"
    TYPE2_CASE6 = "type2.case6"
    TYPE2_CASE6_PSI_HALF_PI = "type2.case6.psi_half_pi"
    TYPE3_ARCHITECTURE = "type3.architecture"

    @property
    def description(self) -> str:
        return _CASE_TEXT[self]


_CASE_TEXT = {
    SingularityCase.TYPE1_CASE1: "det B: sqrt(d^2-(q2-q1)^2) = 0, link d parallel to OZ (CYL-U blocked)",
    SingularityCase.TYPE1_CASE2: "det B: q2 - q1 = 0, link d perpendicular to OZ",
    SingularityCase.TYPE1_CASE3: "det B: sqrt(d^2-(q2-q1)^2) + b = 0, A1 on the q3 axis (r_A = 0)",
    SingularityCase.TYPE1_CASE4: "det B: q5 - Y_E + h sin(psi) sin(theta) = 0, link c perpendicular to OY",
    SingularityCase.TYPE2_CASE5: "det A: sin(theta) = 0, lc parallel to OZ",
    SingularityCase.TYPE2_CASE6: "det A: link c collinear with GE' (psi = psi2), assembly modes merge",
    SingularityCase.TYPE2_CASE6_PSI_HALF_PI: (
        "det A: psi = pi/2, X_E = e, alpha = 0 (removed by the design restriction r_A < dx - e)"
    ),
    SingularityCase.TYPE3_ARCHITECTURE: "det A = det B = 0 together",
}

_TYPE1 = (
    SingularityCase.TYPE1_CASE1,
    SingularityCase.TYPE1_CASE2,
    SingularityCase.TYPE1_CASE3,
    SingularityCase.TYPE1_CASE4,
)
_TYPE2 = (SingularityCase.TYPE2_CASE5, SingularityCase.TYPE2_CASE6)


def singularity_factors(
    q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS
) -> dict[SingularityCase, np.ndarray]:
    """Dimensionless distance of each factor of det A / det B from zero (…).

    case 1: √(d² − (q2−q1)²)/d; case 2: |q2 − q1|/d; case 3: |r_A|/d;
    case 4: |Y_C2 − q5|/c; case 5: |sin θ|; case 6: |P sin ψ − Q cos ψ|/c
    (the sine of the angle between link c and the needle projection);
    case 6 particular: max(case 6, |cos ψ|, |X_E − e|/c).
    """
    qa, xa = _broadcast(q, pose)
    p = params
    _, c2 = needle_points(xa, p)
    dq = qa[..., 1] - qa[..., 0]
    s = np.sqrt(np.clip(p.d**2 - dq**2, 0.0, None))
    P = c2[..., 0] - p.e
    Q = c2[..., 1] - qa[..., 4]
    psi, th = xa[..., 3], xa[..., 4]
    case6 = np.abs(P * np.sin(psi) - Q * np.cos(psi)) / p.c
    return {
        SingularityCase.TYPE1_CASE1: s / p.d,
        SingularityCase.TYPE1_CASE2: np.abs(dq) / p.d,
        SingularityCase.TYPE1_CASE3: np.abs(s + p.b) / p.d,
        SingularityCase.TYPE1_CASE4: np.abs(Q) / p.c,
        SingularityCase.TYPE2_CASE5: np.abs(np.sin(th)),
        SingularityCase.TYPE2_CASE6: case6,
        SingularityCase.TYPE2_CASE6_PSI_HALF_PI: np.maximum.reduce(
            [case6, np.abs(np.cos(psi)), np.abs(xa[..., 0] - p.e) / p.c]
        ),
    }


def classify_singularity(
    q: ArrayLike | None = None,
    pose: ArrayLike | None = None,
    tol: float = 1e-6,
    *,
    params: ParaBrachyParams = DEFAULT_PARAMS,
    working_mode: Sequence[int] = (1, 1),
) -> list[SingularityCase]:
    """Name the singular cases one configuration is in (empty list: regular).

    Give ``pose`` (q follows from the IGM in ``working_mode``, strokes not
    checked), ``q`` (every DGM assembly mode is examined and the union
    returned), or both (they must satisfy eq 7). A factor counts as zero when
    its normalised value (:func:`singularity_factors`) is below ``tol``.
    Near a locus some factors come out of a square root (the IGM's
    √(d² − …) at case 2, the DGM's circle intersection at case 6), so
    rounding leaves them at about 1e-8: keep ``tol`` above 1e-7.
    """
    if not (tol > 0.0):
        raise ValueError(f"tol must be positive, got {tol!r}")
    if q is None and pose is None:
        raise ValueError("classify_singularity needs q, pose or both")
    if pose is not None:
        xs = _as_last5(pose, "pose")
        if xs.ndim != 1:
            raise ValueError(f"classify_singularity takes one pose, got shape {xs.shape}")
        if q is None:
            qs = igm(xs, params, working_mode, check_limits=False)
        else:
            qs = _as_last5(q, "q")
            res = constraint(qs, xs, params)
            scale = np.array([1.0, 1.0, 1.0, 1.0, 1.0 / (2.0 * params.c)])
            if np.max(np.abs(res * scale)) > 1e-6:
                raise ValueError(f"q and pose do not satisfy eq (7): F = {np.array2string(res, precision=3)}")
        pairs = [(qs, xs)]
    else:
        qs = _as_last5(q, "q")
        if qs.ndim != 1:
            raise ValueError(f"classify_singularity takes one q, got shape {qs.shape}")
        sols = dgm(qs, params)
        pairs = [(qs, s) for s in sols]
    found: set[SingularityCase] = set()
    for qq, xx in pairs:
        f = singularity_factors(qq, xx, params)
        found.update(case for case, value in f.items() if float(value) < tol)
    if found & set(_TYPE1) and found & (set(_TYPE2) | {SingularityCase.TYPE2_CASE6_PSI_HALF_PI}):
        found.add(SingularityCase.TYPE3_ARCHITECTURE)
    order = list(SingularityCase)
    return sorted(found, key=order.index)


def architecture_violations(params: ParaBrachyParams = DEFAULT_PARAMS) -> list[str]:
    """Design-stage conditions that let a singular case into the joint space (empty: none).

    The paper removes the particular case of type-2 case 6 by requiring
    r_A < dx − e for every r_A the CYL-U can make (r_A ≤ b + d); type-1
    case 3 needs r_A = b + √(…) = 0, impossible when b > 0.
    """
    p = params
    out = []
    if p.b + p.d >= abs(p.dx - p.e):
        out.append(
            f"r_A can reach b + d = {p.b + p.d:.6g} m >= |dx - e| = {abs(p.dx - p.e):.6g} m: "
            "the paper's restriction r_A < dx - e fails, type2.case6.psi_half_pi is possible"
        )
    if p.b <= 0.0:
        out.append(f"b = {p.b:.6g} m <= 0: r_A = b + sqrt(d^2-(q2-q1)^2) can vanish, type1.case3 is possible")
    return out


_LEAN_MINUS_X = np.array([WORKSPACE_CENTRE[0], WORKSPACE_CENTRE[1], 0.0, 170.0 * DEG, 40.0 * DEG])
_CASE_BASE = {SingularityCase.TYPE1_CASE1: _LEAN_MINUS_X, SingularityCase.TYPE1_CASE3: _LEAN_MINUS_X}


def _pose_from_c1c2(c1: np.ndarray, psi: float, theta: float, p: ParaBrachyParams) -> np.ndarray:
    w = insertion_direction(psi, theta)
    tip = c1 + (p.h + p.lc) * w
    return np.array([tip[0], tip[1], tip[2], psi, theta])


def singular_configuration(
    case: SingularityCase | str,
    offset: float = 0.0,
    params: ParaBrachyParams = DEFAULT_PARAMS,
    base_pose: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A (q, pose) on the given singular case, or ``offset`` away from it along one path.

    Built from ``base_pose`` (default: the workspace centre; for type-1
    cases 1 and 3 the needle leans towards −X, ψ = 170°, θ = 40°, because
    with A1 that close to the column C2 would otherwise lie beyond the reach
    c of the q5 module) by moving one feature only, so the other factors
    stay put while the named one goes to zero. ``offset`` is the value of that feature:

    * type1.case1: √(d² − (q2 − q1)²) = offset (m): C1 slides radially to
      r_A = b + offset;
    * type1.case2: q2 − q1 = offset (m): r_A = b + √(d² − offset²);
    * type1.case3: r_A = offset (m) (needs b ≤ 0);
    * type1.case4: Y_C2 − q5 = offset (m): C2 slides along X to X_C2 − e = √(c² − offset²);
    * type2.case5: θ = offset (rad), tip and ψ kept;
    * type2.case6: ψ = (direction of link c) + offset (rad), C2 and q5 kept;
    * type2.case6.psi_half_pi: ψ = π/2 and X_E = e, link c along +OY; only
      possible when the design restriction r_A < dx − e is violated.

    Raises ValueError if the case cannot occur for these parameters.
    """
    case = SingularityCase(case)
    p = params
    if base_pose is None:
        base_pose = _CASE_BASE.get(case, WORKSPACE_CENTRE)
    base = _as_last5(base_pose, "base_pose")
    psi0, th0 = float(base[3]), float(base[4])
    c1, c2 = needle_points(base, p)
    axis = np.array([p.dx, p.l3])

    def at_radius(r: float) -> np.ndarray:
        u = c1[:2] - axis
        u = u / np.linalg.norm(u)
        new_c1 = np.array([*(axis + r * u), c1[2]])
        return _pose_from_c1c2(new_c1, psi0, th0, p)

    if case is SingularityCase.TYPE1_CASE1:
        pose = at_radius(p.b + offset)
        mode = (1, 1)
    elif case is SingularityCase.TYPE1_CASE2:
        if abs(offset) > p.d:
            raise ValueError(f"type1.case2 offset |q2 - q1| = {abs(offset)!r} m exceeds d = {p.d!r} m")
        pose = at_radius(p.b + np.sqrt(p.d**2 - offset**2))
        mode = (1 if offset >= 0.0 else -1, 1)
    elif case is SingularityCase.TYPE1_CASE3:
        if p.b > 0.0:
            raise ValueError(
                f"type1.case3 (r_A = 0) needs b <= 0, these parameters have b = {p.b!r} m: "
                "A1 can never reach the q3 axis"
            )
        pose = at_radius(abs(offset))
        mode = (1, 1)
    elif case is SingularityCase.TYPE1_CASE4:
        if abs(offset) > p.c:
            raise ValueError(f"type1.case4 offset {offset!r} m exceeds c = {p.c!r} m")
        sign = 1.0 if c2[0] - p.e >= 0.0 else -1.0
        shift = p.e + sign * np.sqrt(p.c**2 - offset**2) - c2[0]
        pose = base.copy()
        pose[0] += shift
        mode = (1, 1 if offset >= 0.0 else -1)
    elif case is SingularityCase.TYPE2_CASE5:
        pose = base.copy()
        pose[4] = offset
        mode = (1, 1)
    elif case is SingularityCase.TYPE2_CASE6:
        q0 = igm(base, p, check_limits=False)
        P, Q = c2[0] - p.e, c2[1] - q0[4]
        phi = np.arctan2(Q, P)
        # the needle projection direction closest to the base azimuth that is parallel to c
        phi = phi if abs(wrap_angle(phi - psi0)) <= np.pi / 2 else phi + np.pi
        psi = float(wrap_angle(phi + offset))
        w = np.array([np.sin(th0) * np.cos(psi), np.sin(th0) * np.sin(psi), -np.cos(th0)])
        tip = c2 + p.h * w
        pose = np.array([*tip, psi, th0])
        q = q0.copy()
        q[:4] = igm(pose, p, check_limits=False)[:4]
        return q, pose
    elif case is SingularityCase.TYPE2_CASE6_PSI_HALF_PI:
        if p.b + p.d < abs(p.dx - p.e):
            raise ValueError(
                "type2.case6.psi_half_pi needs r_A >= dx - e, which the design restriction "
                f"b + d = {p.b + p.d!r} m < dx - e = {p.dx - p.e!r} m excludes"
            )
        psi = np.pi / 2 + offset
        pose = np.array([p.e, base[1], base[2], psi, th0])
        mode = (1, 1)
    else:
        raise ValueError(f"no single configuration for {case.value!r}; combine a type-1 and a type-2 case")
    return igm(pose, p, mode, check_limits=False), pose
