"""Triangle–triangle distance and the paper's triangle–triangle contact test, vectorised.

Seed 001 (section 3.2, eqs 4–6) decides contact of two triangles α, β with
plane-side tests: if every vertex of β lies strictly on one side of α's
plane there is no contact (eq 4); otherwise contact if an edge of β that
crosses α's plane pierces α (eq 6, three signed volumes of the same sign).
That is Möller's idea [15] and :func:`paper_intersects` transcribes it.

A yes/no overlap cannot honour a safety margin except by inflating one mesh
(the paper enlarges the robot by 20 mm, Fig. 14, which is not a distance).
:func:`triangle_distance` generalises the same test to the exact Euclidean
distance between two triangles: it is zero when an edge of one pierces the
other (eq 6, in both directions), and otherwise the minimum over the nine
edge–edge distances and the six vertex–face distances whose foot lies inside
the face. Those fifteen features contain a closest pair of any two disjoint
triangles, coplanar and parallel ones included.

Every function takes arrays of triangles of shape (n, 3, 3) (triangle,
vertex, xyz) and works pair by pair along the first axis.
"""

from __future__ import annotations

import numpy as np

__all__ = ["segment_distance", "triangle_distance", "paper_intersects", "point_triangle_distance",
           "prepare", "indexed_distance"]

_NEXT = np.array([1, 2, 0])

# Internally a set of triangles is stored as (coordinate, vertex, triangle),
# shape (3, 3, n): every arithmetic step then runs over contiguous rows of n
# values and every small reduction is over a leading axis, which is several
# times faster in numpy than working along trailing axes of length 3.


