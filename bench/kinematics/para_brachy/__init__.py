"""Kinematics of the 5-DOF parallel needle-placement robot of seed 003.

Gherman, Pisla, Vaida, Plitea, "On workspace and accuracy evaluation of a
parallel robot for needle placement procedures" (Proc. Romanian Academy A,
2015): a CYL-U module (two sliders q1, q2 on a column parallel to OZ and a
rotation q3 about it) and a second module (q4 along OZ carrying q5 along OY)
hold the needle at two universal joints C1 and C2.

Frame and pose
--------------
Robot base frame, OZ up (away from the patient on the CT bed). A pose is the
5-vector ``[X_E, Y_E, Z_E, psi, theta]`` (m, m, m, rad, rad): E is the needle
tip, theta the angle between the needle and OZ, psi the azimuth of its
horizontal projection. The insertion direction (from C1 towards the tip) is
``w = (sin θ cos ψ, sin θ sin ψ, −cos θ)``, so θ = 0 is a needle pointing
straight down. Joints ``q = [q1, q2, q3, q4, q5]`` (m, m, rad, m, m).

The mechanism, as eqs 1–5 describe it
--------------------------------------
* C1 = E − (h + lc)·w and C2 = E − h·w lie on the needle (eq 4), lc apart.
* CYL-U: the column (q3 axis) is the vertical line X = dx, Y = l3. A1 sits at
  height q1 (eq 3) and radius r_A = b + √(d² − (q2 − q1)²) from the column,
  at polar angle π − q3 seen from the column (eq 3); C1 hangs l1 below A1
  (eq 1: q1 = Z_C1 + l1).
* Second module: G = (e, q5, q4) slides along OY at X = e; the link c joins G
  to A2 in the horizontal plane (eq 2) and C2 stands l2 above A2
  (eq 1: q4 = Z_C2 − l2).

Repairs to the paper (it is inconsistent in places)
----------------------------------------------------
1. Eq 7's f2 and f3 carry ``+(h + lc) sin θ cos ψ`` and
   ``(b − √(d² − (q2 − q1)²))``, which contradict eqs 1, 3, 4
   (C1 = E − (h+lc)·w, r_A − b = +√…) and eq 8 (whose factor
   (√… + b)/√…·(q2 − q1) is r_A·∂r_A/∂q1 for r_A = b + √…, not for b − √…).
   F below is eq 7 rewritten with the signs of eqs 1–5; its det B is eq 8
   up to the overall sign.
2. Eqs 1–3 have no e and no l3 while eq 7 has both. Here e is the X of the q5
   guide and l3 the Y of the column; e = l3 = 0 gives eqs 1–3 exactly.
3. Eq 1 takes one branch of each square root. They are kept as the default
   *working mode* (+1, +1): q2 above q1, and G at lower Y than A2
   (q5 = Y_C2 − √(c² − (X_C2 − e)²)). The other branches are available.
4. The paper's geometric parameter values are not printed; the defaults of
   :class:`ParaBrachyParams` are chosen for a CT-bed workspace (see there).
5. Eqs 9–10 and the text of type-1 cases 2–4 and type-2 case 5 are missing
   from the source; they are rebuilt from det A and det B as derived here
   (see :class:`SingularityCase`).

The package, by section of the paper: :mod:`.model` (parameters, eq 4),
:mod:`.geometric` (IGM eq 1, DGM eqs 2–5), :mod:`.jacobians` (eqs 6–8),
:mod:`.singularities` (section 3), :mod:`.workspace` (the map),
:mod:`.sweep` (section 4, eqs 12–14) and :mod:`.robot` (the common
needle-robot interface).
"""

from __future__ import annotations

from bench.kinematics.batch import wrap_angle
from bench.kinematics.needle import UnreachableError
from bench.kinematics.para_brachy.geometric import (
    IGM_FAILURES,
    closest_pose,
    dgm,
    dgm_closest,
    igm,
    working_mode,
)
from bench.kinematics.para_brachy.jacobians import (
    constraint,
    det_A,
    det_B,
    inverse_condition,
    jacobian_A,
    jacobian_B,
)
from bench.kinematics.para_brachy.model import (
    DEFAULT_PARAMS,
    DEG,
    JOINT_NAMES,
    POSE_NAMES,
    WORKSPACE_CENTRE,
    ParaBrachyParams,
    insertion_direction,
    needle_points,
)
from bench.kinematics.para_brachy.robot import ParaBrachyRobot
from bench.kinematics.para_brachy.singularities import (
    SingularityCase,
    architecture_violations,
    classify_singularity,
    singular_configuration,
    singularity_factors,
)
from bench.kinematics.para_brachy.sweep import PerturbationSweep, perturbation_sweep
from bench.kinematics.para_brachy.workspace import WorkspaceGrid, WorkspaceMap, save_workspace, workspace_map

__all__ = [
    "DEG",
    "JOINT_NAMES",
    "POSE_NAMES",
    "UnreachableError",
    "IGM_FAILURES",
    "ParaBrachyParams",
    "DEFAULT_PARAMS",
    "WORKSPACE_CENTRE",
    "insertion_direction",
    "igm",
    "dgm",
    "closest_pose",
    "dgm_closest",
    "working_mode",
    "needle_points",
    "constraint",
    "jacobian_A",
    "jacobian_B",
    "det_A",
    "det_B",
    "inverse_condition",
    "SingularityCase",
    "singularity_factors",
    "classify_singularity",
    "singular_configuration",
    "architecture_violations",
    "WorkspaceGrid",
    "WorkspaceMap",
    "workspace_map",
    "save_workspace",
    "PerturbationSweep",
    "perturbation_sweep",
    "wrap_angle",
    "ParaBrachyRobot",
]
