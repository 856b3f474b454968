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

Every public function takes arrays of triangles of shape (n, 3, 3)
(triangle, vertex, xyz) and works pair by pair along the first axis.

Speed: a robot-vs-gantry check runs a few hundred numpy operations on a few
hundred to a few thousand pairs, so the cost is in numpy's per-call
overhead and in broadcasting, which sends a call down the slow general
iterator. A set of triangles is therefore one packed array
(:class:`TriangleSet`, one row per quantity, one column per triangle): one
``take`` gathers every quantity of the pairs, and every operation below
works on same-shaped contiguous rows (repeated explicitly with ``tile`` /
``take`` where a pair meets three vertices or nine edge pairs).
"""

from __future__ import annotations

import numpy as np

__all__ = ["TriangleSet", "segment_distance", "triangle_distance", "paper_intersects",
           "point_triangle_distance", "pair_distance2", "edge_distance2", "prism_bound",
           "prism_bounds"]

_NEXT = np.array([1, 2, 0])
_EDGE_I = np.repeat(np.arange(3), 3)  # the nine edge pairs (i of one, j of the other)
_EDGE_J = np.tile(np.arange(3), 3)

# Rows of the packed layout; vector quantities are (coordinate, index) blocks.
_V = slice(0, 9)     # vertex k, coordinate c at row 3c + k
_E = slice(9, 18)    # edge k, from vertex k to k + 1
_N = slice(18, 21)   # normal (v1 - v0) × (v2 - v0), not normalised
_NN = 21             # |n|²
_ND = 22             # n · v0
_M = slice(23, 32)   # inward in-plane normal of edge k, n × e_k
_MV = slice(32, 35)  # m_k · v_k: a point x projects inside edge k when m_k · x >= m_k · v_k
_EE = slice(35, 38)  # |e_k|²
_KERNEL = 38         # rows the distance kernel reads
_WO = slice(38, 54)  # unit normal and unit edge normals (3 coordinates × 4), then offsets (4)
_ROWS = 54


def _dot(u, v) -> np.ndarray:
    """Dot product over the leading axis of length 3 (arrays, or sequences of three)."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u, v) -> np.ndarray:
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def _clamp01(x: np.ndarray) -> np.ndarray:
    return np.minimum(np.maximum(x, 0.0), 1.0)


class TriangleSet:
    """Triangles packed for the kernels: ``data`` (54, n), with named views of its rows."""

    __slots__ = ("data", "v", "e", "n", "nn", "nd", "m", "mv", "ee", "wo")

    def __init__(self, data: np.ndarray) -> None:
        self.data = data
        n = data.shape[1]
        self.v = data[_V].reshape(3, 3, n)
        self.e = data[_E].reshape(3, 3, n)
        self.n = data[_N]
        self.nn = data[_NN]
        self.nd = data[_ND]
        self.m = data[_M].reshape(3, 3, n)
        self.mv = data[_MV]
        self.ee = data[_EE]
        self.wo = data[_WO]

    @classmethod
    def from_triangles(cls, T: np.ndarray) -> "TriangleSet":
        """Pack triangles given as (n, 3, 3) (triangle, vertex, xyz)."""
        T = np.asarray(T, dtype=float)
        n = len(T)
        data = np.empty((_ROWS, n))
        v = data[_V].reshape(3, 3, n)
        v[...] = T.transpose(2, 1, 0)
        e = data[_E].reshape(3, 3, n)
        e[...] = v[:, _NEXT] - v
        nrm = _cross(e[:, 0], -e[:, 2])
        data[_N] = nrm
        data[_NN] = _dot(nrm, nrm)
        data[_ND] = _dot(nrm, v[:, 0])
        m = _cross(nrm[:, None], e)
        data[_M] = m.reshape(9, n)
        data[_MV] = _dot(m, v)
        data[_EE] = _dot(e, e)
        W = np.concatenate([nrm[:, None], m], axis=1)  # (3, 4, n)
        W /= np.sqrt(np.maximum(_dot(W, W), 1e-300))  # a degenerate triangle's stay 0: no bound
        data[38:50] = W.reshape(12, n)
        data[50:54] = _dot(W, v[:, [0, 0, 1, 2]])  # edge k's line passes through vertex k
        return cls(data)

    def __len__(self) -> int:
        return self.data.shape[1]

    def take(self, idx: np.ndarray, planes: bool = False) -> "TriangleSet":
        """Triangles ``idx`` (with their planes only if asked: the distance kernel needs none)."""
        return TriangleSet(np.take(self.data if planes else self.data[:_KERNEL], idx, axis=1))

    def vertices(self, idx: np.ndarray) -> np.ndarray:
        """Vertices of triangles ``idx``, (coordinate, vertex, pair)."""
        return np.take(self.data[_V], idx, axis=1).reshape(3, 3, len(idx))

    def planes(self, idx: np.ndarray) -> np.ndarray:
        """Unit normals, unit edge normals and offsets of triangles ``idx``, for
        :func:`prism_bound`."""
        return np.take(self.data[_WO], idx, axis=1)


