"""Small triangle-mesh utilities: enclosing radii and refinement by longest-edge bisection."""

from __future__ import annotations

import numpy as np

__all__ = ["enclosing_radius", "refine"]


def enclosing_radius(tris: np.ndarray) -> np.ndarray:
    """Radius of the smallest ball containing each triangle (n, 3, 3) -> (n,).

    For an obtuse (or right) triangle that is half its longest edge; for an
    acute one, its circumradius.
    """
    a = np.linalg.norm(tris[:, 1] - tris[:, 2], axis=1)
    b = np.linalg.norm(tris[:, 2] - tris[:, 0], axis=1)
    c = np.linalg.norm(tris[:, 0] - tris[:, 1], axis=1)
    longest = np.maximum(np.maximum(a, b), c)
    s2 = np.sort(np.stack([a, b, c], axis=1) ** 2, axis=1)
    obtuse = s2[:, 2] >= s2[:, 0] + s2[:, 1]
    area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    circum = a * b * c / np.maximum(2 * area2, 1e-300)
    return np.where(obtuse, longest / 2, circum)


def refine(tris: np.ndarray, max_radius: float, max_triangles: int = 200_000) -> np.ndarray:
    """Split triangles at the midpoint of their longest edge until every enclosing radius
    is at most ``max_radius``; the surface is unchanged."""
    if max_radius <= 0:
        raise ValueError(f"max_radius must be positive, got {max_radius}")
    done = []
    pending = np.asarray(tris, dtype=float)
    while len(pending):
        big = enclosing_radius(pending) > max_radius
        done.append(pending[~big])
        pending = pending[big]
        if not len(pending):
            break
        if sum(len(d) for d in done) + 2 * len(pending) > max_triangles:
            raise ValueError(f"refining to {max_radius * 1e3:.3g} mm needs more than "
                             f"{max_triangles} triangles")
        e = np.stack([np.linalg.norm(pending[:, (k + 1) % 3] - pending[:, (k + 2) % 3], axis=1)
                      for k in range(3)], axis=1)
        k = np.argmax(e, axis=1)  # the longest edge is opposite vertex k
        idx = np.arange(len(pending))
        apex = pending[idx, k]
        p = pending[idx, (k + 1) % 3]
        q = pending[idx, (k + 2) % 3]
        mid = (p + q) / 2
        pending = np.concatenate([np.stack([apex, p, mid], axis=1), np.stack([apex, mid, q], axis=1)])
    return np.concatenate(done)
