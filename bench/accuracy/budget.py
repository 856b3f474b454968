"""The needle-tip error budget: first order (Jacobian × tolerance) and exact (Monte Carlo), beside Table 3."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from bench.accuracy.poses import (
    Distribution,
    Tolerances,
    _axis_angle,
    _kinds,
    _names,
    _sigma,
    default_pose,
    resolve_tolerances,
)
from bench.kinematics.arc_train import SERVO_TOL_DEG, table3_deviations
from bench.kinematics.batch import angle_tilt, needle_jacobian, needle_vectors, wrap_angle

# ---------------------------------------------------------------------------
# First order: the Jacobian budget
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class JacobianBudget:
    """Needle error from joint tolerances to first order (central-difference Jacobian).

    Jacobians are per unit joint motion (m/m, m/rad, rad/m, rad/rad), columns
    in joint order. ``contrib_*`` are ``|J_i|·tol_i`` per joint; ``worst_*``
    their sums (every joint at the tolerance, signs aligned); ``rss_*`` the 1σ
    from ``sigma`` (per axis, and the RMS axis error); ``share_*`` each joint's
    part of the variance.
    """

    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]
    q: np.ndarray
    tolerances: np.ndarray
    sigma: np.ndarray
    distribution: str
    jac_tip: np.ndarray  # (3, n)
    jac_entry: np.ndarray  # (3, n)
    jac_axis: np.ndarray  # (3, n) derivative of the unit direction
    jac_angle: np.ndarray  # (n,) insertion angle
    jac_depth: np.ndarray  # (n,)
    contrib_tip_mm: np.ndarray  # (n, 3)
    contrib_axis_deg: np.ndarray  # (n,)
    worst_tip_mm: np.ndarray  # (3,)
    worst_tip_norm_mm: float
    worst_entry_mm: np.ndarray
    worst_axis_deg: float
    worst_angle_deg: float
    worst_depth_mm: float
    rss_tip_mm: np.ndarray  # (3,)
    rss_tip_norm_mm: float
    rss_entry_mm: np.ndarray
    rss_axis_deg: float
    rss_angle_deg: float
    rss_depth_mm: float
    share_tip: np.ndarray  # (n,)
    share_tip_axes: np.ndarray  # (3, n)
    share_axis: np.ndarray  # (n,)


def _shares(parts: np.ndarray) -> np.ndarray:
    """Normalise non-negative variance parts (…, n) to sum 1; all zero stays zero."""
    total = parts.sum(axis=-1, keepdims=True)
    return np.divide(parts, total, out=np.zeros_like(parts), where=total > 0)


def jacobian_budget(robot, q: Optional[ArrayLike] = None, tolerances: Tolerances = None, *,
                    distribution: Distribution = "uniform", tol_deg: float = SERVO_TOL_DEG) -> JacobianBudget:
    """First-order needle error from each joint's tolerance (see the module notes for σ and shares)."""
    q0 = default_pose(robot) if q is None else np.array(q, dtype=float)
    tol = resolve_tolerances(robot, tolerances, tol_deg)
    sigma = _sigma(tol, distribution)
    J = needle_jacobian(robot, q0)
    axis_rate = np.linalg.norm(J["axis"], axis=0)  # rad of axis turn per unit joint motion
    contrib_tip = np.abs(J["tip"]).T * tol[:, None]
    var_tip_axes = (J["tip"] * sigma) ** 2  # (3, n)
    var_axis = (axis_rate * sigma) ** 2
    return JacobianBudget(
        joint_names=_names(robot), kinds=_kinds(robot), q=q0, tolerances=tol, sigma=sigma,
        distribution=distribution, jac_tip=J["tip"], jac_entry=J["entry"], jac_axis=J["axis"],
        jac_angle=J["angle"], jac_depth=J["depth"],
        contrib_tip_mm=contrib_tip * 1e3, contrib_axis_deg=np.degrees(axis_rate * tol),
        worst_tip_mm=contrib_tip.sum(axis=0) * 1e3,
        worst_tip_norm_mm=float(np.sum(np.linalg.norm(J["tip"], axis=0) * tol) * 1e3),
        worst_entry_mm=(np.abs(J["entry"]) @ tol) * 1e3,
        worst_axis_deg=float(np.degrees(axis_rate @ tol)),
        worst_angle_deg=float(np.degrees(np.abs(J["angle"]) @ tol)),
        worst_depth_mm=float(np.abs(J["depth"]) @ tol * 1e3),
        rss_tip_mm=np.sqrt(var_tip_axes.sum(axis=1)) * 1e3,
        rss_tip_norm_mm=float(np.sqrt(var_tip_axes.sum()) * 1e3),
        rss_entry_mm=np.sqrt(((J["entry"] * sigma) ** 2).sum(axis=1)) * 1e3,
        rss_axis_deg=float(np.degrees(np.sqrt(var_axis.sum()))),
        rss_angle_deg=float(np.degrees(np.sqrt(((J["angle"] * sigma) ** 2).sum()))),
        rss_depth_mm=float(np.sqrt(((J["depth"] * sigma) ** 2).sum()) * 1e3),
        share_tip=_shares(var_tip_axes.sum(axis=0)), share_tip_axes=_shares(var_tip_axes),
        share_axis=_shares(var_axis),
    )


