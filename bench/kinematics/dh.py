"""Denavit–Hartenberg chains, vectorised over batches of joint vectors.

One row per joint. By default a row is *standard* DH, the convention of
seed 000 eq 1: ``T = Rz(theta) · Tz(d) · Tx(a) · Rx(alpha)``. A row built with
``convention="modified"`` is modified (Craig) DH, the convention of seed 001
eq 1: ``T = Rx(alpha) · Tx(a) · Rz(theta) · Tz(d)``, where ``a`` and ``alpha``
are the printed ``a_{i-1}`` and ``alpha_{i-1}`` of the row, so a paper's table
is copied row by row. A revolute row adds its joint value to ``theta``, a
prismatic row adds it to ``d``. The same rows feed the URDF writer
(:mod:`bench.scene.urdf_writer`), so the analytic model and the physics
scene cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping, Sequence

import numpy as np

JointKind = Literal["revolute", "prismatic"]
Convention = Literal["standard", "modified"]


@dataclass(frozen=True)
class DHRow:
    """One joint: its DH constants, its kind and its limits (SI units)."""

    name: str
    kind: JointKind
    theta: float  # rad; the offset added to the joint value for a revolute row
    d: float  # m; the offset added to the joint value for a prismatic row
    a: float  # m
    alpha: float  # rad
    lower: float
    upper: float
    home: float
    velocity: float  # rad/s or m/s
    effort: float  # N·m or N
    # "standard": Rz(theta)·Tz(d)·Tx(a)·Rx(alpha); "modified" (Craig):
    # Rx(alpha)·Tx(a)·Rz(theta)·Tz(d) with a, alpha the row's a_{i-1}, alpha_{i-1}.
    convention: Convention = "standard"

    def __post_init__(self) -> None:
        if self.convention not in ("standard", "modified"):
            raise ValueError(f"joint {self.name}: unknown DH convention {self.convention!r}; "
                             "use 'standard' or 'modified'")


def _trig(theta: np.ndarray, d: np.ndarray, alpha: float):
    """d broadcast to theta, the sines and cosines of theta and alpha, and a zero (..., 4, 4)."""
    theta = np.asarray(theta, dtype=float)
    d = np.broadcast_to(np.asarray(d, dtype=float), theta.shape)
    return (d, np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha), np.zeros(theta.shape + (4, 4)))


def dh_transform(theta: np.ndarray, d: np.ndarray, a: float, alpha: float) -> np.ndarray:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` for arrays of theta and d (shape (...,) -> (..., 4, 4))."""
    d, ct, st, ca, sa, T = _trig(theta, d, alpha)
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = st * sa
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -ct * sa
    T[..., 1, 3] = a * st
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


def mdh_transform(theta: np.ndarray, d: np.ndarray, a: float, alpha: float) -> np.ndarray:
    """Modified (Craig) DH ``Rx(alpha) Tx(a) Rz(theta) Tz(d)`` (seed 001 eq 1), shape (..., 4, 4)."""
    d, ct, st, ca, sa, T = _trig(theta, d, alpha)
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st
    T[..., 0, 3] = a
    T[..., 1, 0] = st * ca
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -sa
    T[..., 1, 3] = -d * sa
    T[..., 2, 0] = st * sa
    T[..., 2, 1] = ct * sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d * ca
    T[..., 3, 3] = 1.0
    return T


