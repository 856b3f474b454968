"""The seed-003 parallel robot behind the bench's common robot interface.

The rest of :mod:`bench.kinematics.para_brachy` speaks the paper's language (poses
``[X_E, Y_E, Z_E, ψ, θ]``, two assembly modes, strokes). Code that studies
every robot alike (the accuracy budget, the CLI) wants what the serial models
offer: ``chain.rows`` with (name, kind, lower, upper, home), ``joint_names``,
``needle(q) -> NeedlePose`` and ``ik(NeedleTarget) -> q``. This adapter gives
that and nothing else; the kinematics stay in the package's other modules.

Choices the common interface forces:

* Frame: the robot base frame of the paper (OZ up), not the bed frame.
* Home: the IGM of :data:`~bench.kinematics.para_brachy.WORKSPACE_CENTRE`.
* Assembly mode: the DGM has two solutions; solution 0 always puts A2 on the
  left of A1'→G', so one index names one assembly mode everywhere off the
  type-2 case-6 singularity. The adapter keeps the index the home pose is in.
* The robot has no insertion joint: the needle's free length below the lower
  universal joint C2 is the fixed ``h``. ``NeedlePose.entry`` is C2 and
  ``depth`` is ``h``, so ``tip = entry + depth·direction`` still holds;
  :meth:`ParaBrachyRobot.ik` uses the target's tip and direction only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.batch import wrap_angle
from bench.kinematics.dh import JointKind, JointRows
from bench.kinematics.needle import NeedlePose, NeedleTarget, UnreachableError, angles_of
from bench.kinematics.para_brachy.geometric import dgm, igm
from bench.kinematics.para_brachy.model import (
    DEFAULT_PARAMS,
    JOINT_NAMES,
    WORKSPACE_CENTRE,
    ParaBrachyParams,
    insertion_direction,
)

__all__ = ["JointRow", "JointTable", "ParaBrachyRobot"]


@dataclass(frozen=True)
class JointRow:
    """One actuated joint: its kind and stroke (SI units)."""

    name: str
    kind: JointKind
    lower: float
    upper: float
    home: float


@dataclass(frozen=True)
class JointTable(JointRows):
    """The part of a serial chain's interface a parallel robot can honestly offer."""

    rows: tuple[JointRow, ...]


class ParaBrachyRobot:
    """The 5-DOF parallel needle robot with the serial robots' interface."""

    name = "para-brachy"

    def __init__(self, params: ParaBrachyParams = DEFAULT_PARAMS,
                 home_pose: ArrayLike = WORKSPACE_CENTRE) -> None:
        self.params = params
        self.home_pose = np.asarray(home_pose, dtype=float)
        home = igm(self.home_pose, params)
        sols = dgm(home, params)
        dist = np.linalg.norm(sols[:, :3] - self.home_pose[:3], axis=-1) + np.abs(
            wrap_angle(sols[:, 3] - self.home_pose[3]))
        self.assembly = int(np.argmin(dist))
        kinds: tuple[JointKind, ...] = ("prismatic", "prismatic", "revolute", "prismatic", "prismatic")
        self.chain = JointTable(tuple(
            JointRow(n, k, float(lo), float(hi), float(h))
            for n, k, lo, hi, h in zip(JOINT_NAMES, kinds, params.q_min, params.q_max, home)))

    @property
    def joint_names(self) -> list[str]:
        return list(JOINT_NAMES)

    def joint_vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Joint dict → vector, missing joints at home; unknown names refused."""
        return self.chain.vector_from(values, "para-brachy")

    def pose(self, q: ArrayLike) -> np.ndarray:
        """The paper's pose ``[X_E, Y_E, Z_E, ψ, θ]`` (…, 5) in this robot's assembly mode."""
        return dgm(q, self.params)[..., self.assembly, :]

    def needle_vectors(self, q: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Batch FK: (entry = C2, tip, direction), each (…, 3), for q of shape (…, 5)."""
        x = self.pose(q)
        w = insertion_direction(x[..., 3], x[..., 4])
        tip = x[..., :3]
        return tip - self.params.h * w, tip, w

    def needle(self, q: ArrayLike) -> NeedlePose:
        """Forward kinematics of one configuration to the needle."""
        q = np.asarray(q, dtype=float)
        if q.shape != (5,):
            raise ValueError(f"expected 5 joint values (q1..q5), got shape {q.shape}")
        entry, tip, w = self.needle_vectors(q)
        angle, tilt = angles_of(w)
        return NeedlePose(entry=entry, tip=tip, direction=w, angle=angle, depth=self.params.h,
                          out_of_plane=tilt)

    def ik(self, target: NeedleTarget) -> np.ndarray:
        """Joint values putting the tip on ``target.tip`` along its direction (eq 1)."""
        w = np.asarray(target.direction, dtype=float)
        w = w / np.linalg.norm(w)
        theta = float(np.arccos(np.clip(-w[2], -1.0, 1.0)))
        psi = float(np.arctan2(w[1], w[0]))
        pose = np.array([*target.tip, psi, theta])
        q = igm(pose, self.params)
        back = self.needle(q)
        if np.max(np.abs(back.tip - target.tip)) > 1e-9 or np.linalg.norm(back.direction - w) > 1e-9:
            raise UnreachableError(
                f"pose {np.array2string(pose, precision=6)} is reached only in the other assembly "
                f"mode (DGM solution {1 - self.assembly}); this robot works in solution {self.assembly}")
        return q
