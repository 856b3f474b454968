"""Seed 003's accuracy study (eqs 12–14) for any robot: sweep one joint, step every joint by ε."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike

from bench.accuracy.poses import (
    PAPER_EPS_ANGULAR,
    PAPER_EPS_LINEAR,
    _axis_angle,
    _joint_index,
    _kinds,
    _names,
    _psi_theta,
    _rows,
    default_pose,
    per_joint,
    robot_label,
)
from bench.kinematics import para_brachy as pb
from bench.kinematics.batch import needle_vectors, wrap_angle
from bench.kinematics.needle import UnreachableError
from bench.kinematics.para_brachy import ParaBrachyRobot

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
    """The paper's ε per joint (0.05 mm sliding, 0.05° rotating) unless given (SI)."""
    defaults = [PAPER_EPS_LINEAR if k == "prismatic" else PAPER_EPS_ANGULAR for k in _kinds(robot)]
    return per_joint(_names(robot), np.array(defaults), eps, "eps", positive=True)


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
    sw = pb.perturbation_sweep(j, vals, linear.pop(), angular.pop(), q_ref=q0,
                               reference_pose=robot.pose(q0), params=robot.params)
    d0 = pb.insertion_direction(sw.poses[:, 3], sw.poses[:, 4])[:, None, :]
    d1 = pb.insertion_direction(sw.poses[:, None, 3] + sw.psi_err, sw.poses[:, None, 4] + sw.theta_err)
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
