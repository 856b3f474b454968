"""Every friction law of the servo core, written once: the gearbox's dry friction level (Coulomb,
the Stribeck curve with its exponent, the load-dependent gear friction of BAM's m3–m6) and the
three ways an integrator applies a dry level, by name:

- ``"smooth"``: ``level·tanh(ω/ω_ε)``, what a stiff integrator over a full mass matrix applies
  (the robot's plant, identification's rollout);
- ``"stick"``: the exact stick-slip force that stops the joint within a step and never exceeds the
  level, for a diagonal mass matrix (the stand's pendulum, BAM's simulator, the bus's inertias);
- ``"implicit"``: the smooth law at the speed the step ends with (backward Euler through zero
  speed, :func:`implicit_smooth_speed`), for a diagonal mass matrix stepped far coarser than the
  firmware (the twin's 10 ms), where the smooth law taken at the step's start would chatter.

Viscous friction is linear and sits in the integrator's implicit damping, not here. Nothing
outside this module evaluates a friction law (``tests/test_servo_core.py`` scans for one).
"""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np

__all__ = ["FRICTION_SMOOTHING_RAD_S", "FrictionParams", "FrictionLaw", "friction_level", "friction_torque",
           "implicit_smooth_speed", "regressors", "smooth_friction", "stopping_friction", "stribeck_fade"]

#: Velocity below which Coulomb friction is smoothed (rad/s): tanh(ω/ω_ε), as the plant integrates it.
FRICTION_SMOOTHING_RAD_S = 1e-3

#: How an integrator applies a dry friction level (see the module's docstring).
FrictionLaw = Literal["smooth", "stick", "implicit"]
#: Newton steps of :func:`implicit_smooth_speed`: each brings the smoothed speed within a fraction
#: of ω_ε, far below what moves a joint an encoder tick in a step.
IMPLICIT_NEWTON_STEPS = 3


class FrictionParams(Protocol):
    """What the laws read of the servo parameters (:class:`~drivers.servo.model.ServoParams`), per joint."""

    coulomb: np.ndarray
    viscous: np.ndarray
    stribeck: np.ndarray
    stribeck_velocity: np.ndarray
    stribeck_alpha: np.ndarray
    load_motor: np.ndarray
    load_external: np.ndarray
    load_stribeck_motor: np.ndarray
    load_stribeck_external: np.ndarray
    load_quad_motor: np.ndarray
    load_quad_external: np.ndarray
    #: which terms any joint has: Stribeck peak, load, load at rest, quadratic (worked out once)
    _friction_terms: tuple[bool, bool, bool, bool]
    #: the Stribeck exponents, 2.0 where all are 2 (worked out once)
    _stribeck_alpha: float | np.ndarray


def friction_level(params: FrictionParams, omega: np.ndarray, motor_torque=0.0,
                   external_torque=0.0) -> np.ndarray:
    """The gearbox's dry friction (N·m, ≥ 0, viscous apart) at output speed ``omega`` (rad/s) while
    the motor gives ``motor_torque`` and the load ``external_torque`` (N·m at the shaft): Coulomb
    with a Stribeck peak, plus the load-dependent terms (BAM's m3–m6 laws)."""
    peak, load, load_rest, quadratic = params._friction_terms
    level = params.coulomb
    fade = None
    if peak or load_rest or quadratic:
        fade = stribeck_fade(omega, params.stribeck_velocity, params._stribeck_alpha)
    if peak:
        level = np.where(params.stribeck > 0.0, params.coulomb + (params.stribeck - params.coulomb) * fade,
                         params.coulomb)
    tm, te = motor_torque, external_torque
    if load:
        level = level + np.abs(params.load_external * te - params.load_motor * tm)
    if load_rest:
        level = level + fade * np.abs(params.load_stribeck_external * te - params.load_stribeck_motor * tm)
    if quadratic:  # BAM m6: the driven side's torque squared, at rest, when motor and load oppose each other
        opposed = np.sign(te) != np.sign(tm)
        quad = (np.where(np.abs(te) < np.abs(tm), params.load_quad_external * te ** 2, 0.0)
                + np.where(np.abs(te) > np.abs(tm), params.load_quad_motor * tm ** 2, 0.0))
        level = level + fade * quad * opposed
    if level is params.coulomb:  # never hand out the parameters' own array
        level = level.copy()
    return level * np.ones_like(omega) if np.ndim(level) < np.ndim(omega) else level


