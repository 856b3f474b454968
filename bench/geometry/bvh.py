"""A static box tree over a mesh's triangles, queried in bulk with a few array passes.

Built once for a static mesh (the gantry): items are split at the median of
their longest axis until a leaf holds at most ``leaf_size``; consecutive
leaves (siblings in that split) are grouped ``branch`` at a time into parent
boxes, and so on up until at most ``top_size`` boxes remain. A query tests a
whole batch of boxes against the top level in one array operation, then walks
down one level per pass, expanding only the boxes it hit: a handful of numpy
calls per level on small arrays, where a per-node walk would cost a round of
calls per node. Boxes are stored as six rows (lo xyz, hi xyz) of one array,
so a level's boxes are gathered with one ``take`` and every comparison runs
on contiguous rows.
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


def _overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether the boxes (six rows: lo, hi) of a and b overlap, column by column."""
    return ((a[0] <= b[3]) & (a[1] <= b[4]) & (a[2] <= b[5])
            & (b[0] <= a[3]) & (b[1] <= a[4]) & (b[2] <= a[5]))


_EMPTY = np.array([np.inf] * 3 + [-np.inf] * 3)  # a box that overlaps nothing


def _pad(boxes: np.ndarray, size: int) -> np.ndarray:
    """Box columns (6, n) padded with empty boxes to a multiple of ``size``."""
    extra = -boxes.shape[1] % size
    return np.hstack([boxes, np.repeat(_EMPTY[:, None], extra, axis=1)])


@dataclass(frozen=True)
class BoxIndex:
    """Box levels (top first, each (6, nodes): lo then hi) and the item boxes (6, slots),
    leaf by leaf in slots of ``leaf_size`` (``item[slot]`` says which item, -1 for an
    empty slot). Every level but the top is padded with empty boxes to whole groups of
    ``branch``, so a node's children, and a leaf's items, are a fixed-size run: the walk
    down expands hits with one broadcast add instead of ragged ranges."""

    levels: tuple[np.ndarray, ...]
    items: np.ndarray  # (6, leaves * leaf_size)
    item: np.ndarray  # (leaves * leaf_size,)
    branch: int
    leaf_size: int

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
        boxes = np.hstack([item_lo, item_hi]).T  # (6, n)
        item = np.full(len(leaves) * leaf_size, -1)
        for k, g in enumerate(leaves):
            item[k * leaf_size:k * leaf_size + len(g)] = g
        items = np.where(item >= 0, boxes[:, np.maximum(item, 0)], _EMPTY[:, None])
        level = np.vstack([items[:3].reshape(3, -1, leaf_size).min(axis=2),
                           items[3:].reshape(3, -1, leaf_size).max(axis=2)])
        levels = [level]
        while levels[-1].shape[1] > top_size:
            prev = _pad(levels[-1], branch)
            levels[-1] = prev
            levels.append(np.vstack([prev[:3].reshape(3, -1, branch).min(axis=2),
                                     prev[3:].reshape(3, -1, branch).max(axis=2)]))
        return cls(tuple(np.ascontiguousarray(lv) for lv in levels[::-1]),
                   np.ascontiguousarray(items), item, branch, leaf_size)

    def query(self, q_lo: np.ndarray, q_hi: np.ndarray, pad: float = 0.0):
        """All (query, item) pairs whose boxes come within ``pad`` of each other.

        Returns ``(query_index, item_index, gap)`` with ``gap`` the box–box
        distance, a lower bound on the distance between their contents.
        """
        q_lo = np.asarray(q_lo, dtype=float).T
        q_hi = np.asarray(q_hi, dtype=float).T
        Q = np.concatenate([q_lo - pad, q_hi + pad])  # each query box grown by the pad, (6, n)
        top = self.levels[0]
        qi, node = np.nonzero(_overlap(Q[:, :, None], top[:, None, :]))
        b = self.branch
        for level in self.levels[1:]:
            qi = np.repeat(qi, b)
            node = (node[:, None] * b + np.arange(b)).reshape(-1)
            keep = _overlap(Q.take(qi, axis=1), level.take(node, axis=1))
            qi, node = qi[keep], node[keep]
        s = self.leaf_size
        qi = np.repeat(qi, s)
        slots = (node[:, None] * s + np.arange(s)).reshape(-1)
        B = self.items.take(slots, axis=1)
        lo, hi = q_lo.take(qi, axis=1), q_hi.take(qi, axis=1)
        g = np.maximum(np.maximum(B[:3] - hi, lo - B[3:]), 0.0)
        gap = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])  # inf for an empty slot
        keep = gap <= pad
        return qi[keep], self.item[slots[keep]], gap[keep]
