"""What both simulators share: joints named by their settings, kinds and limits from the URDF,
and a clock that only moves when the physics is stepped."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from drivers import ActuatorsBase, JointLimits

__all__ = ["SteppedActuators", "block_commands"]


def block_commands(position: np.ndarray, velocity: np.ndarray, ends: np.ndarray,
                   limits: JointLimits) -> tuple[np.ndarray, np.ndarray]:
    """A block's commands checked whole before anything moves (a row per cycle, every joint,
    finite positions), clipped to the joints' limits: (positions, velocities)."""
    position = np.asarray(position, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    k, n = len(ends), len(limits.lower)
    if position.shape != (k, n) or velocity.shape != (k, n):
        raise ValueError(f"a block of {k} cycles needs ({k}, {n}) positions and velocities, "
                         f"got {position.shape} and {velocity.shape}")
    if not np.isfinite(position).all():
        raise ValueError(f"command position is not finite in row "
                         f"{int(np.flatnonzero(~np.isfinite(position).all(axis=1))[0])}")
    return (np.minimum(np.maximum(position, limits.lower), limits.upper),
            np.minimum(np.maximum(velocity, -limits.velocity), limits.velocity))


class SteppedActuators(ActuatorsBase):
    """Base of the PyBullet backends: subclasses set ``settings``, ``_kinds``, ``_limits``,
    ``_dt`` and count ``_step_count``."""

    settings: Any
    _kinds: list[str]
    _limits: JointLimits
    _dt: float
    _step_count: int = 0

    @property
    def joint_names(self) -> Sequence[str]:
        return list(self.settings.joint_names)

    @property
    def joint_kinds(self) -> list[str]:
        return list(self._kinds)

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def now(self) -> float:
        return self._step_count * self._dt