def stribeck_fade(omega, stribeck_velocity, alpha=2.0) -> np.ndarray:
    """The Stribeck curve e^{-|ω/ω_s|^α}: 1 at rest, fading to 0 past ω_s (α = 2 unless set)."""
    ratio = omega / np.maximum(stribeck_velocity, 1e-9)
    if (alpha == 2.0 if isinstance(alpha, float) else np.all(np.asarray(alpha) == 2.0)):
        return np.exp(-(ratio * ratio))
    return np.exp(-np.abs(ratio) ** alpha)


def regressors(omega: np.ndarray, stribeck_velocity: float) -> tuple[np.ndarray, np.ndarray]:
    """The dry laws as a linear regression's columns at shaft speeds ``omega`` (moving rows only):
    Coulomb's (the direction of motion, per N·m of level) and the Stribeck peak's over it (that
    direction times the fade, per N·m of peak above Coulomb)."""
    direction = np.sign(omega)
    return direction, direction * stribeck_fade(np.abs(omega), stribeck_velocity)


def friction_torque(params: FrictionParams, omega: np.ndarray, motor_torque=0.0,
                    external_torque=0.0) -> np.ndarray:
    """Gearbox friction at output speed ``omega`` (rad/s), smoothed through zero speed, plus viscous
    (the loads as :func:`friction_level`): what a stiff integrator applies."""
    level = friction_level(params, omega, motor_torque, external_torque)
    return smooth_friction(level, omega) + params.viscous * omega


def smooth_friction(level, omega: np.ndarray) -> np.ndarray:
    """A dry friction ``level`` (N·m) smoothed through zero shaft speed ``omega`` (rad/s): the
    ``"smooth"`` law."""
    return level * np.tanh(omega / FRICTION_SMOOTHING_RAD_S)


def stopping_friction(level: np.ndarray, viscous: np.ndarray, omega: np.ndarray,
                      tau_stop: np.ndarray) -> np.ndarray:
    """The friction torque (N·m) a step applies: it opposes ``tau_stop``, the torque that would stop the
    shaft within the step, and never exceeds it nor the friction budget ``level + viscous·|ω|``.
    A shaft held by friction stays put (stick) instead of chattering through zero speed."""
    budget = level + viscous * np.abs(omega)
    return -np.sign(tau_stop) * np.minimum(np.abs(tau_stop), budget)


def implicit_smooth_speed(inertia: np.ndarray, momentum: np.ndarray, level: np.ndarray,
                          scale: np.ndarray) -> np.ndarray:
    """The joint speeds ``v`` that solve ``inertia·v + level·tanh(scale·v / ω_ε) = momentum``, per
    joint: the ``"implicit"`` law's step (``momentum`` = A·q̇ + dt·rhs, ``level`` = dt × the dry
    level at the joint, ``scale`` the shaft's speed per joint speed, |1/ratio|).

    The left side grows with ``v``, so there is one root; in ``s = scale·v/ω_ε`` it is concave for
    s > 0, and Newton's steps from a point right of the root (the root without friction, or the
    creep speed where the inertia is negligible) land left of it and climb to it without passing it."""
    k = scale / FRICTION_SMOOTHING_RAD_S
    a = inertia / k
    b = np.abs(momentum)
    e = np.maximum(level, 1e-300)
    s = b / a
    creep = b < e
    if creep.any():  # held by friction: no faster than the smoothed law's own creep
        s = np.where(creep, np.minimum(s, np.arctanh(np.minimum(b / e, 1.0 - 1e-12))), s)
    for _ in range(IMPLICIT_NEWTON_STEPS):
        t = np.tanh(s)
        s = s - (a * s + e * t - b) / (a + e * (1.0 - t * t))
    return np.copysign(s, momentum) / k
