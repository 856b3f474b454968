"""How far the needle goes wrong when the joints are off by their tolerances.

Three views of one question, for any robot model with the bench's interface
(``chain.rows`` with name, kind, lower, upper, home; ``joint_names``;
``needle(q) -> NeedlePose``; ``ik(NeedleTarget) -> q``):

* :func:`perturbation_sweep` — seed 003's accuracy study (eqs 12–14): sweep
  one joint, step every joint by ε (0.05 mm or 0.05°) at each sweep point and
  record how far the needle tip moves (eq 12) and how its orientation turns
  (ψ, eq 13; θ, eq 14; and the total angle between the needle axes). For the
  parallel robot the implementation in :mod:`bench.kinematics.para_brachy` is
  used and its output converted.
* :func:`jacobian_budget` — first order: the numerical Jacobian (central
  differences) of the tip, entry point and needle axis, times each joint's
  tolerance: per-joint contributions, the worst case (Σ |J_i|·tol_i), the RSS
  (1σ) and each joint's share of the variance.
* :func:`monte_carlo_budget` — exact: joint errors sampled and pushed through
  the forward kinematics; the tip, entry, depth and angle error distributions
  and each joint's share of the variance.

Units: SI inside (m, rad); results carry mm and degrees in their names.

Orientation: ``θ`` is the needle's angle from the downward vertical and ``ψ``
the azimuth of its horizontal projection (seed 003's pose angles, defined
for every robot from the needle direction). The *axis error* is the angle
between the perturbed and the nominal needle axis (always ≥ 0). The
*insertion angle* and *tilt* are the bench's (README): the angle in the
axial plane measured from −Z towards +Y, and the lean out of that plane;
Table 3's "angle of insertion" is the former.

Joint-error models (``distribution``), all zero-mean and independent per
joint:

* ``"uniform"`` — uniform on ±tol: the servo deadband model (a Dynamixel
  servo settles anywhere within its ±0.29° band); σ = tol/√3.
* ``"normal"`` — normal with the *same variance* as the uniform model
  (σ = tol/√3), so the two differ only in their tails.
* ``"endpoints"`` — ±tol with random sign: every servo over- or undershoots
  by the full tolerance, the wording of seed 000 section 6; σ = tol.

Variance shares: a joint's share of the tip error is its part of the total
tip variance (the trace of the 3×3 covariance, i.e. the mean squared 3-D
error); of the axis error, its part of the needle direction's variance.
:func:`jacobian_budget` takes ``(|J_i| σ_i)² / Σ_j (|J_j| σ_j)²``.
:func:`monte_carlo_budget` perturbs one joint at a time with the same
samples and takes ``V_i / Σ_j V_j`` (so the shares sum to 1); ``additivity``
``= Σ_j V_j / V_total`` says how well single-joint variances add up (1 for a
linear map and independent errors). A joint with zero tolerance has share 0.

Servo tolerances (seed 000 section 6: the Dynamixel servos hold position to
±0.29°). Every joint of the arc-and-train robot is servo-driven, the train's
arc angle too. Through the transmission a servo error of ±δ becomes:

* revolute joints (direct drive): ±δ;
* prismatic joints: rack and pinion with a 10 mm pinion radius
  (:data:`PINION_RADIUS`): ±δ·10 mm, so ±0.29° → ±0.0506 mm;
* the train: the same 10 mm pinion on the arc's rack of radius R = 200 mm:
  ±δ·10/200 of arc angle, so ±0.29° → ±0.0145°.

Other robots: revolute joints direct drive, prismatic joints the same rack
and pinion (for the parallel robot this gives ±0.0506 mm on its sliders,
close to the paper's ε = 0.05 mm). Every tolerance can be set per joint.

Default poses (:func:`default_pose`): the arc-and-train robot at Target 1
(the IK of :data:`bench.kinematics.arc_train.TARGET_1`: Y 88.2 mm, Z 66 mm,
30.1 mm deep at 47°, where Table 3 was measured); the parallel robot at its
workspace centre (its adapter's home, in its own base frame); every other
robot (they share the bed frame) at the same Target 1 by its own IK, so the
budgets of different robots compare at one clinical target — Zerobot
reaches it with q4 = 47° and q6 = 30.1 mm — or at its home if it cannot
reach it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics import para_brachy as pb
from bench.kinematics.arc_train import (
    PINION_RADIUS,
    SERVO_TOL_DEG,
    TABLE3_MEASURED,
    TABLE3_TARGET,
    TARGET_1,
    ArcTrainRobot,
    table3_deviations,
)
from bench.kinematics.batch import angle_tilt, needle_jacobian, needle_vectors, wrap_angle
from bench.kinematics.needle import UnreachableError
from bench.kinematics.para_brachy import ParaBrachyRobot

__all__ = [
    "DISTRIBUTIONS",
    "Distribution",
    "Tolerances",
    "PAPER_EPS_LINEAR",
    "PAPER_EPS_ANGULAR",
    "PINION_RADIUS",
    "SERVO_TOL_DEG",
    "TABLE3_MEASURED",
    "TABLE3_TARGET",
    "ErrorStats",
    "JacobianBudget",
    "MonteCarloBudget",
    "Sweep",
    "default_pose",
    "default_sweep",
    "default_tolerances",
    "jacobian_budget",
    "monte_carlo_budget",
    "perturbation_sweep",
    "pose_from_joints",
    "resolve_tolerances",
    "robot_label",
    "servo_transmissions",
    "table3_summary",
]

Distribution = Literal["uniform", "normal", "endpoints"]
DISTRIBUTIONS: tuple[str, ...] = ("uniform", "normal", "endpoints")
Tolerances = Union[None, Mapping[str, float], Sequence[float], np.ndarray]

DEG = np.pi / 180.0
PAPER_EPS_LINEAR = 0.05e-3  #: seed 003's ε for a sliding joint (m)
PAPER_EPS_ANGULAR = 0.05 * DEG  #: seed 003's ε for a rotating joint (rad)


# ---------------------------------------------------------------------------
# Robots, poses and tolerances
# ---------------------------------------------------------------------------

def robot_label(robot) -> str:
    return str(getattr(robot, "name", type(robot).__name__))


def _rows(robot) -> tuple:
    return tuple(robot.chain.rows)


def _kinds(robot) -> tuple[str, ...]:
    return tuple(r.kind for r in _rows(robot))


def _names(robot) -> tuple[str, ...]:
    return tuple(robot.joint_names)


def default_pose(robot) -> np.ndarray:
    """Where the budget is taken when no pose is given (see the module notes)."""
    home = np.array([r.home for r in _rows(robot)], dtype=float)
    if isinstance(robot, ParaBrachyRobot):
        return home
    try:
        return np.asarray(robot.ik(TARGET_1), dtype=float)
    except UnreachableError:
        return home


def pose_from_joints(robot, values: Mapping[str, float], base: Optional[ArrayLike] = None) -> np.ndarray:
    """Joint dict (SI) → vector; missing joints from ``base`` (default pose); checked against limits."""
    names = _names(robot)
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"unknown joint(s) {unknown}; {robot_label(robot)} joints are {list(names)}")
    q = default_pose(robot) if base is None else np.array(base, dtype=float)
    for i, n in enumerate(names):
        if n in values:
            v = values[n]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"joint {n} must be a finite number (rad or m), got {v!r}")
            q[i] = float(v)
    _check_limits(robot, q)
    return q


def _check_limits(robot, q: np.ndarray) -> None:
    for n, v, r in zip(_names(robot), q, _rows(robot)):
        if not r.lower - 1e-12 <= v <= r.upper + 1e-12:
            raise ValueError(f"joint {n} = {v:.6g} is outside its limits [{r.lower:.6g}, {r.upper:.6g}]")


def servo_transmissions(robot) -> np.ndarray:
    """Joint motion per radian of servo error: 1 (direct drive), the pinion radius (m) or R_pinion/R_arc."""
    ratio = np.array([PINION_RADIUS if k == "prismatic" else 1.0 for k in _kinds(robot)])
    if isinstance(robot, ArcTrainRobot):
        ratio[_names(robot).index("train")] = PINION_RADIUS / robot.params.arc_radius
    return ratio


def default_tolerances(robot, tol_deg: float = SERVO_TOL_DEG) -> np.ndarray:
    """±tolerance per joint (rad or m) for servos holding ±``tol_deg`` through their transmissions."""
    if not (np.isfinite(tol_deg) and tol_deg >= 0.0):
        raise ValueError(f"servo tolerance must be a non-negative number of degrees, got {tol_deg!r}")
    return tol_deg * DEG * servo_transmissions(robot)


def resolve_tolerances(robot, tolerances: Tolerances = None, tol_deg: float = SERVO_TOL_DEG) -> np.ndarray:
    """Per-joint tolerances (SI): defaults, a {joint: tol} override, or a full vector."""
    names = _names(robot)
    tol = default_tolerances(robot, tol_deg)
    if tolerances is None:
        return tol
    if isinstance(tolerances, Mapping):
        unknown = sorted(set(tolerances) - set(names))
        if unknown:
            raise ValueError(f"tolerance for unknown joint(s) {unknown}; joints are {list(names)}")
        for i, n in enumerate(names):
            if n in tolerances:
                tol[i] = float(tolerances[n])
    else:
        arr = np.asarray(tolerances, dtype=float)
        if arr.shape != (len(names),):
            raise ValueError(f"expected {len(names)} tolerances ({', '.join(names)}), got shape {arr.shape}")
        tol = arr.copy()
    for n, t in zip(names, tol):
        if not (np.isfinite(t) and t >= 0.0):
            raise ValueError(f"tolerance of joint {n} must be finite and >= 0, got {float(t)!r}")
    return tol


def _sigma(tol: np.ndarray, distribution: str) -> np.ndarray:
    """1σ of each joint's error under ``distribution``."""
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution must be one of {DISTRIBUTIONS}, got {distribution!r}")
    return tol if distribution == "endpoints" else tol / np.sqrt(3.0)


