"""A static two-level box index: items grouped into compact clusters, queried in bulk.

Built once for a static mesh (the gantry) by median splits along the longest
axis until each cluster holds at most ``cluster_size`` items. A query tests a
whole batch of boxes against every cluster box in one array operation, then
the items of the clusters hit against their query boxes: two numpy passes
instead of a walk down a deep tree, which in numpy costs a round of calls per
level. For a 6144-triangle torus and a robot's few hundred triangles this is
the cheaper of the two.
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


@dataclass(frozen=True)
class BoxIndex:
    """Cluster boxes (3, C), each cluster's run of ``order``, and the item boxes (3, n)."""

    cluster_lo: np.ndarray
    cluster_hi: np.ndarray
    start: np.ndarray
    count: np.ndarray
    order: np.ndarray
    item_lo: np.ndarray
    item_hi: np.ndarray

    @classmethod
    def build(cls, item_lo: np.ndarray, item_hi: np.ndarray, cluster_size: int = 64) -> "BoxIndex":
        item_lo = np.asarray(item_lo, dtype=float)
        item_hi = np.asarray(item_hi, dtype=float)
        if item_lo.shape != item_hi.shape or item_lo.ndim != 2 or item_lo.shape[1] != 3 \
                or len(item_lo) == 0:
            raise ValueError(f"need non-empty (n, 3) item bounds, got {item_lo.shape}")
        if cluster_size < 1:
            raise ValueError(f"cluster_size must be at least 1, got {cluster_size}")
        groups = _split((item_lo + item_hi) / 2, np.arange(len(item_lo)), cluster_size)
        count = np.array([len(g) for g in groups])
        order = np.concatenate(groups)
        lo = np.array([item_lo[g].min(axis=0) for g in groups]).T
        hi = np.array([item_hi[g].max(axis=0) for g in groups]).T
        return cls(np.ascontiguousarray(lo), np.ascontiguousarray(hi), np.cumsum(count) - count,
                   count, order, np.ascontiguousarray(item_lo.T), np.ascontiguousarray(item_hi.T))

    def query(self, q_lo: np.ndarray, q_hi: np.ndarray, pad: float = 0.0):
        """All (query, item) pairs whose boxes come within ``pad`` of each other.

        Returns ``(query_index, item_index, gap)`` with ``gap`` the box–box
        distance, a lower bound on the distance between their contents.
        """
        qlo = np.asarray(q_lo, dtype=float).T[:, :, None]  # (3, n, 1)
        qhi = np.asarray(q_hi, dtype=float).T[:, :, None]
        a = qlo - pad <= self.cluster_hi[:, None, :]
        b = self.cluster_lo[:, None, :] <= qhi + pad
        qi, ci = np.nonzero(a[0] & a[1] & a[2] & b[0] & b[1] & b[2])
        counts = self.count[ci]
        total = int(counts.sum())
        if total == 0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, np.zeros(0)
        q_rep = np.repeat(qi, counts)
        items = self.order[np.repeat(self.start[ci] - np.cumsum(counts) + counts, counts)
                           + np.arange(total)]
        qlo, qhi = qlo[:, :, 0], qhi[:, :, 0]
        g = np.maximum(np.maximum(self.item_lo[:, items] - qhi[:, q_rep],
                                  qlo[:, q_rep] - self.item_hi[:, items]), 0.0)
        gap = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
        keep = gap <= pad
        return q_rep[keep], items[keep], gap[keep]