# ---------------------------------------------------------------------------
# Exact: the Monte-Carlo budget
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ErrorStats:
    """Summary of one error sample: mean, std, RMS, 95th percentile and max of |error|."""

    mean: float
    std: float
    rms: float
    p95: float
    max: float

    @classmethod
    def of(cls, x: np.ndarray) -> "ErrorStats":
        a = np.abs(x)
        return cls(float(np.mean(x)), float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
                   float(np.sqrt(np.mean(x ** 2))), float(np.percentile(a, 95)), float(np.max(a)))

    def as_dict(self, digits: int = 4) -> dict[str, float]:
        return {k: round(v, digits) + 0.0 for k, v in
                (("mean", self.mean), ("std", self.std), ("rms", self.rms), ("p95", self.p95), ("max", self.max))}


@dataclass(frozen=True)
class MonteCarloBudget:
    """Needle errors from sampled joint errors through the exact FK (mm and degrees).

    Sample arrays have one row per draw: ``tip_err_mm`` and ``entry_err_mm``
    (n, 3) in X, Y, Z; ``depth_err_mm``, ``axis_err_deg`` (≥ 0, angle between
    the axes), ``angle_err_deg`` (insertion angle, signed) and
    ``tilt_err_deg`` (n,). ``share_tip`` and ``share_axis`` come from one
    joint perturbed at a time (module notes); ``additivity_*`` is
    Σ single-joint variance / total variance.
    """

    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]
    q: np.ndarray
    tolerances: np.ndarray
    distribution: str
    n: int
    seed: int
    joint_err: np.ndarray  # (n, n_joints) SI
    tip_err_mm: np.ndarray
    entry_err_mm: np.ndarray
    depth_err_mm: np.ndarray
    axis_err_deg: np.ndarray
    angle_err_deg: np.ndarray
    tilt_err_deg: np.ndarray
    share_tip: np.ndarray
    share_axis: np.ndarray
    additivity_tip: float
    additivity_axis: float
    nominal_tip_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def tip_stats(self) -> dict[str, ErrorStats]:
        """Per axis (x, y, z) and for the 3-D distance (norm)."""
        out = {a: ErrorStats.of(self.tip_err_mm[:, i]) for i, a in enumerate("xyz")}
        out["norm"] = ErrorStats.of(np.linalg.norm(self.tip_err_mm, axis=1))
        return out

    def entry_stats(self) -> dict[str, ErrorStats]:
        return {a: ErrorStats.of(self.entry_err_mm[:, i]) for i, a in enumerate("xyz")}


def _sample_unit(rng: np.random.Generator, shape: tuple[int, int], distribution: str) -> np.ndarray:
    if distribution == "uniform":
        return rng.uniform(-1.0, 1.0, shape)
    if distribution == "normal":
        return rng.standard_normal(shape) / np.sqrt(3.0)
    return rng.choice(np.array([-1.0, 1.0]), size=shape)