def _soa(T: np.ndarray) -> np.ndarray:
    """(n, 3, 3) triangles -> (coordinate, vertex, triangle)."""
    return np.ascontiguousarray(np.asarray(T, dtype=float).transpose(2, 1, 0))


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def _seg_dist2(p1, d1, p2, d2, aa=None, ee=None) -> np.ndarray:
    """Squared distance between segments p1 + s·d1 and p2 + t·d2 (coordinate-first arrays).

    Ericson's closest-point method; for parallel segments s is clamped to an
    end and the clamping steps then find the true minimum. ``d2`` must not
    vanish; ``d1`` may (a point against a segment).
    """
    r = p1 - p2
    a = _dot(d1, d1) if aa is None else aa
    e = _dot(d2, d2) if ee is None else ee
    f = _dot(d2, r)
    c = _dot(d1, r)
    b = _dot(d1, d2)
    inv_a = 1.0 / np.maximum(a, 1e-300)
    # (Near-)parallel segments give a vanishing determinant: any s is then as
    # good as another, and the clamped quotient picks 0 or 1.
    denom = np.maximum(a * e - b * b, 1e-300)
    s = np.minimum(np.maximum((b * f - c * e) / denom, 0.0), 1.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.minimum(np.maximum(-c * inv_a, 0.0), 1.0),
                 np.where(t > 1.0, np.minimum(np.maximum((b - c) * inv_a, 0.0), 1.0), s))
    t = np.minimum(np.maximum(t, 0.0), 1.0)
    diff = r + d1 * s - d2 * t
    return _dot(diff, diff)


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distance between segments p1q1 and p2q2 (arrays (..., 3)); p2 != q2."""
    p1, q1, p2, q2 = (np.moveaxis(np.asarray(v, dtype=float), -1, 0) for v in (p1, q1, p2, q2))
    return np.sqrt(_seg_dist2(p1, q1 - p1, p2, q2 - p2))


class _Tris:
    """Triangles in (coordinate, vertex, triangle) layout with what every test reuses."""

    __slots__ = ("v", "e", "n", "nn", "m", "mv", "ee")

    def __init__(self, v: np.ndarray) -> None:
        self.v = v  # (3, 3, n)
        self.e = v[:, _NEXT] - v  # edge k from vertex k to k + 1
        self.n = _cross(self.e[:, 0], -self.e[:, 2])  # (3, n), not normalised
        self.nn = _dot(self.n, self.n)
        self.m = _cross(self.n[:, None], self.e)  # inward in-plane edge normals (3, 3, n)
        self.mv = _dot(self.m, v)  # a point x is inside edge k when m_k·x >= mv_k
        self.ee = _dot(self.e, self.e)  # (3, n)

    def take(self, idx: np.ndarray) -> "_Tris":
        out = _Tris.__new__(_Tris)
        out.v, out.e, out.m = self.v[..., idx], self.e[..., idx], self.m[..., idx]
        out.n, out.nn, out.mv, out.ee = self.n[:, idx], self.nn[idx], self.mv[:, idx], self.ee[:, idx]
        return out


def _stack(A: _Tris, B: _Tris) -> _Tris:
    out = _Tris.__new__(_Tris)
    for name in _Tris.__slots__:
        setattr(out, name, np.concatenate([getattr(A, name), getattr(B, name)], axis=-1))
    return out


def _inside(x: np.ndarray, T: _Tris) -> np.ndarray:
    """Whether points x (3, k, n) project into their triangle (edges included), shape (k, n)."""
    ok = None
    for k in range(3):
        side = _dot(x, T.m[:, k:k + 1]) >= T.mv[k:k + 1]
        ok = side if ok is None else ok & side
    return ok


def _one_way(A: _Tris, B: _Tris):
    """Squared vertex–face distances of A's vertices against B, and whether an edge of A
    pierces B (eq 6), per pair."""
    s = _dot(A.v - B.v[:, :1], B.n[:, None])  # (3 vertices, n), scaled by |nB|
    inside = _inside(A.v, B)
    vf2 = np.where(inside, s * s, np.inf).min(axis=0) / np.maximum(B.nn, 1e-300)
    s_next = s[_NEXT]
    crossing = s * s_next < 0.0
    w = s / np.where(crossing, s - s_next, 1.0)
    hit = crossing & _inside(A.v + A.e * w, B)
    return vf2, hit[0] | hit[1] | hit[2]


def _distance2(A: _Tris, B: _Tris) -> np.ndarray:
    n = len(A.nn)
    # both directions (A's vertices and edges against B, B's against A) in one pass
    vf, pierce = _one_way(_stack(A, B), _stack(B, A))
    ee = _seg_dist2(A.v[:, :, None], A.e[:, :, None], B.v[:, None], B.e[:, None],
                    A.ee[:, None], B.ee[None])
    d2 = np.minimum(np.minimum(vf[:n], vf[n:]), ee.reshape(9, n).min(axis=0))
    return np.where(pierce[:n] | pierce[n:], 0.0, d2)


def prepare(T: np.ndarray) -> _Tris:
    """Precompute a static mesh (n, 3, 3) once for :func:`indexed_distance`."""
    return _Tris(_soa(T))


def indexed_distance(A: _Tris, ia: np.ndarray, B: _Tris, ib: np.ndarray) -> np.ndarray:
    """Distances between the triangle pairs (A[ia[k]], B[ib[k]]) of two prepared meshes."""
    return np.sqrt(_distance2(A.take(ia), B.take(ib)))


def triangle_distance(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Exact distance between triangles A[i] and B[i] (0 where they touch or intersect)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape != B.shape or A.shape[1:] != (3, 3):
        raise ValueError(f"need two arrays of triangles of the same shape (n, 3, 3), "
                         f"got {A.shape} and {B.shape}")
    return np.sqrt(_distance2(_Tris(_soa(A)), _Tris(_soa(B))))


def point_triangle_distance(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Distance from points P[i] (n, 3) to triangles T[i] (n, 3, 3)."""
    tri = _Tris(_soa(T))
    p = np.asarray(P, dtype=float).T[:, None, :]  # (3, 1, n)
    s = _dot(p - tri.v[:, :1], tri.n[:, None])[0]
    face2 = np.where(_inside(p, tri)[0], s * s / np.maximum(tri.nn, 1e-300), np.inf)
    edge2 = _seg_dist2(p, np.zeros_like(p), tri.v, tri.e, ee=tri.ee).min(axis=0)
    return np.sqrt(np.minimum(face2, edge2))


def _plane_f(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Eq 5: f(x) = a x + b y + c z + d for the plane through p0, p1, p2 (a, b, c = r1 × r2)."""
    return _dot(_cross(p0 - p1, p0 - p2), x - p0)


def _paper_one_way(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    a1, a2, a3 = alpha[:, 0], alpha[:, 1], alpha[:, 2]
    f = [_plane_f(a1, a2, a3, beta[:, k]) for k in range(3)]
    separated = (f[0] * f[1] > 0) & (f[0] * f[2] > 0)  # eq 4
    hit = np.zeros(alpha.shape[2], dtype=bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        bi, bj = beta[:, i], beta[:, j]
        divided = f[i] * f[j] < 0  # the edge crosses alpha's plane
        eq6 = ((_plane_f(a1, a2, bi, bj) * _plane_f(a1, a2, bi, a3) > 0)
               & (_plane_f(a2, a3, bi, bj) * _plane_f(a2, a3, bi, a1) > 0)
               & (_plane_f(a3, a1, bi, bj) * _plane_f(a3, a1, bi, a2) > 0))
        hit |= divided & eq6
    return ~separated & hit


def paper_intersects(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Seed 001 eqs 4–6 for pairs of triangles, applied both ways (β's edges through α and
    α's edges through β; one way alone misses a small triangle piercing a large one).

    Like the paper's strict inequalities, it reports no contact for coplanar
    or merely touching triangles; :func:`triangle_distance` is the exact test.
    """
    a, b = _soa(A), _soa(B)
    return _paper_one_way(a, b) | _paper_one_way(b, a)