def _joint_index(robot, joint: Union[str, int]) -> int:
    names = _names(robot)
    if isinstance(joint, str):
        if joint not in names:
            raise ValueError(f"unknown joint {joint!r}; {robot_label(robot)} joints are {list(names)}")
        return names.index(joint)
    if isinstance(joint, (int, np.integer)) and 0 <= joint < len(names):
        return int(joint)
    raise ValueError(f"joint must be a name in {list(names)} or an index 0..{len(names) - 1}, got {joint!r}")


# ---------------------------------------------------------------------------
# Forward kinematics in batches
# ---------------------------------------------------------------------------


def _psi_theta(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seed 003's ψ (azimuth) and θ (from the downward vertical) of unit directions (…, 3)."""
    return np.arctan2(d[..., 1], d[..., 0]), np.arctan2(np.hypot(d[..., 0], d[..., 1]), -d[..., 2])


def _axis_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors, accurate for tiny angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


# ---------------------------------------------------------------------------
# Eqs 12–14: the perturbation sweep
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Sweep:
    """Seed 003 eqs 12–14 along a sweep of one joint.

    Arrays ``(n_values, n_joints)``: row i is the sweep point ``values[i]``
    (SI), column j the joint stepped by ``eps[j]`` (SI). ``pos_change_mm`` is
    eq 12, ``psi_change_deg`` eq 13, ``theta_change_deg`` eq 14 and
    ``axis_change_deg`` the angle between the needle axes before and after
    the step.
    """

    robot: str
    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]
    joint: str
    values: np.ndarray
    q: np.ndarray
    eps: np.ndarray
    tip_mm: np.ndarray
    pos_change_mm: np.ndarray
    psi_change_deg: np.ndarray
    theta_change_deg: np.ndarray
    axis_change_deg: np.ndarray

    @property
    def eps_display(self) -> np.ndarray:
        """ε in mm (sliding joints) or degrees (rotating joints)."""
        return np.array([e * 1e3 if k == "prismatic" else np.degrees(e) for e, k in zip(self.eps, self.kinds)])

    @property
    def ratio(self) -> np.ndarray:
        """Tip motion per step: mm per mm for sliding joints, mm per degree for rotating ones."""
        return self.pos_change_mm / self.eps_display

    @property
    def values_display(self) -> np.ndarray:
        """The swept values in mm or degrees."""
        j = self.joint_names.index(self.joint)
        return self.values * 1e3 if self.kinds[j] == "prismatic" else np.degrees(self.values)


