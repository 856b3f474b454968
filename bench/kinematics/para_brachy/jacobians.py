"""The constraint equations (eq 7) and their Jacobians A and B (eq 6), determinants and conditioning."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.para_brachy.model import DEFAULT_PARAMS, ParaBrachyParams, _as_last5, needle_points

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
