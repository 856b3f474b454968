"""The needle of many poses at once, and its Jacobian: what every error budget and comparison needs.

Uses a model's vectorised FK where it has one (``needle_vectors``, a DH chain's
``tool_pose`` or ``needle_batch``), checked against ``robot.needle`` on three rows
before it is trusted; otherwise ``robot.needle`` per row. The Jacobian is a central
difference of that exact FK, one batch for all joints.
"""

from __future__ import annotations

from typing import Callable, Iterable

import numpy as np
from numpy.typing import ArrayLike

from bench.kinematics.needle import UnreachableError

__all__ = ["JACOBIAN_STEP", "angle_tilt", "needle_jacobian", "needle_vectors", "wrap_angle"]


JACOBIAN_STEP = 1e-6  #: central-difference step (m or rad)


_CHUNK = 50_000  # rows of one batch FK call: bounds the memory of chain.frames


def _loop_fk(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    poses = [robot.needle(row) for row in q]
    return (np.array([p.entry for p in poses], dtype=float), np.array([p.tip for p in poses], dtype=float),
            np.array([p.direction for p in poses], dtype=float))


def _candidates(robot, q: np.ndarray) -> Iterable[Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Vectorised FKs a model may offer, most direct first; each is checked before use."""
    if callable(getattr(robot, "needle_vectors", None)):
        yield lambda: tuple(np.asarray(a, dtype=float) for a in robot.needle_vectors(q))  # type: ignore[misc]
    chain = getattr(robot, "chain", None)
    if callable(getattr(chain, "tool_pose", None)):
        def via_tool() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            # A DH chain whose tool frame is the needle tip with z along the needle;
            # the entry point sits `depth` back along it, depth affine in q.
            T = chain.tool_pose(q)
            tip, axis = T[:, :3, 3], T[:, :3, 2]
            q0 = q[0]
            d0 = robot.needle(q0).depth
            grad = np.empty(q.shape[1])
            for j in range(q.shape[1]):
                e = np.zeros(q.shape[1])
                e[j] = 1e-3
                grad[j] = (robot.needle(q0 + e).depth - robot.needle(q0 - e).depth) / 2e-3
            depth = d0 + (q - q0) @ grad
            return tip - depth[:, None] * axis, tip, axis

        yield via_tool
    if callable(getattr(robot, "needle_batch", None)):
        def via_batch() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            entry, tip = (np.asarray(a, dtype=float) for a in robot.needle_batch(q)[:2])
            length = np.linalg.norm(tip - entry, axis=1)
            if np.min(length) < 1e-6:
                raise ValueError("needle axis undefined at zero depth")
            return entry, tip, (tip - entry) / length[:, None]

        yield via_batch


def _agrees(robot, q: np.ndarray, out: tuple[np.ndarray, np.ndarray, np.ndarray]) -> bool:
    rows = sorted({0, len(q) // 2, len(q) - 1})
    for i in rows:
        p = robot.needle(q[i])
        for a, b in zip(out, (p.entry, p.tip, p.direction)):
            if a.shape != (len(q), 3) or not np.all(np.abs(a[i] - b) <= 1e-9):
                return False
    return True


def needle_vectors(robot, q: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact FK of a batch (N, n) → entry, tip and unit needle direction, each (N, 3), in m.

    Uses the model's vectorised FK when it has one (``needle_vectors``, a DH
    ``chain.tool_pose`` or ``needle_batch``), after checking three of the
    rows against ``robot.needle``; otherwise calls ``robot.needle`` per row.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.shape[1] != len(robot.joint_names):
        raise ValueError(f"expected {len(robot.joint_names)} joint values per row, got shape {q.shape}")
    if len(q) > _CHUNK:
        parts = [needle_vectors(robot, q[i:i + _CHUNK]) for i in range(0, len(q), _CHUNK)]
        return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))  # type: ignore[return-value]
    for compute in _candidates(robot, q):
        try:
            out = compute()
        except (ValueError, TypeError, IndexError, AttributeError) as e:
            if isinstance(e, UnreachableError):
                raise
            continue
        if _agrees(robot, q, out):
            return out
    return _loop_fk(robot, q)


def angle_tilt(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bench's insertion angle and tilt of unit directions (…, 3), as needle.angles_of."""
    return np.arctan2(d[..., 1], -d[..., 2]), np.arcsin(np.clip(d[..., 0], -1.0, 1.0))


def wrap_angle(a: ArrayLike) -> np.ndarray:
    """Map angles to (−π, π] so differences compare across the atan2 cut."""
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)


def needle_jacobian(robot, q: ArrayLike, step: float = JACOBIAN_STEP) -> dict[str, np.ndarray]:
    """Central-difference Jacobians of tip, entry, direction (3, n), insertion angle and depth (n,)."""
    q = np.asarray(q, dtype=float)
    n = q.size
    h = np.eye(n) * step
    entry, tip, d = needle_vectors(robot, np.concatenate([q + h, q - h]))
    ang, _ = angle_tilt(d)
    depth = np.sum((tip - entry) * d, axis=1)

    def diff(a: np.ndarray) -> np.ndarray:
        return (a[:n] - a[n:]) / (2.0 * step)

    return {"tip": diff(tip).T, "entry": diff(entry).T, "axis": diff(d).T,
            "angle": wrap_angle(ang[:n] - ang[n:]) / (2.0 * step), "depth": diff(depth)}
