"""Section 4's accuracy study: sweep one joint, step every joint by ε, record eqs 12–14."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.batch import wrap_angle
from bench.kinematics.para_brachy.geometric import closest_pose, dgm, igm
from bench.kinematics.para_brachy.model import (
    _ANGULAR_JOINT,
    DEFAULT_PARAMS,
    DEG,
    WORKSPACE_CENTRE,
    ParaBrachyParams,
    _as_last5,
)

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
