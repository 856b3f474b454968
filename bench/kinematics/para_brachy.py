"""Kinematics of the 5-DOF parallel needle-placement robot of seed 003.

Gherman, Pisla, Vaida, Plitea, "On workspace and accuracy evaluation of a
parallel robot for needle placement procedures" (Proc. Romanian Academy A,
2015): a CYL-U module (two sliders q1, q2 on a column parallel to OZ and a
rotation q3 about it) and a second module (q4 along OZ carrying q5 along OY)
hold the needle at two universal joints C1 and C2.

Frame and pose
--------------
Robot base frame, OZ up (away from the patient on the CT bed). A pose is the
5-vector ``[X_E, Y_E, Z_E, psi, theta]`` (m, m, m, rad, rad): E is the needle
tip, theta the angle between the needle and OZ, psi the azimuth of its
horizontal projection. The insertion direction (from C1 towards the tip) is
``w = (sin θ cos ψ, sin θ sin ψ, −cos θ)``, so θ = 0 is a needle pointing
straight down. Joints ``q = [q1, q2, q3, q4, q5]`` (m, m, rad, m, m).

The mechanism, as eqs 1–5 describe it
--------------------------------------
* C1 = E − (h + lc)·w and C2 = E − h·w lie on the needle (eq 4), lc apart.
* CYL-U: the column (q3 axis) is the vertical line X = dx, Y = l3. A1 sits at
  height q1 (eq 3) and radius r_A = b + √(d² − (q2 − q1)²) from the column,
  at polar angle π − q3 seen from the column (eq 3); C1 hangs l1 below A1
  (eq 1: q1 = Z_C1 + l1).
* Second module: G = (e, q5, q4) slides along OY at X = e; the link c joins G
  to A2 in the horizontal plane (eq 2) and C2 stands l2 above A2
  (eq 1: q4 = Z_C2 − l2).

Repairs to the paper (it is inconsistent in places)
----------------------------------------------------
1. Eq 7's f2 and f3 carry ``+(h + lc) sin θ cos ψ`` and
   ``(b − √(d² − (q2 − q1)²))``, which contradict eqs 1, 3, 4
   (C1 = E − (h+lc)·w, r_A − b = +√…) and eq 8 (whose factor
   (√… + b)/√…·(q2 − q1) is r_A·∂r_A/∂q1 for r_A = b + √…, not for b − √…).
   F below is eq 7 rewritten with the signs of eqs 1–5; its det B is eq 8
   up to the overall sign.
2. Eqs 1–3 have no e and no l3 while eq 7 has both. Here e is the X of the q5
   guide and l3 the Y of the column; e = l3 = 0 gives eqs 1–3 exactly.
3. Eq 1 takes one branch of each square root. They are kept as the default
   *working mode* (+1, +1): q2 above q1, and G at lower Y than A2
   (q5 = Y_C2 − √(c² − (X_C2 − e)²)). The other branches are available.
4. The paper's geometric parameter values are not printed; the defaults of
   :class:`ParaBrachyParams` are chosen for a CT-bed workspace (see there).
5. Eqs 9–10 and the text of type-1 cases 2–4 and type-2 case 5 are missing
   from the source; they are rebuilt from det A and det B as derived here
   (see :class:`SingularityCase`).
"""

from __future__ import annotations

import csv
import dataclasses
import enum
import json
import pathlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

DEG = np.pi / 180.0

__all__ = [
    "DEG",
    "JOINT_NAMES",
    "POSE_NAMES",
    "UnreachableError",
    "IGM_FAILURES",
    "ParaBrachyParams",
    "DEFAULT_PARAMS",
    "WORKSPACE_CENTRE",
    "igm",
    "dgm",
    "closest_pose",
    "dgm_closest",
    "working_mode",
    "needle_points",
    "constraint",
    "jacobian_A",
    "jacobian_B",
    "det_A",
    "det_B",
    "inverse_condition",
    "SingularityCase",
    "singularity_factors",
    "classify_singularity",
    "singular_configuration",
    "architecture_violations",
    "WorkspaceGrid",
    "WorkspaceMap",
    "workspace_map",
    "save_workspace",
    "plot_workspace",
    "PerturbationSweep",
    "perturbation_sweep",
    "wrap_angle",
]

JOINT_NAMES = ("q1", "q2", "q3", "q4", "q5")
POSE_NAMES = ("X_E", "Y_E", "Z_E", "psi", "theta")
_ANGULAR_JOINT = 2  # q3 is the only revolute actuator


class UnreachableError(ValueError):
    """No joint values (IGM) or no assembly (DGM) exist; the message names the equation."""


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


def wrap_angle(a: ArrayLike) -> np.ndarray:
    """Map angles to (−π, π] so differences of ψ compare across the atan2 cut."""
    a = np.asarray(a, dtype=float)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


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