def monte_carlo_budget(robot, q: Optional[ArrayLike] = None, tolerances: Tolerances = None, n: int = 20000,
                       seed: int = 0, distribution: Distribution = "uniform", *, tol_deg: float = SERVO_TOL_DEG,
                       shares: bool = True) -> MonteCarloBudget:
    """Sample joint errors (``distribution``, seeded), push them through the exact FK, summarise.

    ``shares=False`` skips the one-joint-at-a-time runs (n_joints more FK
    batches) and leaves the shares NaN.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n must be an integer >= 2 samples, got {n!r}")
    q0 = default_pose(robot) if q is None else np.array(q, dtype=float)
    tol = resolve_tolerances(robot, tolerances, tol_deg)
    _sigma(tol, distribution)  # validates the name
    rng = np.random.default_rng(seed)
    dq = _sample_unit(rng, (int(n), q0.size), distribution) * tol
    e0, t0, d0 = needle_vectors(robot, q0[None])
    entry, tip, d = needle_vectors(robot, q0 + dq)
    ang0, tilt0 = angle_tilt(d0)
    ang, tilt = angle_tilt(d)
    depth0 = np.sum((t0 - e0) * d0, axis=1)
    depth = np.sum((tip - entry) * d, axis=1)
    tip_err = tip - t0
    dir_err = d - d0
    share_tip = np.full(q0.size, np.nan)
    share_axis = np.full(q0.size, np.nan)
    add_tip = add_axis = float("nan")
    if shares:
        v_tip, v_axis = np.zeros(q0.size), np.zeros(q0.size)
        for j in np.flatnonzero(tol > 0):
            qj = np.repeat(q0[None], int(n), axis=0)
            qj[:, j] += dq[:, j]
            _, tj, dj = needle_vectors(robot, qj)
            v_tip[j] = np.var(tj - t0, axis=0).sum()
            v_axis[j] = np.var(dj - d0, axis=0).sum()
        share_tip, share_axis = _shares(v_tip), _shares(v_axis)
        total_tip, total_axis = np.var(tip_err, axis=0).sum(), np.var(dir_err, axis=0).sum()
        add_tip = float(v_tip.sum() / total_tip) if total_tip > 0 else float("nan")
        add_axis = float(v_axis.sum() / total_axis) if total_axis > 0 else float("nan")
    return MonteCarloBudget(
        joint_names=_names(robot), kinds=_kinds(robot), q=q0, tolerances=tol, distribution=distribution,
        n=int(n), seed=int(seed), joint_err=dq, tip_err_mm=tip_err * 1e3, entry_err_mm=(entry - e0) * 1e3,
        depth_err_mm=(depth - depth0) * 1e3, axis_err_deg=np.degrees(_axis_angle(d, d0)),
        angle_err_deg=np.degrees(wrap_angle(ang - ang0)), tilt_err_deg=np.degrees(tilt - tilt0),
        share_tip=share_tip, share_axis=share_axis, additivity_tip=add_tip, additivity_axis=add_axis,
        nominal_tip_mm=t0[0] * 1e3,
    )


# ---------------------------------------------------------------------------
# Seed 000 Table 3
# ---------------------------------------------------------------------------


def table3_summary() -> dict[str, dict[str, object]]:
    """Table 3's deviations from Target 1 with their statistics, per quantity (mm; angle in degrees)."""
    out: dict[str, dict[str, object]] = {}
    for k, dev in table3_deviations().items():
        out[k] = {"deviations": [round(float(v), 4) + 0.0 for v in dev],
                  "mean": round(float(dev.mean()), 4) + 0.0,
                  "std": round(float(dev.std(ddof=1)), 4) + 0.0,
                  "mean_abs": round(float(np.abs(dev).mean()), 4) + 0.0,
                  "max_abs": round(float(np.abs(dev).max()), 4) + 0.0}
    return out