def row_matrix(row: DHRow, theta: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The row's transform for given theta and d arrays, in the row's own convention."""
    f = mdh_transform if row.convention == "modified" else dh_transform
    return f(theta, d, row.a, row.alpha)


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


class JointRows:
    """Names, limits and home of a robot's joints, read off its ``rows`` (name, lower, upper, home)."""

    rows: tuple

    @property
    def joint_names(self) -> list[str]:
        return [r.name for r in self.rows]

    @property
    def lower(self) -> np.ndarray:
        return np.array([r.lower for r in self.rows])

    @property
    def upper(self) -> np.ndarray:
        return np.array([r.upper for r in self.rows])

    @property
    def home(self) -> np.ndarray:
        return np.array([r.home for r in self.rows])

    def vector_from(self, values: Mapping[str, float], robot: str) -> np.ndarray:
        """Joint dict → vector, missing joints at home; unknown names refused."""
        names = self.joint_names
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise KeyError(f"unknown joint(s) {unknown}; {robot} joints are {names}")
        q = self.home.copy()
        for i, n in enumerate(names):
            if n in values:
                q[i] = float(values[n])
        return q


@dataclass(frozen=True)
class DHChain(JointRows):
    """A serial chain: a fixed base pose, DH rows, and a fixed tool transform."""

    base: np.ndarray  # world <- DH frame 0
    rows: tuple[DHRow, ...]
    tool: np.ndarray  # last DH frame <- tool frame

    def row_transform(self, i: int, q: np.ndarray) -> np.ndarray:
        r = self.rows[i]
        q = np.asarray(q, dtype=float)
        if r.kind == "revolute":
            return row_matrix(r, r.theta + q, np.full(q.shape, r.d))
        return row_matrix(r, np.full(q.shape, r.theta), r.d + q)

    def frames(self, q: np.ndarray) -> np.ndarray:
        """World poses of DH frames 0..n, shape (..., n+1, 4, 4) for q of shape (..., n)."""
        q = np.asarray(q, dtype=float)
        if q.shape[-1] != len(self.rows):
            raise ValueError(f"expected {len(self.rows)} joint values, got {q.shape[-1]}")
        batch = q.shape[:-1]
        out = np.empty(batch + (len(self.rows) + 1, 4, 4))
        T = np.broadcast_to(self.base, batch + (4, 4)).copy()
        out[..., 0, :, :] = T
        for i in range(len(self.rows)):
            T = T @ self.row_transform(i, q[..., i])
            out[..., i + 1, :, :] = T
        return out

    def tool_pose(self, q: np.ndarray) -> np.ndarray:
        """World pose of the tool frame, shape (..., 4, 4)."""
        return self.frames(q)[..., -1, :, :] @ self.tool


def joint_split(row: DHRow) -> tuple[np.ndarray, np.ndarray]:
    """Split a row's transform at q = 0 into (before the motion, after the motion).

    ``T(q) = lead · M(q) · trail`` with ``M`` a rotation about or translation
    along z. Rz and Tz commute, so both kinds share, for a standard row,
    ``lead = Rz(theta)·Tz(d)`` and ``trail = Tx(a)·Rx(alpha)``; a modified row
    moves last, so ``lead`` is its whole transform at q = 0 and ``trail`` is
    the identity. The URDF writer places each joint at ``lead`` and carries
    ``trail`` into the next joint's origin.
    """
    if row.convention == "modified":
        return mdh_transform(np.array(row.theta), np.array(row.d), row.a, row.alpha), np.eye(4)
    lead = dh_transform(np.array(row.theta), np.array(row.d), 0.0, 0.0)
    trail = dh_transform(np.array(0.0), np.array(0.0), row.a, row.alpha)
    return lead, trail


def rpy_from_matrix(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (R = Rz(yaw)·Ry(pitch)·Rx(roll)), exact at gimbal lock."""
    sy = float(np.hypot(R[0, 0], R[1, 0]))
    if sy > 1e-12:
        return (
            float(np.arctan2(R[2, 1], R[2, 2])),
            float(np.arctan2(-R[2, 0], sy)),
            float(np.arctan2(R[1, 0], R[0, 0])),
        )
    if R[2, 0] < 0:  # pitch = +pi/2
        return float(np.arctan2(R[0, 1], R[1, 1])), float(np.pi / 2), 0.0
    return float(np.arctan2(-R[0, 1], R[1, 1])), float(-np.pi / 2), 0.0


def matrix_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def check_rows(rows: Sequence[DHRow]) -> None:
    for r in rows:
        if not r.lower <= r.home <= r.upper:
            raise ValueError(f"joint {r.name}: home {r.home} outside [{r.lower}, {r.upper}]")