def needle_points(pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> tuple[np.ndarray, np.ndarray]:
    """C1 and C2 (…, 3) of eq 4: the two universal joints on the needle."""
    x = np.asarray(pose, dtype=float)
    psi, th = x[..., 3], x[..., 4]
    w = np.stack([np.sin(th) * np.cos(psi), np.sin(th) * np.sin(psi), -np.cos(th)], axis=-1)
    tip = x[..., :3]
    c1 = tip - (params.h + params.lc) * w
    c2 = tip - params.h * w
    return c1, c2


# ---------------------------------------------------------------------------
# Inverse geometric model (eq 1)
# ---------------------------------------------------------------------------

_IGM_OK, _IGM_THETA, _IGM_RA_BELOW_B, _IGM_RA_BEYOND_D, _IGM_C_TOO_SHORT = 0, 1, 2, 3, 4
_IGM_LIMIT = 5  # 5 + joint index

IGM_FAILURES = {
    _IGM_THETA: "theta outside [0, pi] (eq 5)",
    _IGM_RA_BELOW_B: "eq (1) q2: r_A < b",
    _IGM_RA_BEYOND_D: "eq (1) q2: r_A - b > d",
    _IGM_C_TOO_SHORT: "eq (1) q5: |X_C2 - e| > c",
    **{_IGM_LIMIT + j: f"{JOINT_NAMES[j]} outside its stroke" for j in range(5)},
}


def _igm_core(
    x: np.ndarray, p: ParaBrachyParams, mode: tuple[float, float], check_limits: bool
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Eq 1 vectorised; returns q (NaN where unreachable), failure code, intermediates."""
    c1, c2 = needle_points(x, p)
    theta = x[..., 4]
    # eq 1, q1 and q4
    q1 = c1[..., 2] + p.l1
    q4 = c2[..., 2] - p.l2
    # eq 1, q3: polar angle of C1 about the column (eq 3: X = dx − r cos(π − q3))
    u = p.dx - c1[..., 0]
    v = c1[..., 1] - p.l3
    q3 = np.pi - np.arctan2(v, u)
    r_a = np.hypot(u, v)
    # eq 1, q2
    rb = r_a - p.b
    s2 = p.d**2 - rb**2
    q2 = q1 + mode[0] * np.sqrt(np.clip(s2, 0.0, None))
    # eq 1, q5
    pc = c2[..., 0] - p.e
    t2 = p.c**2 - pc**2
    q5 = c2[..., 1] - mode[1] * np.sqrt(np.clip(t2, 0.0, None))
    q = np.stack([q1, q2, q3, q4, q5], axis=-1)

    code = np.zeros(x.shape[:-1], dtype=np.int8)

    def flag(mask: np.ndarray, value: int) -> None:
        code[(code == _IGM_OK) & mask] = value

    flag((theta < 0.0) | (theta > np.pi), _IGM_THETA)
    flag(rb < 0.0, _IGM_RA_BELOW_B)
    flag(s2 < 0.0, _IGM_RA_BEYOND_D)
    flag(t2 < 0.0, _IGM_C_TOO_SHORT)
    if check_limits:
        lo, hi = np.asarray(p.q_min), np.asarray(p.q_max)
        for j in range(5):
            flag((q[..., j] < lo[j]) | (q[..., j] > hi[j]), _IGM_LIMIT + j)
    q[code != _IGM_OK] = np.nan
    extra = {"r_a": r_a, "rb": rb, "pc": pc, "c1": c1, "c2": c2, "q_raw": np.stack([q1, q2, q3, q4, q5], -1)}
    return q, code, extra


def _igm_message(code: int, i: tuple[int, ...], x: np.ndarray, p: ParaBrachyParams, extra: dict) -> str:
    shown = np.array2string(x[i], precision=6)
    where = f"pose{list(i)} = {shown}" if i else f"pose {shown}"
    if code == _IGM_THETA:
        return (
            f"{where} unreachable: theta = {x[i][4]:.6g} rad is outside [0, pi]; "
            "eq (5) gives theta = atan2(sqrt(lc^2 - dZ^2), dZ)"
        )
    if code == _IGM_RA_BELOW_B:
        return (
            f"{where} unreachable, eq (1) q2: C1 is r_A = {extra['r_a'][i]:.6g} m from the q3 axis, "
            f"less than b = {p.b:.6g} m; the CYL-U places A1 at r_A = b + sqrt(d^2 - (q2 - q1)^2) >= b"
        )
    if code == _IGM_RA_BEYOND_D:
        return (
            f"{where} unreachable, eq (1) q2: r_A - b = {extra['rb'][i]:.6g} m exceeds d = {p.d:.6g} m "
            f"(C1 is r_A = {extra['r_a'][i]:.6g} m from the q3 axis; sqrt of a negative number)"
        )
    if code == _IGM_C_TOO_SHORT:
        return (
            f"{where} unreachable, eq (1) q5: |X_C2 - e| = {abs(extra['pc'][i]):.6g} m exceeds c = {p.c:.6g} m "
            f"(sqrt of a negative number)"
        )
    j = code - _IGM_LIMIT
    val = extra["q_raw"][i][j]
    unit = "rad" if j == _ANGULAR_JOINT else "m"
    return (
        f"{where} unreachable: eq (1) gives {JOINT_NAMES[j]} = {val:.6g} {unit}, outside its stroke "
        f"[{p.q_min[j]:.6g}, {p.q_max[j]:.6g}] {unit}"
    )


def igm(
    pose: ArrayLike,
    params: ParaBrachyParams = DEFAULT_PARAMS,
    working_mode: Sequence[int] = (1, 1),
    *,
    check_limits: bool = True,
) -> np.ndarray:
    """Inverse geometric model (eq 1): pose(s) (…, 5) → joint values (…, 5).

    ``working_mode = (σ1, σ2)`` picks the square-root branches:
    q2 = q1 + σ1·√(d² − (r_A − b)²), q5 = Y_C2 − σ2·√(c² − (X_C2 − e)²);
    eq 1 is (+1, +1). q3 is returned in [0, 2π). Raises
    :class:`UnreachableError` naming the failing equation or stroke for the
    first pose that has no solution.
    """
    x = _as_last5(pose, "pose")
    q, code, extra = _igm_core(x, params, _mode_signs(working_mode), check_limits)
    if (code != _IGM_OK).any():
        i = tuple(int(k) for k in np.argwhere(code != _IGM_OK)[0]) if code.ndim else ()
        raise UnreachableError(_igm_message(int(code[i]), i, x, params, extra))
    return q


# ---------------------------------------------------------------------------
# Direct geometric model (eqs 2–5)
# ---------------------------------------------------------------------------

_DGM_OK, _DGM_D, _DGM_LC, _DGM_CIRCLES, _DGM_COINCIDENT = 0, 1, 2, 3, 4


def _dgm_core(q: np.ndarray, p: ParaBrachyParams) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Eqs 2–5 vectorised: (…, 5) joints → (…, 2, 5) poses, failure code (…)."""
    q1, q2, q3, q4, q5 = (q[..., j] for j in range(5))
    code = np.zeros(q.shape[:-1], dtype=np.int8)

    def flag(mask: np.ndarray, value: int) -> None:
        code[(code == _DGM_OK) & mask] = value

    dq = q2 - q1
    s2 = p.d**2 - dq**2
    flag(s2 < 0.0, _DGM_D)
    r_a = p.b + np.sqrt(np.clip(s2, 0.0, None))
    # eq 3 (column at X = dx, Y = l3)
    xa1 = p.dx - r_a * np.cos(np.pi - q3)
    ya1 = p.l3 + r_a * np.sin(np.pi - q3)
    z_c1 = q1 - p.l1
    z_c2 = q4 + p.l2
    dz = z_c1 - z_c2
    rho2 = p.lc**2 - dz**2
    flag(rho2 < 0.0, _DGM_LC)
    rho = np.sqrt(np.clip(rho2, 0.0, None))
    # eq 2: circle about A1' (radius rho) meets circle about G' = (e, q5) (radius c)
    gx = p.e - xa1
    gy = q5 - ya1
    dist = np.hypot(gx, gy)
    flag(dist < 1e-15, _DGM_COINCIDENT)
    safe = np.where(dist < 1e-15, 1.0, dist)
    along = (rho**2 - p.c**2 + dist**2) / (2.0 * safe)
    half2 = rho**2 - along**2
    slack = 1e-12 * (p.c + rho + dist) ** 2  # rounding at tangency (type-2 case 6)
    flag(half2 < -slack, _DGM_CIRCLES)
    half = np.sqrt(np.clip(half2, 0.0, None))
    ex, ey = gx / safe, gy / safe
    mx, my = xa1 + along * ex, ya1 + along * ey
    sign = np.array([1.0, -1.0])
    xa2 = mx[..., None] - sign * half[..., None] * ey[..., None]
    ya2 = my[..., None] + sign * half[..., None] * ex[..., None]
    # eq 5
    psi = np.arctan2(ya2 - ya1[..., None], xa2 - xa1[..., None])
    theta = np.arctan2(rho, dz)
    st = np.sin(theta)[..., None]
    hl = p.h + p.lc
    # eq 4
    xe = xa1[..., None] + hl * st * np.cos(psi)
    ye = ya1[..., None] + hl * st * np.sin(psi)
    ze = np.broadcast_to((z_c1 - hl * np.cos(theta))[..., None], psi.shape)
    poses = np.stack([xe, ye, ze, psi, np.broadcast_to(theta[..., None], psi.shape)], axis=-1)
    poses[code != _DGM_OK] = np.nan
    extra = {"dq": dq, "rho": rho, "dz": dz, "dist": dist, "r_a": r_a}
    return poses, code, extra


def _dgm_message(code: int, i: tuple[int, ...], q: np.ndarray, p: ParaBrachyParams, extra: dict) -> str:
    shown = np.array2string(q[i], precision=6)
    where = f"q{list(i)} = {shown}" if i else f"q = {shown}"
    if code == _DGM_D:
        return (
            f"no assembly for {where}: eq (3) needs |q2 - q1| = {abs(extra['dq'][i]):.6g} m "
            f"<= d = {p.d:.6g} m"
        )
    if code == _DGM_LC:
        return (
            f"no assembly for {where}: eq (5) needs |Z_C1 - Z_C2| = |q1 - l1 - q4 - l2| = "
            f"{abs(extra['dz'][i]):.6g} m <= lc = {p.lc:.6g} m"
        )
    if code == _DGM_COINCIDENT:
        return f"no unique assembly for {where}: eq (2) circle centres A1 and G coincide"
    return (
        f"no assembly for {where}: eq (2) circles about A1 (radius {extra['rho'][i]:.6g} m) and G "
        f"(radius c = {p.c:.6g} m) do not meet: centre distance {extra['dist'][i]:.6g} m"
    )


def dgm(q: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS, *, strict: bool = True) -> np.ndarray:
    """Direct geometric model (eqs 2–5): joints (…, 5) → both assembly modes (…, 2, 5).

    The two solutions are the two intersections of the circles of eq 2;
    solution 0 has A2 on the left of the directed line A1'→G', solution 1 on
    its right (they coincide at type-2 case 6). ψ is in (−π, π]; at θ = 0
    (type-2 case 5) ψ is undefined and whatever the rounding gives.
    With ``strict`` (default) a configuration that cannot be assembled
    raises :class:`UnreachableError`; otherwise its rows are NaN.
    """
    qa = _as_last5(q, "q")
    poses, code, extra = _dgm_core(qa, params)
    if strict and (code != _DGM_OK).any():
        i = tuple(int(k) for k in np.argwhere(code != _DGM_OK)[0]) if code.ndim else ()
        raise UnreachableError(_dgm_message(int(code[i]), i, qa, params, extra))
    return poses


def _pose_distance(a: np.ndarray, b: np.ndarray, scale: float) -> np.ndarray:
    dpos = a[..., :3] - b[..., :3]
    dang = np.stack([wrap_angle(a[..., 3] - b[..., 3]), a[..., 4] - b[..., 4]], axis=-1)
    return np.sqrt(np.sum(dpos**2, axis=-1) + scale**2 * np.sum(dang**2, axis=-1))


def closest_pose(
    solutions: ArrayLike, reference: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS
) -> np.ndarray:
    """Pick, per configuration, the DGM solution (…, k, 5) nearest to ``reference`` (…, 5).

    Distance: tip distance and (h + lc)·angle differences (ψ wrapped), so a
    degree weighs like the tip motion it causes. NaN solutions never win.
    """
    sol = np.asarray(solutions, dtype=float)
    ref = np.asarray(reference, dtype=float)
    dist = _pose_distance(sol, ref[..., None, :], params.length_scale)
    dist = np.where(np.isnan(dist), np.inf, dist)
    if np.isinf(dist).all(axis=-1).any():
        bad = tuple(int(k) for k in np.argwhere(np.isinf(dist).all(axis=-1))[0])
        raise UnreachableError(f"configuration {list(bad)} has no assembly mode (all DGM solutions are NaN)")
    k = np.argmin(dist, axis=-1)
    return np.take_along_axis(sol, k[..., None, None], axis=-2)[..., 0, :]


def dgm_closest(
    q: ArrayLike, reference: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS
) -> np.ndarray:
    """DGM followed by :func:`closest_pose`: the assembly mode continuing from ``reference``."""
    return closest_pose(dgm(q, params), reference, params)


def working_mode(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """The IGM branches (σ1, σ2) (…, 2) a configuration sits in (0 counts as +1).

    σ1 = sign(q2 − q1), σ2 = sign(Y_C2 − q5); pass them to :func:`igm` to get
    ``q`` back from a DGM solution.
    """
    qa = np.asarray(q, dtype=float)
    _, c2 = needle_points(pose, params)
    s1 = np.where(qa[..., 1] - qa[..., 0] < 0.0, -1, 1)
    s2 = np.where(c2[..., 1] - qa[..., 4] < 0.0, -1, 1)
    return np.stack([s1, s2], axis=-1)


# ---------------------------------------------------------------------------
# Constraint equations (eq 7) and their Jacobians (eq 6)
# ---------------------------------------------------------------------------


def _broadcast(q: ArrayLike, pose: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    qa = _as_last5(q, "q")
    xa = _as_last5(pose, "pose")
    shape = np.broadcast_shapes(qa.shape, xa.shape)
    return np.broadcast_to(qa, shape), np.broadcast_to(xa, shape)


def constraint(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """F(q, x) of eq 7 (signs repaired, see module notes); zero on every assembly.

    f1..f4 are in m, f5 in m² (it is the squared-distance closure of link c).
    """
    qa, xa = _broadcast(q, pose)
    p = params
    X, Y, Z, psi, th = (xa[..., k] for k in range(5))
    q1, q2, q3, q4, q5 = (qa[..., k] for k in range(5))
    hl = p.h + p.lc
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(psi), np.cos(psi)
    r_a = p.b + np.sqrt(p.d**2 - (q2 - q1) ** 2)
    f1 = Z + hl * ct + p.l1 - q1
    f2 = X - hl * st * cp - p.dx + r_a * np.cos(np.pi - q3)
    f3 = Y - hl * st * sp - r_a * np.sin(np.pi - q3) - p.l3
    f4 = Z - p.l2 + p.h * ct - q4
    f5 = (X - p.h * st * cp - p.e) ** 2 + (Y - p.h * st * sp - q5) ** 2 - p.c**2
    return np.stack([f1, f2, f3, f4, f5], axis=-1)


def jacobian_A(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """A = ∂F/∂x (…, 5, 5), columns X_E, Y_E, Z_E, ψ, θ (eq 6: A·ẋ = −B·q̇)."""
    qa, xa = _broadcast(q, pose)
    p = params
    X, Y, psi, th = xa[..., 0], xa[..., 1], xa[..., 3], xa[..., 4]
    hl = p.h + p.lc
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(psi), np.cos(psi)
    P = X - p.h * st * cp - p.e
    Q = Y - p.h * st * sp - qa[..., 4]
    A = np.zeros(xa.shape[:-1] + (5, 5))
    A[..., 0, 2] = 1.0
    A[..., 0, 4] = -hl * st
    A[..., 1, 0] = 1.0
    A[..., 1, 3] = hl * st * sp
    A[..., 1, 4] = -hl * ct * cp
    A[..., 2, 1] = 1.0
    A[..., 2, 3] = -hl * st * cp
    A[..., 2, 4] = -hl * ct * sp
    A[..., 3, 2] = 1.0
    A[..., 3, 4] = -p.h * st
    A[..., 4, 0] = 2.0 * P
    A[..., 4, 1] = 2.0 * Q
    A[..., 4, 3] = 2.0 * p.h * st * (P * sp - Q * cp)
    A[..., 4, 4] = -2.0 * p.h * ct * (P * cp + Q * sp)
    return A


def jacobian_B(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """B = ∂F/∂q (…, 5, 5), columns q1..q5; infinite where √(d² − (q2 − q1)²) = 0 (type-1 case 1)."""
    qa, xa = _broadcast(q, pose)
    p = params
    q1, q2, q3, q5 = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 4]
    Y, psi, th = xa[..., 1], xa[..., 3], xa[..., 4]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(p.d**2 - (q2 - q1) ** 2)
        tau = (q2 - q1) / s  # ∂s/∂q1; ∂s/∂q2 = −tau
    r_a = p.b + s
    Q = Y - p.h * np.sin(th) * np.sin(psi) - q5
    c3, s3 = np.cos(q3), np.sin(q3)
    B = np.zeros(qa.shape[:-1] + (5, 5))
    B[..., 0, 0] = -1.0
    # f2 = … − r_A cos q3, f3 = … − r_A sin q3  (cos(π − q3) = −cos q3, sin(π − q3) = sin q3)
    B[..., 1, 0] = -tau * c3
    B[..., 1, 1] = tau * c3
    B[..., 1, 2] = r_a * s3
    B[..., 2, 0] = -tau * s3
    B[..., 2, 1] = tau * s3
    B[..., 2, 2] = -r_a * c3
    B[..., 3, 3] = -1.0
    B[..., 4, 4] = -2.0 * Q
    return B


def det_A(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """Closed form of det A: 2·lc²·sin²θ·(P sin ψ − Q cos ψ), P = X_C2 − e, Q = Y_C2 − q5.

    Its factors are the type-2 cases: sin θ = 0 (case 5) and link c collinear
    with the needle's horizontal projection (case 6).
    """
    qa, xa = _broadcast(q, pose)
    p = params
    _, c2 = needle_points(xa, p)
    P = c2[..., 0] - p.e
    Q = c2[..., 1] - qa[..., 4]
    psi, th = xa[..., 3], xa[..., 4]
    return 2.0 * p.lc**2 * np.sin(th) ** 2 * (P * np.sin(psi) - Q * np.cos(psi))


def det_B(q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS) -> np.ndarray:
    """Eq 8 with this F's sign: −2·(q5 − Y_C2)·(s + b)/s·(q2 − q1), s = √(d² − (q2 − q1)²).

    Its factors are the four type-1 cases; it is infinite at s = 0 (case 1).
    """
    qa, xa = _broadcast(q, pose)
    p = params
    _, c2 = needle_points(xa, p)
    dq = qa[..., 1] - qa[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(p.d**2 - dq**2)
        return -2.0 * (qa[..., 4] - c2[..., 1]) * (s + p.b) / s * dq


def _scaled(A: np.ndarray, B: np.ndarray, p: ParaBrachyParams) -> tuple[np.ndarray, np.ndarray]:
    """Make A and B dimensionless: f5 / 2c (m² → m), angles as arc lengths (h + lc)·angle."""
    L = p.length_scale
    row = np.array([1.0, 1.0, 1.0, 1.0, 1.0 / (2.0 * p.c)])
    col_a = np.array([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L])
    col_b = np.array([1.0, 1.0, 1.0 / L, 1.0, 1.0])
    return A * row[:, None] * col_a, B * row[:, None] * col_b


def _inv_cond(M: np.ndarray) -> np.ndarray:
    finite = np.isfinite(M).all(axis=(-2, -1))
    safe = np.where(finite[..., None, None], M, 0.0)
    sv = np.linalg.svd(safe, compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sv[..., -1] / sv[..., 0]
    return np.where(finite & (sv[..., 0] > 0.0), ratio, 0.0)


def inverse_condition(
    q: ArrayLike, pose: ArrayLike, params: ParaBrachyParams = DEFAULT_PARAMS
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse condition numbers (σ_min/σ_max) of A and B, in [0, 1]; 0 on a singularity.

    A and B are first made unit-consistent (f5 divided by 2c, angles
    measured as arcs of radius h + lc), so the numbers do not depend on whether
    lengths are in m or mm and fall towards 0 as a singularity nears.
    """
    A, B = _scaled(jacobian_A(q, pose, params), jacobian_B(q, pose, params), params)
    return _inv_cond(A), _inv_cond(B)


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
    w = np.array([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi), -np.cos(theta)])
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


# ---------------------------------------------------------------------------
# Workspace map
# ---------------------------------------------------------------------------


POSE_NAMES_GRID = ("x", "y", "z", "psi", "theta")


@dataclass(frozen=True)
class WorkspaceGrid:
    """Axes of a pose grid: tip X, Y, Z (m), ψ, θ (rad); 1-D arrays."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    psi: np.ndarray
    theta: np.ndarray

    def __post_init__(self) -> None:
        for name in POSE_NAMES_GRID:
            arr = np.atleast_1d(np.asarray(getattr(self, name), dtype=float))
            if arr.ndim != 1 or arr.size == 0 or not np.isfinite(arr).all():
                raise ValueError(f"WorkspaceGrid.{name} must be a non-empty finite 1-D array, got {arr!r}")
            object.__setattr__(self, name, arr)

    @classmethod
    def around(
        cls,
        centre: ArrayLike = WORKSPACE_CENTRE,
        half_width: float = 0.06,
        half_depth: float = 0.03,
        psi_half_range: float = 30.0 * DEG,
        theta_range: tuple[float, float] = (10.0 * DEG, 40.0 * DEG),
        n: Sequence[int] = (13, 13, 7, 7, 7),
    ) -> "WorkspaceGrid":
        """The default CT-bed workspace: X, Y ± 6 cm, Z ± 3 cm, ψ ± 30°, θ 10°–40°."""
        c = np.asarray(centre, dtype=float)
        if len(n) != 5 or min(n) < 1:
            raise ValueError(f"n must be 5 positive grid sizes, got {tuple(n)!r}")
        return cls(
            x=np.linspace(c[0] - half_width, c[0] + half_width, n[0]),
            y=np.linspace(c[1] - half_width, c[1] + half_width, n[1]),
            z=np.linspace(c[2] - half_depth, c[2] + half_depth, n[2]),
            psi=np.linspace(c[3] - psi_half_range, c[3] + psi_half_range, n[3]),
            theta=np.linspace(theta_range[0], theta_range[1], n[4]),
        )

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        return (self.x.size, self.y.size, self.z.size, self.psi.size, self.theta.size)

    def poses(self) -> np.ndarray:
        """All grid poses, shape ``self.shape + (5,)``."""
        mesh = np.meshgrid(self.x, self.y, self.z, self.psi, self.theta, indexing="ij")
        return np.stack(mesh, axis=-1)


@dataclass(frozen=True)
class WorkspaceMap:
    """Reachability and conditioning over a :class:`WorkspaceGrid` (arrays shaped ``grid.shape``).

    ``fail_code`` is 0 where reachable, else a key of ``IGM_FAILURES``;
    ``inv_cond_A`` / ``inv_cond_B`` are NaN where unreachable;
    ``margin`` is the smallest normalised singularity factor and ``nearest``
    the index into ``cases`` of the factor that attains it.
    """

    grid: WorkspaceGrid
    params: ParaBrachyParams
    q: np.ndarray
    reachable: np.ndarray
    fail_code: np.ndarray
    inv_cond_A: np.ndarray
    inv_cond_B: np.ndarray
    margin: np.ndarray
    nearest: np.ndarray
    cases: tuple[str, ...]

    @property
    def reachable_fraction(self) -> float:
        return float(np.mean(self.reachable))


def workspace_map(
    grid: WorkspaceGrid | None = None,
    params: ParaBrachyParams = DEFAULT_PARAMS,
    working_mode: Sequence[int] = (1, 1),
    *,
    check_limits: bool = True,
) -> WorkspaceMap:
    """Evaluate the IGM, conditioning and singularity margin on every grid pose."""
    grid = WorkspaceGrid.around() if grid is None else grid
    x = grid.poses()
    q, code, extra = _igm_core(x, params, _mode_signs(working_mode), check_limits)
    ok = code == _IGM_OK
    q_safe = np.nan_to_num(extra["q_raw"])  # unreachable entries are masked below
    with np.errstate(invalid="ignore", divide="ignore"):
        ica, icb = inverse_condition(q_safe, x, params)
        factors = singularity_factors(q_safe, x, params)
    cases = tuple(c.value for c in (*_TYPE1, *_TYPE2))
    stack = np.stack([factors[SingularityCase(c)] for c in cases], axis=-1)
    nearest = np.argmin(stack, axis=-1).astype(np.int8)
    margin = np.min(stack, axis=-1)
    nan = np.nan
    return WorkspaceMap(
        grid=grid,
        params=params,
        q=q,
        reachable=ok,
        fail_code=code,
        inv_cond_A=np.where(ok, ica, nan),
        inv_cond_B=np.where(ok, icb, nan),
        margin=np.where(ok, margin, nan),
        nearest=np.where(ok, nearest, -1).astype(np.int8),
        cases=cases,
    )


def save_workspace(
    result: WorkspaceMap, path: str | pathlib.Path, *, csv_path: str | pathlib.Path | None = None
) -> pathlib.Path:
    """Write the map to ``path`` (.npz; parameters as JSON) and optionally a flat CSV.

    The .npz keeps the grid axes and full arrays for later analysis; the CSV
    has one row per grid pose for spreadsheets.
    """
    path = pathlib.Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"workspace file must end in .npz, got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    g = result.grid
    np.savez_compressed(
        path,
        x=g.x,
        y=g.y,
        z=g.z,
        psi=g.psi,
        theta=g.theta,
        q=result.q,
        reachable=result.reachable,
        fail_code=result.fail_code,
        inv_cond_A=result.inv_cond_A,
        inv_cond_B=result.inv_cond_B,
        margin=result.margin,
        nearest=result.nearest,
        cases=np.array(result.cases),
        fail_reasons=json.dumps({str(k): v for k, v in IGM_FAILURES.items()}),
        params=json.dumps(result.params.as_dict()),
    )
    if csv_path is not None:
        csv_path = pathlib.Path(csv_path)
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        poses = g.poses().reshape(-1, 5)
        q = result.q.reshape(-1, 5)
        cols = [
            result.reachable.ravel(),
            result.fail_code.ravel(),
            result.inv_cond_A.ravel(),
            result.inv_cond_B.ravel(),
            result.margin.ravel(),
            result.nearest.ravel(),
        ]
        with csv_path.open("w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow([
                "X_E_m", "Y_E_m", "Z_E_m", "psi_rad", "theta_rad", "reachable", "fail_reason",
                "q1_m", "q2_m", "q3_rad", "q4_m", "q5_m", "inv_cond_A", "inv_cond_B",
                "singularity_margin", "nearest_case",
            ])
            for k in range(poses.shape[0]):
                code = int(cols[1][k])
                near = int(cols[5][k])
                wr.writerow([
                    *(f"{v:.9g}" for v in poses[k]),
                    int(cols[0][k]),
                    IGM_FAILURES.get(code, "") if code else "",
                    *(f"{v:.9g}" for v in q[k]),
                    f"{cols[2][k]:.6g}", f"{cols[3][k]:.6g}", f"{cols[4][k]:.6g}",
                    result.cases[near] if near >= 0 else "",
                ])
    return path


def plot_workspace(result: WorkspaceMap, path: str | pathlib.Path) -> pathlib.Path:
    """Save a figure: X–Y maps of 1/cond(A), 1/cond(B) at the middle Z, ψ, θ, and reach per (ψ, θ).

    Uses matplotlib's object API with the Agg canvas, so it needs no display
    and does not touch pyplot's global state.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy: loaded only when a figure is drawn
    from matplotlib.figure import Figure  # heavy: loaded only when a figure is drawn

    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    g = result.grid
    kz, kp, kt = g.z.size // 2, g.psi.size // 2, g.theta.size // 2
    fig = Figure(figsize=(13.5, 4.2), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    extent = [g.x[0] * 1e3, g.x[-1] * 1e3, g.y[0] * 1e3, g.y[-1] * 1e3]
    for ax, data, title in (
        (axes[0], result.inv_cond_A, "1/cond(A) (type 2)"),
        (axes[1], result.inv_cond_B, "1/cond(B) (type 1)"),
    ):
        sl = np.ma.masked_invalid(data[:, :, kz, kp, kt].T)
        im = ax.imshow(sl, origin="lower", extent=extent, aspect="auto", vmin=0.0, cmap="viridis")
        ax.set_title(
            f"{title}\nZ={g.z[kz]*1e3:.0f} mm, psi={g.psi[kp]/DEG:.0f} deg, theta={g.theta[kt]/DEG:.0f} deg",
            fontsize=9,
        )
        ax.set_xlabel("X_E [mm]")
        ax.set_ylabel("Y_E [mm]")
        fig.colorbar(im, ax=ax)
    frac = result.reachable.mean(axis=(0, 1, 2))
    lo, hi = float(np.nanmin(frac)), float(np.nanmax(frac))
    if hi - lo < 0.005:  # reachability is the same everywhere: one colour would say nothing
        data = np.nanmin(np.where(result.reachable, result.margin, np.nan), axis=(0, 1, 2))
        title = (f"smallest singularity margin per orientation\n(over all tip positions; "
                 f"{lo:.0%} of them reachable at every orientation)")
        fmt = None
    else:
        data, fmt = frac, (lambda v, _: f"{v:.0%}")
        title = "reachable fraction of tip positions per orientation"
    im = axes[2].imshow(
        data.T, origin="lower", aspect="auto", cmap="magma",
        extent=[g.psi[0] / DEG, g.psi[-1] / DEG, g.theta[0] / DEG, g.theta[-1] / DEG])
    axes[2].set_title(title, fontsize=9)
    axes[2].set_xlabel("psi [deg]")
    axes[2].set_ylabel("theta [deg]")
    fig.colorbar(im, ax=axes[2], format=fmt)
    fig.savefig(path, dpi=110)
    return path


# ---------------------------------------------------------------------------
# Accuracy assessment (section 4, eqs 12–14)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PerturbationSweep:
    """Eqs 12–14 along a sweep of one joint.

    Arrays are (n_values, 5): row i is the sweep point ``values[i]``, column
    j the joint stepped by ``eps[j]``. ``pos_err`` is eq 12 (m),
    ``psi_err`` eq 13 and ``theta_err`` eq 14 (rad).
    """

    joint_index: int
    values: np.ndarray
    q: np.ndarray
    poses: np.ndarray
    eps: np.ndarray
    pos_err: np.ndarray
    psi_err: np.ndarray
    theta_err: np.ndarray

    @property
    def ratio(self) -> np.ndarray:
        """Tip motion per step, pos_err / ε (m/m for sliders, m/rad for q3)."""
        return self.pos_err / self.eps


def perturbation_sweep(
    joint_index: int,
    values: ArrayLike,
    eps_linear: float = 0.05e-3,
    eps_angular: float = 0.05 * DEG,
    *,
    q_ref: ArrayLike | None = None,
    reference_pose: ArrayLike | None = None,
    params: ParaBrachyParams = DEFAULT_PARAMS,
) -> PerturbationSweep:
    """Section 4's accuracy study: sweep one joint, step each joint by ε, record eqs 12–14.

    The paper increments one joint by ε at a time and differences
    consecutive DGM poses; here every sweep point gets all five steps, so
    one call gives the paper's curves for all joints at once (with values
    spaced by ε, the swept joint's column is exactly the paper's series).
    The assembly mode is followed by continuity from ``reference_pose``
    (default: the workspace centre when ``q_ref`` is not given, else DGM
    solution 0 of ``q_ref``); ``q_ref`` defaults to the IGM of the workspace
    centre. Raises :class:`UnreachableError` if a swept or stepped
    configuration cannot be assembled.
    """
    if joint_index not in range(5):
        raise ValueError(f"joint_index must be 0..4 (q1..q5), got {joint_index!r}")
    if not (eps_linear > 0.0 and eps_angular > 0.0):
        raise ValueError(f"eps must be positive, got eps_linear={eps_linear!r}, eps_angular={eps_angular!r}")
    vals = np.atleast_1d(np.asarray(values, dtype=float))
    if vals.ndim != 1 or not np.isfinite(vals).all():
        raise ValueError(f"values must be a finite 1-D array, got {values!r}")
    if q_ref is None:
        ref_pose = WORKSPACE_CENTRE if reference_pose is None else np.asarray(reference_pose, dtype=float)
        q0 = igm(ref_pose, params, check_limits=False)
    else:
        q0 = _as_last5(q_ref, "q_ref")
        ref_pose = (
            dgm(q0, params)[0] if reference_pose is None else _as_last5(reference_pose, "reference_pose")
        )
    eps = np.full(5, float(eps_linear))
    eps[_ANGULAR_JOINT] = eps_angular
    n = vals.size
    q = np.repeat(q0[None, :], n, axis=0)
    q[:, joint_index] = vals
    poses = np.empty((n, 5))
    prev = ref_pose
    sols = dgm(q, params)
    # follow the assembly mode from the reference along the sweep
    start = int(np.argmin(np.abs(vals - q0[joint_index])))
    order = list(range(start, n)) + list(range(start - 1, -1, -1))
    for i in order:
        if i == start - 1:
            prev = poses[start]
        poses[i] = closest_pose(sols[i], prev, params)
        prev = poses[i]
    stepped = q[:, None, :] + np.eye(5)[None, :, :] * eps[None, None, :]  # (n, 5 joints, 5)
    moved = closest_pose(dgm(stepped, params), np.repeat(poses[:, None, :], 5, axis=1), params)
    pos_err = np.linalg.norm(moved[..., :3] - poses[:, None, :3], axis=-1)
    psi_err = wrap_angle(moved[..., 3] - poses[:, None, 3])
    theta_err = moved[..., 4] - poses[:, None, 4]
    return PerturbationSweep(joint_index, vals, q, poses, eps, pos_err, psi_err, theta_err)