def _resolve_eps(robot, eps) -> np.ndarray:
    names, kinds = _names(robot), _kinds(robot)
    out = np.array([PAPER_EPS_LINEAR if k == "prismatic" else PAPER_EPS_ANGULAR for k in kinds])
    if eps is None:
        return out
    if isinstance(eps, Mapping):
        unknown = sorted(set(eps) - set(names))
        if unknown:
            raise ValueError(f"eps for unknown joint(s) {unknown}; joints are {list(names)}")
        for i, n in enumerate(names):
            if n in eps:
                out[i] = float(eps[n])
    else:
        arr = np.asarray(eps, dtype=float)
        if arr.shape != (len(names),):
            raise ValueError(f"expected {len(names)} eps values ({', '.join(names)}), got shape {arr.shape}")
        out = arr.copy()
    for n, e in zip(names, out):
        if not (np.isfinite(e) and e > 0.0):
            raise ValueError(f"eps of joint {n} must be positive, got {float(e)!r}")
    return out


def perturbation_sweep(robot, q_ref: Optional[ArrayLike], joint: Union[str, int], values: ArrayLike,
                       eps: Union[None, Mapping[str, float], Sequence[float]] = None, *,
                       native: bool = True) -> Sweep:
    """Seed 003's accuracy study for any robot: sweep ``joint`` over ``values``, step every joint by ε.

    The other joints stay at ``q_ref`` (default: :func:`default_pose`). ε
    defaults to the paper's 0.05 mm (prismatic) and 0.05° (revolute), or is
    given per joint (SI). Every sweep point gets every step, so one call
    gives the paper's curves for all joints. For the parallel robot the
    implementation in :func:`bench.kinematics.para_brachy.perturbation_sweep`
    is used (``native=False`` runs the generic one, e.g. to cross-check).
    """
    j = _joint_index(robot, joint)
    q0 = default_pose(robot) if q_ref is None else np.array(q_ref, dtype=float)
    if q0.shape != (len(_names(robot)),):
        raise ValueError(f"q_ref must have {len(_names(robot))} joint values, got shape {q0.shape}")
    vals = np.atleast_1d(np.asarray(values, dtype=float))
    if vals.ndim != 1 or vals.size == 0 or not np.isfinite(vals).all():
        raise ValueError(f"values must be a non-empty finite 1-D array, got {values!r}")
    row = _rows(robot)[j]
    outside = vals[(vals < row.lower - 1e-12) | (vals > row.upper + 1e-12)]
    if outside.size:
        raise ValueError(f"sweep value {outside[0]:.6g} of joint {row.name} is outside its limits "
                         f"[{row.lower:.6g}, {row.upper:.6g}]")
    step = _resolve_eps(robot, eps)
    if native and isinstance(robot, ParaBrachyRobot):
        return _sweep_para_brachy(robot, q0, j, vals, step)
    return _sweep_generic(robot, q0, j, vals, step)


