"""How far the needle goes wrong when the joints are off by their tolerances.

Three views of one question, for any robot model with the bench's interface
(``chain.rows`` with name, kind, lower, upper, home; ``joint_names``;
``needle(q) -> NeedlePose``; ``ik(NeedleTarget) -> q``):

* :func:`perturbation_sweep` — seed 003's accuracy study (eqs 12–14): sweep
  one joint, step every joint by ε (0.05 mm or 0.05°) at each sweep point and
  record how far the needle tip moves (eq 12) and how its orientation turns
  (ψ, eq 13; θ, eq 14; and the total angle between the needle axes). For the
  parallel robot the implementation in :mod:`bench.kinematics.para_brachy` is
  used and its output converted.
* :func:`jacobian_budget` — first order: the numerical Jacobian (central
  differences) of the tip, entry point and needle axis, times each joint's
  tolerance: per-joint contributions, the worst case (Σ |J_i|·tol_i), the RSS
  (1σ) and each joint's share of the variance.
* :func:`monte_carlo_budget` — exact: joint errors sampled and pushed through
  the forward kinematics; the tip, entry, depth and angle error distributions
  and each joint's share of the variance.

Units: SI inside (m, rad); results carry mm and degrees in their names.

Orientation: ``θ`` is the needle's angle from the downward vertical and ``ψ``
the azimuth of its horizontal projection (seed 003's pose angles, defined
for every robot from the needle direction). The *axis error* is the angle
between the perturbed and the nominal needle axis (always ≥ 0). The
*insertion angle* and *tilt* are the bench's (README): the angle in the
axial plane measured from −Z towards +Y, and the lean out of that plane;
Table 3's "angle of insertion" is the former.

Joint-error models (``distribution``), all zero-mean and independent per
joint:

* ``"uniform"`` — uniform on ±tol: the servo deadband model (a Dynamixel
  servo settles anywhere within its ±0.29° band); σ = tol/√3.
* ``"normal"`` — normal with the *same variance* as the uniform model
  (σ = tol/√3), so the two differ only in their tails.
* ``"endpoints"`` — ±tol with random sign: every servo over- or undershoots
  by the full tolerance, the wording of seed 000 section 6; σ = tol.

Variance shares: a joint's share of the tip error is its part of the total
tip variance (the trace of the 3×3 covariance, i.e. the mean squared 3-D
error); of the axis error, its part of the needle direction's variance.
:func:`jacobian_budget` takes ``(|J_i| σ_i)² / Σ_j (|J_j| σ_j)²``.
:func:`monte_carlo_budget` perturbs one joint at a time with the same
samples and takes ``V_i / Σ_j V_j`` (so the shares sum to 1); ``additivity``
``= Σ_j V_j / V_total`` says how well single-joint variances add up (1 for a
linear map and independent errors). A joint with zero tolerance has share 0.

Servo tolerances (seed 000 section 6: the Dynamixel servos hold position to
±0.29°). Every joint of the arc-and-train robot is servo-driven, the train's
arc angle too. Through the transmission a servo error of ±δ becomes:

* revolute joints (direct drive): ±δ;
* prismatic joints: rack and pinion with a 10 mm pinion radius
  (:data:`PINION_RADIUS`): ±δ·10 mm, so ±0.29° → ±0.0506 mm;
* the train: the same 10 mm pinion on the arc's rack of radius R = 200 mm:
  ±δ·10/200 of arc angle, so ±0.29° → ±0.0145°.

Other robots: revolute joints direct drive, prismatic joints the same rack
and pinion (for the parallel robot this gives ±0.0506 mm on its sliders,
close to the paper's ε = 0.05 mm). Every tolerance can be set per joint.

Default poses (:func:`default_pose`): the arc-and-train robot at Target 1
(the IK of :data:`bench.kinematics.arc_train.TARGET_1`: Y 88.2 mm, Z 66 mm,
30.1 mm deep at 47°, where Table 3 was measured); the parallel robot at its
workspace centre (its adapter's home, in its own base frame); every other
robot (they share the bed frame) at the same Target 1 by its own IK, so the
budgets of different robots compare at one clinical target — Zerobot
reaches it with q4 = 47° and q6 = 30.1 mm — or at its home if it cannot
reach it.

The study lives in :mod:`.poses` (robots, poses, tolerances), :mod:`.sweep` (eqs 12–14)
and :mod:`.budget` (Jacobian and Monte-Carlo budgets); this module gathers them.
"""

from __future__ import annotations

from bench.accuracy.budget import (
    ErrorStats,
    JacobianBudget,
    MonteCarloBudget,
    jacobian_budget,
    monte_carlo_budget,
    table3_summary,
)
from bench.accuracy.poses import (
    DISTRIBUTIONS,
    PAPER_EPS_ANGULAR,
    PAPER_EPS_LINEAR,
    Distribution,
    Tolerances,
    default_pose,
    default_tolerances,
    pose_from_joints,
    resolve_tolerances,
    robot_label,
)
from bench.accuracy.sweep import Sweep, default_sweep, perturbation_sweep
from bench.kinematics.arc_train import PINION_RADIUS, SERVO_TOL_DEG, TABLE3_MEASURED, TABLE3_TARGET
from bench.kinematics.transmission import servo_transmissions

__all__ = [
    "DISTRIBUTIONS",
    "Distribution",
    "Tolerances",
    "PAPER_EPS_LINEAR",
    "PAPER_EPS_ANGULAR",
    "PINION_RADIUS",
    "SERVO_TOL_DEG",
    "TABLE3_MEASURED",
    "TABLE3_TARGET",
    "ErrorStats",
    "JacobianBudget",
    "MonteCarloBudget",
    "Sweep",
    "default_pose",
    "default_sweep",
    "default_tolerances",
    "jacobian_budget",
    "monte_carlo_budget",
    "perturbation_sweep",
    "pose_from_joints",
    "resolve_tolerances",
    "robot_label",
    "servo_transmissions",
    "table3_summary",
]
