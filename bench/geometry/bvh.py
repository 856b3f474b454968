"""A static box tree over a mesh's triangles, queried in bulk with a few array passes.

Built once for a static mesh (the gantry): items are split at the median of
their longest axis until a leaf holds at most ``leaf_size``; consecutive
leaves (siblings in that split) are grouped ``branch`` at a time into parent
boxes, and so on up until at most ``top_size`` boxes remain. A query tests a
whole batch of boxes against the top level in one array operation, then walks
down one level per pass, expanding only the boxes it hit: a handful of numpy
calls per level on small arrays, where a per-node walk would cost a round of
calls per node. Boxes are stored as rows ``[lo, hi]`` so a level's boxes are
gathered with one row ``take``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BoxIndex", "box_gap"]


def box_gap(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> np.ndarray:
    """Euclidean distance between boxes (0 when they overlap); a lower bound for their contents."""
    gap = np.maximum(np.maximum(lo_b - hi_a, lo_a - hi_b), 0.0)
    return np.sqrt(np.einsum("...i,...i->...", gap, gap))


def _split(centre: np.ndarray, idx: np.ndarray, size: int) -> list[np.ndarray]:
    if len(idx) <= size:
        return [idx]
    c = centre[idx]
    axis = int(np.argmax(np.ptp(c, axis=0)))
    idx = idx[np.argsort(c[:, axis], kind="stable")]
    half = len(idx) // 2
    return _split(centre, idx[:half], size) + _split(centre, idx[half:], size)


def _ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenated ``arange(start[i], start[i] + count[i])``."""
    total = int(count.sum())
    return np.repeat(start - np.cumsum(count) + count, count) + np.arange(total)


def _overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether box rows ``[lo, hi]`` of a and b overlap (same shape (n, 6))."""
    return ((a[:, 0] <= b[:, 3]) & (a[:, 1] <= b[:, 4]) & (a[:, 2] <= b[:, 5])
            & (b[:, 0] <= a[:, 3]) & (b[:, 1] <= a[:, 4]) & (b[:, 2] <= a[:, 5]))


@dataclass(frozen=True)
class BoxIndex:
    """Box levels (top first, rows ``[lo, hi]``), each leaf's run of ``order``, the item
    boxes in that order, and the branching factor."""

    levels: tuple[np.ndarray, ...]
    leaf_start: np.ndarray
    leaf_count: np.ndarray
    order: np.ndarray
    items: np.ndarray  # (n, 6), row i is item order[i]
    branch: int

    @classmethod
    def build(cls, item_lo: np.ndarray, item_hi: np.ndarray, leaf_size: int = 8,
              branch: int = 8, top_size: int = 64) -> "BoxIndex":
        item_lo = np.asarray(item_lo, dtype=float)
        item_hi = np.asarray(item_hi, dtype=float)
        if item_lo.shape != item_hi.shape or item_lo.ndim != 2 or item_lo.shape[1] != 3 \
                or len(item_lo) == 0:
            raise ValueError(f"need non-empty (n, 3) item bounds, got {item_lo.shape}")
        if leaf_size < 1 or branch < 2 or top_size < 1:
            raise ValueError(f"need leaf_size >= 1, branch >= 2 and top_size >= 1, got "
                             f"{leaf_size}, {branch}, {top_size}")
        leaves = _split((item_lo + item_hi) / 2, np.arange(len(item_lo)), leaf_size)
        count = np.array([len(g) for g in leaves])
        order = np.concatenate(leaves)
        items = np.hstack([item_lo, item_hi])[order]
        start = np.cumsum(count) - count
        level = np.hstack([np.minimum.reduceat(items[:, :3], start),
                           np.maximum.reduceat(items[:, 3:], start)])
        levels = [level]
        while len(levels[-1]) > top_size:
            prev = levels[-1]
            s = np.arange(0, len(prev), branch)
            levels.append(np.hstack([np.minimum.reduceat(prev[:, :3], s),
                                     np.maximum.reduceat(prev[:, 3:], s)]))
        return cls(tuple(levels[::-1]), start, count, order, np.ascontiguousarray(items), branch)

    def query(self, q_lo: np.ndarray, q_hi: np.ndarray, pad: float = 0.0):
        """All (query, item) pairs whose boxes come within ``pad`` of each other.

        Returns ``(query_index, item_index, gap)`` with ``gap`` the box–box
        distance, a lower bound on the distance between their contents.
        """
        q_lo = np.asarray(q_lo, dtype=float)
        q_hi = np.asarray(q_hi, dtype=float)
        Q = np.hstack([q_lo - pad, q_hi + pad])  # each query box grown by the pad
        top = self.levels[0]
        hit = ((Q[:, None, :3] <= top[None, :, 3:]) & (top[None, :, :3] <= Q[:, None, 3:])).all(2)
        qi, node = np.nonzero(hit)
        for level in self.levels[1:]:
            first = node * self.branch
            n_child = np.minimum(self.branch, len(level) - first)
            qi = np.repeat(qi, n_child)
            node = _ranges(first, n_child)
            keep = _overlap(Q.take(qi, axis=0), level.take(node, axis=0))
            qi, node = qi[keep], node[keep]
        n_item = self.leaf_count[node]
        qi = np.repeat(qi, n_item)
        rows = _ranges(self.leaf_start[node], n_item)
        B = self.items.take(rows, axis=0)
        lo, hi = q_lo.take(qi, axis=0), q_hi.take(qi, axis=0)
        g = np.maximum(np.maximum(B[:, :3] - hi, lo - B[:, 3:]), 0.0)
        gap = np.sqrt(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2])
        keep = gap <= pad
        return qi[keep], self.order[rows[keep]], gap[keep]
