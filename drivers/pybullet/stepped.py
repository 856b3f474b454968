"""What both simulators share: joints named by their settings, kinds and limits from the URDF,
and a clock that only moves when the physics is stepped."""

from __future__ import annotations

from typing import Any, Sequence

from drivers import ActuatorsBase, JointLimits

__all__ = ["SteppedActuators"]


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
