"""Servo and transmission tolerances: deadband, encoder bias, backlash, quantisation, noise.

Seed 000 (section 6) blames its 0.1–3.8 mm deviations on the servos'
±0.29° tolerance, on torque-limited joints lagging, and on play in the
3D-printed linear actuators. Each class here reproduces one of those on any
backend. Per-joint amounts are arrays over *all* joints (zero where the
fault does not apply), in SI units (rad or m).
"""

from __future__ import annotations

import numpy as np

from bench.faults.base import FaultWrapper
from drivers import Actuators, JointState

__all__ = ["Backlash", "Bias", "Deadband", "Noise", "Quantisation"]


def _replace_position(st: JointState, position: np.ndarray, extra_flags: tuple[str, ...] = ()) -> JointState:
    return JointState(st.time, position, st.velocity, st.effort, st.flags + extra_flags)


class Deadband(FaultWrapper):
    """A servo stops anywhere within ±tol of its goal.

    A joint's goal is exact while it moves; when its command stops changing
    (the end of a segment) the servo "settles" at an offset drawn uniformly
    in ±tol, and keeps that offset until its command moves again — a fresh
    draw for every move, as a real servo whose position loop gives up inside
    its deadband, overshooting or undershooting by up to the tolerance.

    The offset is eased in and out at ``slew`` × the joint's velocity limit
    (by the backend's clock), never stepped: a goal that jumps would make
    the simulated motor jerk faster than the real servo can turn.
    """

    def __init__(self, actuators: Actuators, tol: np.ndarray, rng: np.random.Generator,
                 slew: float = 0.1) -> None:
        super().__init__(actuators)
        self.tol = np.asarray(tol, dtype=float)
        self._rng = rng
        self._targets = np.flatnonzero(self.tol > 0)
        self._rate = slew * np.asarray(self.limits.velocity, dtype=float)
        self._goal_offset = np.zeros_like(self.tol)  # where the servo will settle, relative
        self._offset = np.zeros_like(self.tol)  # what is applied now (eased towards the goal)
        self._moving = np.ones(self.tol.shape, dtype=bool)
        self._last: np.ndarray | None = None
        self._t: float | None = None

    @property
    def offset(self) -> np.ndarray:
        """The settling offsets drawn for the present holds (rad or m), zero while moving."""
        return self._goal_offset.copy()

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        position = np.asarray(position, dtype=float)
        last = position if self._last is None else self._last
        t = self._targets
        changed = np.abs(position[t] - last[t]) > 1e-12
        settling = t[~changed & self._moving[t]]
        self._moving[t[changed]] = True
        self._goal_offset[t[changed]] = 0.0
        for j in settling:  # one draw per joint that just stopped, in joint order
            self._moving[j] = False
            self._goal_offset[j] = self._rng.uniform(-self.tol[j], self.tol[j])
        now = self.now()
        step = self._rate * (0.0 if self._t is None else max(0.0, now - self._t))
        self._offset += np.clip(self._goal_offset - self._offset, -step, step)
        self._t = now
        self._last = position.copy()
        self.actuators.command(position + self._offset, velocity)


class Bias(FaultWrapper):
    """An encoder offset: reads are ``truth + bias``, so a servo closing its loop
    on them stops at ``goal − bias`` in truth while reading the goal."""

    def __init__(self, actuators: Actuators, bias: np.ndarray) -> None:
        super().__init__(actuators)
        self.bias = np.asarray(bias, dtype=float)

    def read(self) -> JointState:
        st = self.actuators.read()
        return _replace_position(st, st.position + self.bias)

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        self.actuators.command(np.asarray(position, dtype=float) - self.bias, velocity)


class Backlash(FaultWrapper):
    """Play between a motor and its output: the play in the 3D-printed racks of the linear
    actuators (seed 000, section 6), the bench's one law of it.

    The output stays within ``[motor, motor + play]``: driven forward, it
    follows the motor exactly; after a reversal the motor travels ``play``
    before it pulls the output, which from then on trails by ``play``. The
    encoder sits on the motor, so reads show the motor (``output − gap``):
    the servo holds its goal while the slide sits up to ``play`` off it, which
    the backend's truth (a simulator's joints, an emulated rig's plant, what
    the cameras see) shows and the readings never do.
    ``engaged`` says which face of the gap the output rests on at the start:
    ``+1`` (a forward move drives it at once), ``-1`` (a backward one does).
    """

    def __init__(self, actuators: Actuators, play: np.ndarray, engaged: np.ndarray) -> None:
        super().__init__(actuators)
        self.play = np.asarray(play, dtype=float)
        self._targets = self.play > 0
        self._start_gap = np.where(np.asarray(engaged) < 0, self.play, 0.0)
        self._output: np.ndarray | None = None  # goal sent to the output side
        self._gap = self._start_gap.copy()  # output − motor, in [0, play]

    @property
    def gap(self) -> np.ndarray:
        """Output minus motor position for every joint (m or rad)."""
        return self._gap.copy()

    def _start(self, truth: np.ndarray) -> None:
        self._output = np.asarray(truth, dtype=float).copy()

    def read(self) -> JointState:
        st = self.actuators.read()
        if self._output is None:
            self._start(st.position)
        return _replace_position(st, st.position - self._gap)

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        motor = np.asarray(position, dtype=float)
        if self._output is None:
            self._start(self.actuators.read().position)
        out = np.where(self._targets, np.clip(self._output, motor, motor + self.play), motor)
        moved = ~self._targets | (np.abs(out - self._output) > 0)
        self._output = out
        self._gap = out - motor
        if velocity is not None:
            velocity = np.where(moved, velocity, 0.0)
        self.actuators.command(out, velocity)


class Quantisation(FaultWrapper):
    """Goal and present position registers in whole ticks (e.g. 4096 a revolution)."""

    def __init__(self, actuators: Actuators, step: np.ndarray) -> None:
        super().__init__(actuators)
        self.step = np.asarray(step, dtype=float)
        self._targets = self.step > 0
        self._safe = np.where(self._targets, self.step, 1.0)

    def _round(self, q: np.ndarray) -> np.ndarray:
        return np.where(self._targets, np.round(q / self._safe) * self._safe, q)

    def read(self) -> JointState:
        st = self.actuators.read()
        return _replace_position(st, self._round(st.position))

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        self.actuators.command(self._round(np.asarray(position, dtype=float)), velocity)


class Noise(FaultWrapper):
    """Gaussian measurement noise on the read positions (std per joint)."""

    def __init__(self, actuators: Actuators, std: np.ndarray, rng: np.random.Generator) -> None:
        super().__init__(actuators)
        self.std = np.asarray(std, dtype=float)
        self._targets = np.flatnonzero(self.std > 0)
        self._rng = rng

    def read(self) -> JointState:
        st = self.actuators.read()
        q = st.position.copy()
        q[self._targets] += self._rng.standard_normal(self._targets.size) * self.std[self._targets]
        return _replace_position(st, q)