def _stack(A: TriangleSet, B: TriangleSet) -> TriangleSet:
    """A and B side by side, with what the distance kernel uses (not the planes)."""
    return TriangleSet(np.concatenate([A.data[:_KERNEL], B.data[:_KERNEL]], axis=1))


def _seg_dist2(p1, d1, p2, d2, a, e) -> np.ndarray:
    """Squared distance between segments p1 + s·d1 and p2 + t·d2, for same-shaped arrays
    (coordinate first) with ``a = |d1|²`` and ``e = |d2|²``.

    Ericson's closest-point method; for parallel segments s is clamped to an
    end and the clamping steps then find the true minimum. ``d2`` must not
    vanish; ``d1`` may (a point against a segment).
    """
    r = p1 - p2
    f = _dot(d2, r)
    c = _dot(d1, r)
    b = _dot(d1, d2)
    inv_a = 1.0 / np.maximum(a, 1e-300)
    # (Near-)parallel segments give a vanishing determinant: any s is then as
    # good as another, and the clamped quotient picks 0 or 1.
    denom = np.maximum(a * e - b * b, 1e-300)
    s = _clamp01((b * f - c * e) / denom)
    t = (b * s + f) / e
    s = np.where(t < 0.0, _clamp01(-c * inv_a), np.where(t > 1.0, _clamp01((b - c) * inv_a), s))
    t = _clamp01(t)
    dx = r[0] + d1[0] * s - d2[0] * t
    dy = r[1] + d1[1] * s - d2[1] * t
    dz = r[2] + d1[2] * s - d2[2] * t
    return dx * dx + dy * dy + dz * dz


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distance between segments p1q1 and p2q2 (arrays (..., 3)); p2 != q2."""
    p1, q1, p2, q2 = (np.moveaxis(np.asarray(v, dtype=float), -1, 0) for v in (p1, q1, p2, q2))
    p1, q1, p2, q2 = np.broadcast_arrays(p1, q1, p2, q2)
    d1, d2 = q1 - p1, q2 - p2
    return np.sqrt(_seg_dist2(p1, d1, p2, d2, _dot(d1, d1), _dot(d2, d2)))


def _inside(x, m: np.ndarray, mv: np.ndarray) -> np.ndarray:
    """Whether points x (three coordinate rows) project into the triangles with inward edge
    normals ``m`` (3, 3, n) and offsets ``mv`` (3, n), edges included."""
    return ((_dot(x, m[:, 0]) >= mv[0]) & (_dot(x, m[:, 1]) >= mv[1])
            & (_dot(x, m[:, 2]) >= mv[2]))


def _one_way(X: TriangleSet, Y: TriangleSet):
    """Squared vertex–face distances of X's vertices against Y, and whether an edge of X
    pierces Y (eq 6), per pair."""
    m = len(X)
    # Y's plane and edge normals once for each of X's three vertices: rows n, nn, nd, m, mv
    rows = Y.data[_N.start:_MV.stop]
    Yt = np.concatenate([rows, rows, rows], axis=1)
    yn, ynd = Yt[0:3], Yt[_ND - _N.start]
    ym = Yt[_M.start - _N.start:_M.stop - _N.start].reshape(3, 3, 3 * m)
    ymv = Yt[_MV.start - _N.start:]
    xv = X.v.reshape(3, 3 * m)
    s = _dot(xv, yn) - ynd  # heights over Y's plane, scaled by |n|
    vf2 = np.where(_inside(xv, ym, ymv), s * s, np.inf).reshape(3, m).min(axis=0)
    vf2 /= np.maximum(Y.nn, 1e-300)
    s_next = s.reshape(3, m).take(_NEXT, axis=0).reshape(3 * m)
    crossing = s * s_next < 0.0
    w = s / np.where(crossing, s - s_next, 1.0)
    xe = X.e.reshape(3, 3 * m)
    point = (xv[0] + xe[0] * w, xv[1] + xe[1] * w, xv[2] + xe[2] * w)
    hit = (crossing & _inside(point, ym, ymv)).reshape(3, m)
    return vf2, hit[0] | hit[1] | hit[2]


def edge_distance2(A: TriangleSet, B: TriangleSet) -> np.ndarray:
    """Least squared distance between an edge of A[i] and an edge of B[i] (nine pairs).

    With the vertex–face distances (which :func:`prism_bounds` gives as its
    upper bounds) this is the distance of two triangles known to be disjoint.
    """
    ee = _seg_dist2(A.v.take(_EDGE_I, axis=1), A.e.take(_EDGE_I, axis=1),
                    B.v.take(_EDGE_J, axis=1), B.e.take(_EDGE_J, axis=1),
                    A.ee.take(_EDGE_I, axis=0), B.ee.take(_EDGE_J, axis=0))
    return ee.min(axis=0)


def pair_distance2(A: TriangleSet, B: TriangleSet) -> np.ndarray:
    """Squared distances between triangles A[i] and B[i] (0 where they touch or intersect)."""
    n = len(A)
    # both directions (A's vertices and edges against B, B's against A) in one pass
    vf, pierce = _one_way(_stack(A, B), _stack(B, A))
    d2 = np.minimum(np.minimum(vf[:n], vf[n:]), edge_distance2(A, B))
    return np.where(pierce[:n] | pierce[n:], 0.0, d2)


def triangle_distance(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Exact distance between triangles A[i] and B[i] (0 where they touch or intersect)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape != B.shape or A.shape[1:] != (3, 3):
        raise ValueError(f"need two arrays of triangles of the same shape (n, 3, 3), "
                         f"got {A.shape} and {B.shape}")
    return np.sqrt(pair_distance2(TriangleSet.from_triangles(A), TriangleSet.from_triangles(B)))


def point_triangle_distance(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Distance from points P[i] (n, 3) to triangles T[i] (n, 3, 3)."""
    tri = TriangleSet.from_triangles(T)
    n = len(tri)
    p = np.asarray(P, dtype=float).T  # (3, n)
    s = _dot(p, tri.n) - tri.nd
    face2 = np.where(_inside(p, tri.m, tri.mv), s * s / np.maximum(tri.nn, 1e-300), np.inf)
    p3 = np.repeat(p[:, None], 3, axis=1)
    edge2 = _seg_dist2(p3, np.zeros((3, 3, n)), tri.v, tri.e, np.zeros((3, n)), tri.ee)
    return np.sqrt(np.minimum(face2, edge2.min(axis=0)))


