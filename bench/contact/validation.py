"""Check the contact test against PyBullet on poses that matter.

Random joint vectors within limits mostly keep a robot far from the gantry,
where any detector is right. :func:`interesting_poses` draws many and keeps a
stratified sample by the per-cycle clearance: a share in contact, a large
share within a few centimetres of the margin, and the rest anywhere.
:class:`PyBulletDistances` measures the same poses with PyBullet's
``getClosestPoints`` against the gantry's concave mesh (``concave="yes"``).

PyBullet pads convex shapes with a 1 mm collision margin (box corners come
out rounded, up to 0.73 mm farther; a URDF cylinder becomes a 1 mm-padded
convex hull unless loaded as an implicit cylinder), so its distances differ
from the exact mesh distance by up to ~0.75 mm with implicit cylinders; a
verdict comparison therefore leaves out poses within 1 mm of the margin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.scene.contact import GantryClearance
from drivers.quiet import muted_output, quiet_pybullet

__all__ = ["interesting_poses", "PyBulletDistances"]


def interesting_poses(model, clearance: GantryClearance, n: int, rng: np.random.Generator,
                      contact_share: float = 0.2, near_share: float = 0.5,
                      near_band: float = 0.03, pool: int = 20) -> np.ndarray:
    """``n`` joint vectors: ``contact_share`` with the clearance bound below 0,
    ``near_share`` within ``near_band`` of the margin, the rest uniform."""
    if not 0 <= contact_share + near_share <= 1:
        raise ValueError(f"shares must sum to at most 1, got {contact_share} + {near_share}")
    lo, hi = model.chain.lower, model.chain.upper
    Q = rng.uniform(lo, hi, (pool * n, len(lo)))
    d = clearance.distances_batch(Q).min(axis=1)
    m = clearance.margin
    groups = [np.flatnonzero(d < 0.0),
              np.flatnonzero((d >= m - near_band) & (d <= m + near_band)),
              np.arange(len(Q))]
    want = [int(round(contact_share * n)), int(round(near_share * n))]
    want.append(n - sum(want))
    picked: list[np.ndarray] = []
    for idx, k in zip(groups, want):
        idx = np.setdiff1d(idx, np.concatenate(picked) if picked else [])
        if len(idx) < k:
            raise ValueError(f"only {len(idx)} of {pool * n} random poses fall in a stratum that "
                             f"needs {k}; raise pool")
        picked.append(rng.choice(idx, size=k, replace=False))
    out = Q[np.concatenate(picked)]
    return out[rng.permutation(len(out))]


@dataclass
class PyBulletDistances:
    """A headless PyBullet world with the robot and the gantry mesh, for distance queries."""

    robot_urdf: Path
    gantry_urdf: Path

    def __post_init__(self) -> None:

        pb = quiet_pybullet()
        self._pb = pb
        with muted_output():
            self.client = pb.connect(pb.DIRECT)
        c = self.client
        self.robot = pb.loadURDF(str(self.robot_urdf), useFixedBase=True,
                                 flags=pb.URDF_USE_IMPLICIT_CYLINDER, physicsClientId=c)
        self.gantry = pb.loadURDF(str(self.gantry_urdf), useFixedBase=True, physicsClientId=c)
        self.n_joints = pb.getNumJoints(self.robot, physicsClientId=c)

    def min_distance(self, q: np.ndarray, max_distance: float = 0.1) -> float:
        """Smallest robot–gantry distance (m; negative in penetration, inf beyond max_distance)."""
        pb, c = self._pb, self.client
        for j, v in enumerate(q):
            pb.resetJointState(self.robot, j, float(v), physicsClientId=c)
        pts = pb.getClosestPoints(self.robot, self.gantry, max_distance, physicsClientId=c)
        return min((p[8] for p in pts), default=np.inf)

    def close(self) -> None:
        try:
            self._pb.disconnect(self.client)
        except Exception:  # already disconnected
            pass

    def __enter__(self) -> "PyBulletDistances":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
