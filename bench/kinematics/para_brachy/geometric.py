"""The inverse (eq 1) and direct (eqs 2–5) geometric models, with the assembly mode followed by continuity."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.batch import wrap_angle
from bench.kinematics.needle import UnreachableError
from bench.kinematics.para_brachy.model import (
    _ANGULAR_JOINT,
    DEFAULT_PARAMS,
    JOINT_NAMES,
    ParaBrachyParams,
    _as_last5,
    _mode_signs,
    needle_points,
)

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
