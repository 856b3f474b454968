"""The one joint integrator of the servo core: every simulator of a servo moves its joints here.

A geared servo's reflected rotor inertia (the armature) and its back-EMF damping dwarf a small
link, and an explicit step of that damping goes unstable at 1 kHz, so every caller steps

    A Δq̇ = dt · (rhs − f),   A = M(q) + J_a + dt·B,   q' = q + dt·q̇'

semi-implicitly: B (the back-EMF's damping Kt·Ke/R and the viscous friction, through the
transmission) sits in the matrix, ``rhs`` holds everything else but dry friction (the motors'
torques, back-EMF included, −h(q, q̇), −viscous·q̇), and ``f`` is the gearbox's dry friction,
applied by one of :mod:`drivers.servo.friction`'s laws. Only the mass matrix and the bias torques
differ between simulators, and they come from the caller: PyBullet's dynamics (the robot's plant,
A as a Cholesky solve), the pendulum's closed form (the stand), a log's inertia and load (one-joint
identification) or a constant inertia (the bus emulator's default plant), A as its diagonal.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Union

import numpy as np

from drivers.servo.friction import FrictionLaw, implicit_smooth_speed, smooth_friction, stopping_friction

__all__ = ["JointDamping", "JointMatrix", "joint_damping", "step_joints"]

_largest = np.maximum.reduce  # one reduction says whether any joint is past a stop (rows of joints too)

#: A: its diagonal (an array, the matrix being diagonal) or a function solving A x = b.
JointMatrix = Union[np.ndarray, Callable[[np.ndarray], np.ndarray]]


class JointDamping(NamedTuple):
    """A servo's rotor and damping as its joint feels them, through the transmission (kg·m² and
    N·m·s/rad at a revolute joint, kg and N·s/m at a slide)."""

    armature: np.ndarray  #: J_a, the reflected rotor inertia
    back_emf: np.ndarray  #: the back-EMF's damping Kt·Ke/R
    viscous: np.ndarray  #: the gearbox's viscous friction

    def implicit(self, dt: float) -> np.ndarray:
        """What A adds to each joint's inertia for a step of ``dt``: J_a + dt·B."""
        return self.armature + dt * (self.back_emf + self.viscous)


def joint_damping(params, ratio=1.0) -> JointDamping:
    """The servos' (:class:`~drivers.servo.ServoParams`) armature and damping at their joints: each
    divided by ratio² (joint value = ratio × shaft angle)."""
    r2 = np.asarray(ratio, dtype=float) ** 2
    return JointDamping(params.armature / r2, params.back_emf_damping / r2, params.viscous / r2)


def step_joints(q: np.ndarray, qd: np.ndarray, dt: float, rhs: np.ndarray, matrix: JointMatrix,
                dry: np.ndarray | None = None, law: FrictionLaw = "smooth", speed: np.ndarray | None = None,
                lower: np.ndarray | None = None, upper: np.ndarray | None = None,
                shaft_scale: np.ndarray | float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The joints' positions and velocities one step of ``dt`` on (new arrays; the inputs are left
    as they were).

    ``dry``: the dry friction level at each joint (≥ 0; None: none), applied by ``law``:
    ``"smooth"`` over ``speed`` (the shaft's speed the level is smoothed over; q̇ when None), or
    ``"stick"``, the force that stops the joint within the step (A diagonal only), or ``"implicit"``,
    the smooth law at the step's end speed (A diagonal only; ``shaft_scale``: the shaft's speed per
    joint speed). ``lower`` and ``upper``: hard stops, where a joint stops dead."""
    diagonal = isinstance(matrix, np.ndarray)
    qd_new = None
    if dry is not None:
        if law == "implicit":
            if not diagonal:
                raise ValueError("implicit friction needs a diagonal mass matrix")
            qd_new = implicit_smooth_speed(matrix, matrix * qd + dt * rhs, dt * dry, shaft_scale)
        elif law == "smooth":
            rhs = rhs - smooth_friction(dry, qd if speed is None else speed)
        elif law == "stick":
            if not diagonal:
                raise ValueError("stick-slip friction needs a diagonal mass matrix")
            rhs = rhs + stopping_friction(dry, 0.0, qd, matrix / dt * qd + rhs)
        else:
            raise ValueError(f"unknown friction law {law!r}")
    if qd_new is None:
        qd_new = qd + dt * (rhs / matrix if diagonal else matrix(rhs))
    q_new = q + dt * qd_new
    if lower is not None and _largest(np.maximum(lower - q_new, q_new - upper), axis=None) > 0.0:
        stop = (q_new < lower) | (q_new > upper)
        q_new = np.minimum(np.maximum(q_new, lower), upper)
        qd_new = np.where(stop, 0.0, qd_new)
    return q_new, qd_new
