"""Linear segments with parabolic blends (LSPB), phase-synchronised over all joints.

Why phase synchronisation: a needle-placement robot should move along the
straight line in joint space between two poses, with every joint starting and
stopping together, so that the path is predictable and easy to check for
collisions with the CT gantry. Every joint therefore follows one normalised
profile s: [0, tf] -> [0, 1],

    q_i(t) = q0_i + D_i * s(t),        D_i = qf_i - q0_i,

where s has peak speed V and blend acceleration A. They are the largest that
keep every moving joint within its own limits:

    V = min_i vmax_i / |D_i|,          A = min_i amax_i / |D_i|.

Per joint this is the textbook LSPB with signed blend acceleration a = A * D_i,
blend time tb and duration tf:

    0       <= t <= tb:        q = q0 + 1/2 a t^2
    tb      <= t <= tf - tb:   q = q0 + a tb (t - tb/2)
    tf - tb <= t <= tf:        q = qf - 1/2 a (tf - t)^2

Source: "Experimental and numerical analysis of Novel 9 DOF Robotic Manipulator
for CT guided medical procedure", eqs 21-23. The paper prints these with typos
and in the wrong order: its eq 21 gives the cruise segment as
"θ0 − 0.5 t t_b² θ̈ + θ̈ t t_b t_p"; the final blend is its eq 23, and its eq 22
has the sign of the blend wrong. The equations above are the corrected forms.

Timing. Time-optimal (no duration requested): if V^2 / A >= 1 the speed limit
is never reached and the profile is triangular, tb = sqrt(1/A), tf = 2 tb;
otherwise tb = V / A and tf = 1/V + V/A. With a requested duration tf, a
blend exists only if A >= 4 / tf^2; using the full acceleration A,

    tb = tf/2 - sqrt(A^2 tf^2 - 4A) / (2A) = 2 / (A tf + sqrt(A^2 tf^2 - 4A)),

(the second form avoids cancellation when tb << tf) and the cruise speed A tb
must not exceed V. Each solves A tb (tf - tb) = 1, so the segments meet.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .base import Limits, PointToPoint, TrajectoryError, as_joint_vector, as_times

__all__ = ["LSPB"]

# Relative slack on the feasibility checks, so that asking for exactly the
# time-optimal duration is not rejected because of rounding.
_REL_TOL = 1e-12


def _per_joint(name: str, value: ArrayLike, dof: int) -> np.ndarray:
    """A limit per joint; a scalar applies to every joint."""
    if np.ndim(value) == 0:
        value = np.full(dof, value, dtype=float)
    return as_joint_vector(name, value, dof)


class LSPB(PointToPoint):
    """Straight-line joint-space move with trapezoidal (or triangular) speed.

    ``velocity_limit`` and ``acceleration_limit`` are per-joint magnitudes
    (a scalar applies to all joints). Without ``duration`` the plan is the
    fastest the limits allow; with it, the plan takes exactly that long or
    raises :class:`TrajectoryError` naming the joint that makes it infeasible.
    """

    def __init__(
        self,
        start: ArrayLike,
        goal: ArrayLike,
        velocity_limit: ArrayLike,
        acceleration_limit: ArrayLike,
        duration: float | None = None,
    ) -> None:
        self._start = as_joint_vector("start", start)
        dof = self._start.size
        self._goal = as_joint_vector("goal", goal, dof)
        vmax = _per_joint("velocity_limit", velocity_limit, dof)
        amax = _per_joint("acceleration_limit", acceleration_limit, dof)
        Limits(vmax, amax)  # positivity, with the joint named on failure

        self._delta = self._goal - self._start
        moving = np.flatnonzero(self._delta != 0.0)
        tf_req = None if duration is None else self._check_duration(duration, moving.size > 0)

        if moving.size == 0:
            s_acc, tb, tf = 0.0, 0.0, (tf_req or 0.0)
        else:
            dist = np.abs(self._delta[moving])
            v_ratio = vmax[moving] / dist
            a_ratio = amax[moving] / dist
            s_vel, s_acc = float(v_ratio.min()), float(a_ratio.min())
            if tf_req is None:
                tb, tf = self._time_optimal(s_vel, s_acc)
            else:
                tf = tf_req
                s_acc, tb = self._blend_for_duration(s_acc, tf, moving, dist, amax)
                cruise = s_acc * tb
                if cruise > s_vel * (1.0 + _REL_TOL):
                    k = int(np.argmin(v_ratio))
                    j = int(moving[k])
                    raise TrajectoryError(
                        f"duration {tf:.6g} s is too fast for joint {j}'s velocity limit: "
                        f"it would need {cruise * dist[k]:.6g} but the limit is {vmax[j]:.6g}"
                    )

        self._s_acc = s_acc
        self._tb = tb
        self._tf = tf
        self._acc = self._delta * s_acc
        self._peak = self._acc * tb
        for arr in (self._delta, self._acc, self._peak):
            arr.setflags(write=False)

    # -- planning ---------------------------------------------------------
    @staticmethod
    def _check_duration(duration: float, moving: bool) -> float:
        tf = float(duration)
        if not math.isfinite(tf) or tf < 0.0 or (moving and tf == 0.0):
            raise TrajectoryError(
                f"duration must be finite and {'> 0' if moving else '>= 0'}, got {duration!r}"
            )
        return tf

    @staticmethod
    def _time_optimal(s_vel: float, s_acc: float) -> tuple[float, float]:
        if s_vel * s_vel / s_acc >= 1.0:
            tb = math.sqrt(1.0 / s_acc)
            return tb, 2.0 * tb
        return s_vel / s_acc, 1.0 / s_vel + s_vel / s_acc

    @staticmethod
    def _blend_for_duration(
        s_acc: float, tf: float, moving: np.ndarray, dist: np.ndarray, amax: np.ndarray
    ) -> tuple[float, float]:
        """Blend time at full acceleration: the shortest blend gives the lowest cruise speed."""
        needed = 4.0 / (tf * tf)
        if s_acc < needed * (1.0 - _REL_TOL):
            k = int(np.argmin(amax[moving] / dist))
            j = int(moving[k])
            raise TrajectoryError(
                f"acceleration too low to blend in {tf:.6g} s: joint {j} has acceleration "
                f"limit {amax[j]:.6g} but needs at least {needed * dist[k]:.6g}"
            )
        if s_acc <= needed:
            return needed, 0.5 * tf
        disc = s_acc * (s_acc * tf * tf - 4.0)
        return s_acc, 2.0 / (s_acc * tf + math.sqrt(disc))

    # -- Trajectory protocol ----------------------------------------------
    @property
    def duration(self) -> float:
        return self._tf

    @property
    def blend_time(self) -> float:
        """Length of each parabolic blend (half the duration when triangular)."""
        return self._tb

    @property
    def peak_velocity(self) -> np.ndarray:
        """Top speed of each joint (cruise, or apex if triangular), signed like goal − start."""
        return self._peak

    @property
    def acceleration(self) -> np.ndarray:
        """Acceleration of each joint during the first blend, signed like goal − start."""
        return self._acc

    def sample(self, t: float | ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """State at time(s) ``t``; intervals are half-open, so at ``tf`` the joints are at rest."""
        times, scalar = as_times(t)
        tc = times[:, None]
        tb, tf, s_acc = self._tb, self._tf, self._s_acc
        q0, qf, d = self._start, self._goal, self._delta
        shape = (times.size, self.dof)
        conds = [np.broadcast_to(c, shape) for c in (tc < 0.0, tc < tb, tc < tf - tb, tc < tf)]
        zero = np.zeros(shape)
        q = np.select(
            conds,
            [
                np.broadcast_to(q0, shape),
                q0 + d * (0.5 * s_acc * tc * tc),
                q0 + d * (s_acc * tb * (tc - 0.5 * tb)),
                qf - d * (0.5 * s_acc * (tf - tc) ** 2),
            ],
            default=np.broadcast_to(qf, shape),
        )
        qd = np.select(
            conds,
            [
                zero,
                d * (s_acc * tc),
                np.broadcast_to(d * (s_acc * tb), shape),
                d * (s_acc * (tf - tc)),
            ],
            default=zero,
        )
        acc = np.broadcast_to(self._acc, shape)
        qdd = np.select(conds, [zero, acc, zero, -acc], default=zero)
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd
