"""What every trajectory generator shares: the error type, joint limits, the protocol.

The runner and the analysis only ever call :meth:`Trajectory.sample`, so LSPB,
offline ruckig and online ruckig are interchangeable behind it. Units are SI:
rad or m for positions, per second for each derivative.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from drivers.errors import TrajectoryError

__all__ = ["Limits", "Trajectory", "TrajectoryError", "as_joint_vector", "as_times"]


def as_joint_vector(name: str, value: ArrayLike, dof: int | None = None) -> np.ndarray:
    """One finite float per joint, as a read-only array.

    Checked once at construction so that sampling never has to; the message
    names the argument and the offending joint so a bad config is quick to find.
    """
    try:
        vec = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrajectoryError(f"{name} must be numeric, got {value!r}") from exc
    if vec.ndim != 1 or vec.size == 0:
        raise TrajectoryError(
            f"{name} must be a non-empty 1-D array (one value per joint), got shape {vec.shape}"
        )
    if dof is not None and vec.size != dof:
        raise TrajectoryError(f"{name} has {vec.size} values but the motion has {dof} joints")
    bad = np.flatnonzero(~np.isfinite(vec))
    if bad.size:
        i = int(bad[0])
        raise TrajectoryError(f"{name}[{i}] is not finite: {float(vec[i])}")
    vec.setflags(write=False)
    return vec


def as_times(t: float | ArrayLike) -> tuple[np.ndarray, bool]:
    """Sample times as a 1-D float array, plus whether the caller passed a scalar."""
    arr = np.asarray(t, dtype=float)
    if arr.ndim > 1:
        raise TrajectoryError(f"t must be a float or a 1-D array of times, got shape {arr.shape}")
    if np.isnan(arr).any():
        raise TrajectoryError("t contains NaN")
    return np.atleast_1d(arr), arr.ndim == 0


@dataclass(frozen=True, eq=False)
class Limits:
    """Per-joint kinematic limits (magnitudes, symmetric about zero).

    ``velocity`` and ``acceleration`` must be finite and positive. ``jerk`` may
    be ``np.inf`` (per joint, or a scalar applied to every joint) to ask for a
    second-order, acceleration-limited plan.
    """

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray = field(default_factory=lambda: np.array(np.inf))

    def __post_init__(self) -> None:
        vel = as_joint_vector("velocity limit", self.velocity)
        acc = as_joint_vector("acceleration limit", self.acceleration, vel.size)
        jerk = np.array(self.jerk, dtype=float)
        if jerk.ndim == 0:
            jerk = np.full(vel.size, float(jerk))
        if jerk.ndim != 1 or jerk.size != vel.size:
            raise TrajectoryError(
                f"jerk limit has shape {jerk.shape} but the velocity limit has {vel.size} joints"
            )
        jerk.setflags(write=False)
        for name, arr in (("velocity", vel), ("acceleration", acc), ("jerk", jerk)):
            bad = np.flatnonzero(~(arr > 0))
            if bad.size:
                i = int(bad[0])
                raise TrajectoryError(
                    f"{name} limit of joint {i} must be > 0, got {float(arr[i])}"
                )
            object.__setattr__(self, name, arr)

    @property
    def dof(self) -> int:
        return int(self.velocity.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Limits):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, n), getattr(other, n))
            for n in ("velocity", "acceleration", "jerk")
        )

    def __hash__(self) -> int:
        return hash((self.velocity.tobytes(), self.acceleration.tobytes(), self.jerk.tobytes()))


@runtime_checkable
class Trajectory(Protocol):
    """A joint-space motion from ``start`` to ``goal`` that can be sampled in time.

    ``sample(t)`` takes a float or an array of shape ``(T,)`` and returns
    ``(q, qd, qdd)``: each of shape ``(dof,)`` for a float, ``(T, dof)`` for an
    array. Times before 0 give the start state, times at or after ``duration``
    the goal state, so callers need not guard the ends of the motion.
    """

    @property
    def duration(self) -> float: ...

    @property
    def dof(self) -> int: ...

    @property
    def start(self) -> np.ndarray: ...

    @property
    def goal(self) -> np.ndarray: ...

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


class PointToPoint:
    """What every move from ``start`` to ``goal`` answers the same way (the protocol's endpoints)."""

    _start: np.ndarray
    _goal: np.ndarray

    @property
    def dof(self) -> int:
        return int(self._start.size)

    @property
    def start(self) -> np.ndarray:
        return self._start

    @property
    def goal(self) -> np.ndarray:
        return self._goal