def _sweep_generic(robot, q0: np.ndarray, j: int, vals: np.ndarray, step: np.ndarray) -> Sweep:
    n = len(q0)
    q = np.repeat(q0[None, :], vals.size, axis=0)
    q[:, j] = vals
    stepped = q[:, None, :] + np.eye(n)[None] * step[None, None, :]
    _, tip, d = needle_vectors(robot, np.concatenate([q, stepped.reshape(-1, n)]))
    m = vals.size
    tip0, d0 = tip[:m], d[:m]
    tip1, d1 = tip[m:].reshape(m, n, 3), d[m:].reshape(m, n, 3)
    psi0, th0 = _psi_theta(d0)
    psi1, th1 = _psi_theta(d1)
    return Sweep(
        robot=robot_label(robot), joint_names=_names(robot), kinds=_kinds(robot), joint=_names(robot)[j],
        values=vals, q=q, eps=step, tip_mm=tip0 * 1e3,
        pos_change_mm=np.linalg.norm(tip1 - tip0[:, None, :], axis=-1) * 1e3,
        psi_change_deg=np.degrees(wrap_angle(psi1 - psi0[:, None])),
        theta_change_deg=np.degrees(th1 - th0[:, None]),
        axis_change_deg=np.degrees(_axis_angle(d1, d0[:, None, :])),
    )


def _sweep_para_brachy(robot: ParaBrachyRobot, q0: np.ndarray, j: int, vals: np.ndarray,
                       step: np.ndarray) -> Sweep:
    """The parallel robot's own eqs 12–14 (para_brachy.perturbation_sweep), in mm and degrees."""

    kinds = _kinds(robot)
    linear = {float(e) for e, k in zip(step, kinds) if k == "prismatic"}
    angular = {float(e) for e, k in zip(step, kinds) if k == "revolute"}
    if len(linear) != 1 or len(angular) != 1:
        raise ValueError(f"the parallel robot's sweep takes one ε for its sliders and one for q3, got "
                         f"{np.array2string(step, precision=6)}; pass native=False for per-joint ε")
    try:
        sw = pb.perturbation_sweep(j, vals, linear.pop(), angular.pop(), q_ref=q0,
                                   reference_pose=robot.pose(q0), params=robot.params)
    except pb.UnreachableError as e:
        raise UnreachableError(str(e)) from None

    def direction(psi: np.ndarray, th: np.ndarray) -> np.ndarray:
        return np.stack([np.sin(th) * np.cos(psi), np.sin(th) * np.sin(psi), -np.cos(th)], axis=-1)

    d0 = direction(sw.poses[:, 3], sw.poses[:, 4])[:, None, :]
    d1 = direction(sw.poses[:, None, 3] + sw.psi_err, sw.poses[:, None, 4] + sw.theta_err)
    return Sweep(
        robot=robot_label(robot), joint_names=_names(robot), kinds=kinds, joint=_names(robot)[j],
        values=sw.values, q=sw.q, eps=sw.eps, tip_mm=sw.poses[:, :3] * 1e3,
        pos_change_mm=sw.pos_err * 1e3, psi_change_deg=np.degrees(sw.psi_err),
        theta_change_deg=np.degrees(sw.theta_err), axis_change_deg=np.degrees(_axis_angle(d1, d0)),
    )


def default_sweep(robot, q: Optional[ArrayLike] = None, joint: Union[None, str, int] = None,
                  n: int = 41) -> tuple[str, np.ndarray]:
    """A sweep for the report: ``joint`` over its whole range, trimmed to where the robot assembles.

    ``joint`` defaults to q1 for the parallel robot (the paper's sweep) and
    to the needle insertion for a serial robot (its ``insertion_joint``, else
    its last joint): the sweep then shows how each joint's effect on the tip
    grows with depth. Where a parallel mechanism cannot be assembled the
    range stops two grid steps short; ``q`` is always inside it.
    """
    if joint is None:
        joint = 0 if isinstance(robot, ParaBrachyRobot) else getattr(robot, "insertion_joint", -1)
        joint = len(_names(robot)) - 1 if joint == -1 else joint
    j = _joint_index(robot, joint)
    q0 = default_pose(robot) if q is None else np.array(q, dtype=float)
    row = _rows(robot)[j]
    grid = np.unique(np.concatenate([np.linspace(row.lower, row.upper, 201), [q0[j]]]))
    ok = np.ones(grid.size, dtype=bool)
    for i, v in enumerate(grid):
        qi = q0.copy()
        qi[j] = v
        try:
            robot.needle(qi)
        except ValueError:  # UnreachableError and the models' own no-assembly errors
            ok[i] = False
    k = int(np.flatnonzero(grid == q0[j])[0])
    if not ok[k]:
        raise UnreachableError(f"{robot_label(robot)} cannot be assembled at q = {np.array2string(q0, precision=6)}")
    lo, hi = k, k
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < grid.size - 1 and ok[hi + 1]:
        hi += 1
    lo = min(k, lo + 2) if lo > 0 else lo
    hi = max(k, hi - 2) if hi < grid.size - 1 else hi
    if hi == lo:
        return _names(robot)[j], np.array([q0[j]])
    return _names(robot)[j], np.linspace(grid[lo], grid[hi], n)


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