def _heights(planes: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``W·y - o`` for each of X's four planes (rows of ``planes``) and each point of Y:
    (points, 4, n). One ``einsum`` pass; repeating the operands to same-shaped arrays
    first costs more than it saves here."""
    n = Y.shape[2]
    return np.einsum("crn,ckn->krn", planes[:12].reshape(3, 4, n), Y) - planes[12:]


def _lower(H: np.ndarray) -> np.ndarray:
    lo, hi = H.min(axis=0), H.max(axis=0)  # (4, n)
    h = np.maximum(np.maximum(lo[0], -hi[0]), 0.0)
    e = np.maximum(-np.minimum(np.minimum(hi[1], hi[2]), hi[3]), 0.0)
    return np.sqrt(h * h + e * e)


def prism_bound(planes: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Lower bounds of the distance between triangles X[i] (given by
    :meth:`TriangleSet.planes`, (16, n)) and the convex hulls of point sets Y[..., i]
    (coordinate, point, set): another triangle's vertices, or a mesh patch's.

    X lies in its plane and inside its three edge lines; the plane's normal is
    orthogonal to each edge's in-plane normal, so for any x in X and y in Y
    ``|y - x|^2 >= h^2 + e_k^2`` with ``h`` the least height of Y's points
    on one side of the plane (0 if they straddle it) and ``e_k`` how far all
    of them lie beyond edge k (0 if not all do). Exact when the closest
    points are a vertex of Y and a point of X's face or edge.
    """
    return _lower(_heights(planes, Y))


def prism_bounds(planes: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`prism_bound`, and an upper bound: the least height of a point of Y that lies
    over X's face (its distance to X; ``inf`` where no point does)."""
    H = _heights(planes, Y)
    over = (H[:, 1] >= 0.0) & (H[:, 2] >= 0.0) & (H[:, 3] >= 0.0)
    upper = np.where(over, np.abs(H[:, 0]), np.inf).min(axis=0)
    return _lower(H), upper


def _soa(T: np.ndarray) -> np.ndarray:
    """(n, 3, 3) triangles -> (coordinate, vertex, triangle)."""
    return np.ascontiguousarray(np.asarray(T, dtype=float).transpose(2, 1, 0))


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
