"""The mechanical load the emulated servos drive.

A :class:`Plant` is anything with joints that accepts shaft torques and
reports shaft angles; the bus emulator steps it in fixed substeps and knows
nothing else about it, so a physics engine (e.g. a PyBullet model of the
robot) can replace :class:`InertiaPlant` without touching the emulator.

Conventions for every plant: joint ``i`` is the output shaft of one servo;
positions in rad (0 = the servo's centre, tick 2048), velocities in rad/s,
torques in N·m, positive counter-clockwise seen from the horn (the servo's
positive direction). Prismatic joints belong behind the transmission: a plant
for a lead-screw or rack stage converts between shaft angle and travel itself.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from drivers.servo.joints import step_joints

__all__ = ["InertiaPlant", "Plant"]


@runtime_checkable
class Plant(Protocol):
    """What the servo-bus emulator needs from a mechanical model."""

    @property
    def joint_count(self) -> int:
        """Number of joints (servo shafts)."""

    def step(self, dt: float, torque: np.ndarray) -> None:
        """Advance ``dt`` seconds with ``torque`` (N·m, shape ``(joint_count,)``) on the shafts."""

    def position(self) -> np.ndarray:
        """Shaft angles (rad), shape ``(joint_count,)``."""

    def velocity(self) -> np.ndarray:
        """Shaft angular velocities (rad/s), shape ``(joint_count,)``."""


def _per_joint(name: str, value: float | np.ndarray, n: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


class InertiaPlant:
    """Independent joints: inertia, viscous and Coulomb friction, constant load torque, stepped by
    the servo core's one integrator (:func:`~drivers.servo.joints.step_joints`) with a diagonal
    mass matrix and the stick-slip law of :mod:`drivers.servo.friction`.

    Per joint: ``J·a = tau + gravity - b·v - c·sign(v)``, with static friction
    holding the joint while ``|tau + gravity| <= c``. ``gravity`` is a constant
    torque (N·m, signed) — enough to make a loaded joint sag and lag behind a
    light one. Optional hard stops (``lower``/``upper``, rad) stop the joint
    dead, which is how a blocked joint is modelled.

    ``inertia`` should include the gearbox-reflected rotor inertia (for
    X-series servos of order 0.005-0.05 kg·m²); much smaller values make the
    servo's explicit 1 ms control loop unstable, as on real hardware with an
    unloaded horn and high gains. Viscous friction is integrated implicitly. A joint at a hard
    stop stops dead.
    """

    def __init__(
        self,
        joint_count: int,
        *,
        inertia: float | np.ndarray = 0.01,
        viscous: float | np.ndarray = 0.0,
        coulomb: float | np.ndarray = 0.0,
        gravity: float | np.ndarray = 0.0,
        position: float | np.ndarray = 0.0,
        velocity: float | np.ndarray = 0.0,
        lower: float | np.ndarray = -np.inf,
        upper: float | np.ndarray = np.inf,
    ) -> None:
        if joint_count < 1:
            raise ValueError(f"joint_count must be >= 1, got {joint_count}")
        n = joint_count
        self._n = n
        self.inertia = np.broadcast_to(np.asarray(inertia, dtype=float), (n,)).copy()
        if np.any(self.inertia <= 0) or not np.all(np.isfinite(self.inertia)):
            raise ValueError(f"inertia must be finite and > 0 kg·m², got {self.inertia}")
        self.viscous = _per_joint("viscous", viscous, n)
        self.coulomb = _per_joint("coulomb", coulomb, n)
        if np.any(self.viscous < 0) or np.any(self.coulomb < 0):
            raise ValueError(
                f"friction must be >= 0, got viscous={self.viscous} coulomb={self.coulomb}"
            )
        self.gravity = _per_joint("gravity", gravity, n)
        self.lower = np.broadcast_to(np.asarray(lower, dtype=float), (n,)).copy()
        self.upper = np.broadcast_to(np.asarray(upper, dtype=float), (n,)).copy()
        if np.any(self.lower > self.upper):
            raise ValueError(f"lower stops {self.lower} above upper stops {self.upper}")
        self._q = np.clip(_per_joint("position", position, n), self.lower, self.upper)
        self._v = _per_joint("velocity", velocity, n)

    @property
    def joint_count(self) -> int:
        return self._n

    def position(self) -> np.ndarray:
        return self._q.copy()

    def velocity(self) -> np.ndarray:
        return self._v.copy()

    def set_state(self, position: np.ndarray | float, velocity: np.ndarray | float = 0.0) -> None:
        """Teleport the joints (test set-up, not physics)."""
        self._q = np.clip(_per_joint("position", position, self._n), self.lower, self.upper)
        self._v = _per_joint("velocity", velocity, self._n)

    def block(self, joint: int, at: float | None = None) -> None:
        """Jam ``joint`` at ``at`` (default: where it is) — a mechanical blockage."""
        where = float(self._q[joint] if at is None else at)
        self.lower[joint] = self.upper[joint] = where
        self._q[joint] = where
        self._v[joint] = 0.0

    def step(self, dt: float, torque: np.ndarray) -> None:
        if dt <= 0:
            raise ValueError(f"dt must be > 0 s, got {dt}")
        torque = np.asarray(torque, dtype=float)
        if torque.shape != (self._n,):
            raise ValueError(f"torque has shape {torque.shape}, expected ({self._n},)")
        self._q, self._v = step_joints(self._q, self._v, dt, torque + self.gravity - self.viscous * self._v,
                                       self.inertia + dt * self.viscous, self.coulomb, "stick",
                                       lower=self.lower, upper=self.upper)
