"""Contact between a robot and the CT gantry, with a safety margin (seed 001, section 3).

Three ways to answer "is any link closer to the gantry than the margin?":

* :class:`GantryContact` — the exact test. Link meshes (from the URDF's
  collision shapes, posed by the kinematic model) against the gantry's
  triangle mesh, with the exact triangle–triangle *distance* (the paper's
  eqs 4–6 generalised, :mod:`bench.geometry.tri_distance`), so a distance
  below the margin is contact and the margin is honoured exactly. Pruned in
  stages, each a handful of array operations: links whose bounding ball is
  beyond reach of the analytic torus are skipped, then triangles (vertex
  values of the torus' signed distance and a curvature bound); a box tree
  over the gantry's triangles (:mod:`bench.geometry.bvh`) gives the pairs
  within reach; plane-and-edge (prism) bounds both ways drop most of them
  and order the rest, and a per-link branch and bound runs the exact kernel
  on the few whose bound is below the best distance found. A link wholly
  inside the gantry (no surface within reach) is caught by a ray-parity test
  (distance 0). Distances are exact up to ``reach`` (default: margin +
  10 mm); beyond it they are lower bounds.
* :func:`all_pairs_distance` / :func:`all_pairs_contact` — the paper's
  brute force: every robot triangle against every gantry triangle (the
  distance kernel, or the paper's own yes/no test). For benchmarks and as
  an oracle on small cases.
* :class:`GantryClearance` — the per-cycle interlock check: points on the
  link surfaces against the analytic torus, with a curvature bound for what
  lies between them and the mesh's deviation from the torus subtracted. A
  certified lower bound of the exact distance (it never reports clearance
  where the exact test finds contact), about 0.1 ms for the arc robot.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from bench.geometry.bvh import BoxIndex
from bench.geometry.torus import Torus, mesh_slack
from bench.geometry.tri_distance import (
    TriangleSet,
    edge_distance2,
    pair_distance2,
    paper_intersects,
    prism_bounds,
    triangle_distance,
)
from bench.kinematics.arc_train import ArcTrainParams
from bench.scene.robot_geometry import RobotGeometry
from bench.scene.room import SceneParams, gantry_mesh

__all__ = ["Gantry", "GantryContact", "ContactReport", "GantryClearance", "Clearance",
           "RobotGeometry", "all_pairs_distance", "all_pairs_contact", "default_gantry",
           "DEFAULT_MARGIN"]

DEFAULT_MARGIN = 0.020  # m; seed 001 section 4.1


@dataclass
class Gantry:
    """The gantry's triangle mesh, its box index, and (optionally) the torus it approximates.

    ``slack_out`` / ``slack_in``: how far the mesh strays outside / inside the
    analytic torus (m), so torus distances can bound mesh distances.
    """

    tris: np.ndarray  # (G, 3, 3), bed frame
    torus: Torus | None = None
    slack_out: float = 0.0
    slack_in: float = 0.0
    index: BoxIndex = field(init=False)
    prepared: TriangleSet = field(init=False)  # the triangles packed for the kernels

    def __post_init__(self) -> None:
        self.tris = np.asarray(self.tris, dtype=float)
        if self.tris.ndim != 3 or self.tris.shape[1:] != (3, 3) or not len(self.tris):
            raise ValueError(f"gantry triangles must have shape (n, 3, 3), got {self.tris.shape}")
        self.index = BoxIndex.build(self.tris.min(axis=1), self.tris.max(axis=1))
        self.prepared = TriangleSet.from_triangles(self.tris)

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, faces: np.ndarray, torus: Torus | None = None):
        tris = np.asarray(vertices, dtype=float)[np.asarray(faces)]
        if torus is None:
            return cls(tris)
        out, inside = mesh_slack(torus, tris)
        return cls(tris, torus, out, inside)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether points (n, 3) lie inside the closed mesh (ray parity along a skew direction)."""
        d = np.array([0.5773, 0.2113, 0.7887])
        d /= np.linalg.norm(d)
        v0, v1, v2 = self.tris[:, 0], self.tris[:, 1], self.tris[:, 2]
        e1, e2 = v1 - v0, v2 - v0
        pvec = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pvec)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        out = np.zeros(len(points), dtype=bool)
        for k, p in enumerate(np.asarray(points, dtype=float)):
            tvec = p - v0
            u = np.einsum("ij,ij->i", tvec, pvec) * inv
            qvec = np.cross(tvec, e1)
            v = (qvec @ d) * inv
            t = np.einsum("ij,ij->i", qvec, e2) * inv
            hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
            out[k] = bool(hit.sum() % 2)
        return out


@lru_cache(maxsize=2)
def _default_gantry(major_sections: int, minor_sections: int) -> Gantry:

    s, bed = SceneParams(), ArcTrainParams().bed_width
    torus = Torus(s.gantry_centre(bed), np.array([1.0, 0.0, 0.0]),
                  s.bore_radius + s.gantry_tube_radius, s.gantry_tube_radius)
    v, f = gantry_mesh(s, bed, major_sections, minor_sections)
    return Gantry.from_mesh(v, f, torus)


def default_gantry(major_sections: int = 96, minor_sections: int = 32) -> Gantry:
    """The CT room's gantry (bench/scene/room.py: the mesh in ``urdf/meshes/ct_gantry.obj``)."""
    return _default_gantry(major_sections, minor_sections)


def _geometry(robot) -> RobotGeometry:
    return robot if isinstance(robot, RobotGeometry) else RobotGeometry.for_model(robot)


# ---------------------------------------------------------------------------
# The per-cycle check
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Clearance:
    """Closest link and a lower bound of its distance to the gantry (m)."""

    distance: float
    link: str
    margin: float

    @property
    def contact(self) -> bool:
        return self.distance < self.margin


class GantryClearance:
    """Per-cycle gantry clearance: a certified lower bound of the exact distance.

    The gantry is the analytic torus (signed distance ``f``) and its mesh lies
    within ``slack_out`` outside it, so ``min f`` over a link's surface minus
    ``slack_out`` is at most the link's distance to the gantry mesh. The
    minimum of ``f`` over a surface triangle is bounded from its vertices:
    ``f`` is smooth there with Hessian at most ``κ = max(1/D, 1/ρ)`` (``D`` the
    distance to the torus' core circle, ``ρ`` to its axis), so on a triangle
    of enclosing radius ``R`` it dips at most ``κR²/2`` below its vertex
    values (first order, ``2R``, where that is smaller or ``κ`` has no bound).
    The link meshes are refined to ``R ≤ 12 mm`` (≈0.5 mm of slack near the
    gantry) and only surface patches whose ball comes within ``fine_within``
    of the margin are evaluated point by point; the others keep their ball's
    bound. Links inside the torus get negative values.
    """

    def __init__(self, robot, margin: float = DEFAULT_MARGIN, gantry: Gantry | None = None,
                 fine_within: float = 0.05) -> None:
        if not margin >= 0:
            raise ValueError(f"margin must be non-negative (m), got {margin}")
        if not fine_within >= 0:
            raise ValueError(f"fine_within must be non-negative (m), got {fine_within}")
        self.geometry = _geometry(robot)
        self.gantry = gantry if gantry is not None else default_gantry()
        if self.gantry.torus is None:
            raise ValueError("GantryClearance needs a gantry with its analytic torus")
        self.margin = float(margin)
        self.fine_above = self.margin + float(fine_within)
        t = self.gantry.torus
        self._c = np.asarray(t.centre, dtype=float)
        self._axis = np.asarray(t.axis, dtype=float)
        self._major, self._minor = float(t.major), float(t.minor)

    def _torus(self, p: np.ndarray):
        """Signed distance, distance to the core circle, distance to the axis."""
        rel = p - self._c
        x = rel @ self._axis
        rho = np.sqrt(np.maximum((rel * rel).sum(axis=-1) - x * x, 0.0))
        D = np.sqrt((rho - self._major) ** 2 + x * x)
        return D - self._minor, D, rho

    def _patch_bounds(self, F: np.ndarray, fine: bool = True,
                      links: np.ndarray | None = None) -> np.ndarray:
        """Lower bounds (N, P) of each surface patch's distance to the torus, link frames
        F (N, L, 4, 4): the patch ball's, or where that is near (and ``fine``, and the patch
        belongs to one of ``links`` if given), its points'."""
        g = self.geometry
        Fp = F[:, g.patch_link]
        c = np.matmul(Fp[..., :3, :3], g.patch_centre[:, :, None])[..., 0] + Fp[..., :3, 3]
        bound = self._torus(c)[0] - g.patch_radius
        if not fine:
            return bound
        near = bound <= self.fine_above
        if links is not None:
            near &= np.isin(g.patch_link, links)[None, :]
        n_idx, p_idx = np.nonzero(near)
        if n_idx.size:
            # Torus centre and axis in each patch's link frame: |p - c|^2 and (p - c)·a
            # then need two dot products per point and no rotation of the points.
            Fl = F[n_idx, g.patch_link[p_idx]]
            R, t = Fl[:, :3, :3], Fl[:, :3, 3]
            c_l = np.matmul((self._c - t)[:, None, :], R)[:, 0]  # R^T (c - t)
            a_l = self._axis @ R  # R^T a, (pairs, 3)
            G = np.matmul(g.patch_points[p_idx], np.stack([c_l, a_l], axis=2))  # (pairs, k, 2)
            x = G[..., 1] - (c_l * a_l).sum(axis=1)[:, None]
            r2 = g.patch_points_sq[p_idx] - 2 * G[..., 0] + (c_l * c_l).sum(axis=1)[:, None]
            rho = np.sqrt(np.maximum(r2 - x * x, 0.0))
            D = np.sqrt((rho - self._major) ** 2 + x * x)
            R2 = 2 * g.patch_refine[p_idx][:, None]
            with np.errstate(divide="ignore"):
                kappa = np.where((D > R2) & (rho > R2),
                                 np.maximum(1.0 / (D - R2), 1.0 / (rho - R2)), np.inf)
            val = (D - self._minor - np.minimum(kappa * R2 * R2 / 8, R2)).min(axis=1)
            bound[n_idx, p_idx] = np.maximum(bound[n_idx, p_idx], val)
        return bound

    def link_bounds(self, F: np.ndarray, fine: bool = True,
                    links: np.ndarray | None = None) -> np.ndarray:
        """Per-link lower bounds (N, L) of the distance to the gantry mesh, link frames F
        (tight only for ``links`` when given)."""
        b = self._patch_bounds(F, fine, links)
        return np.minimum.reduceat(b, self.geometry.link_pstart, axis=1) - self.gantry.slack_out

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Lower bounds (m) of every link's distance to the gantry mesh, shape (L,).

        Tight (within ~2 mm) wherever a link is within ``fine_within`` of the
        margin; beyond that a coarser bound (still below the truth).
        """
        b = self._patch_bounds(self.geometry.link_frames(q)[None])[0]
        return np.minimum.reduceat(b, self.geometry.link_pstart) - self.gantry.slack_out

    def distances_batch(self, Q: np.ndarray, chunk: int = 2000) -> np.ndarray:
        """Lower bounds for many joint vectors, shape (N, L)."""
        Q = np.asarray(Q, dtype=float)
        out = []
        for start in range(0, len(Q), chunk):
            F = self.geometry.link_frames_batch(Q[start:start + chunk])
            b = self._patch_bounds(F)
            out.append(np.minimum.reduceat(b, self.geometry.link_pstart, axis=1))
        return np.concatenate(out) - self.gantry.slack_out

    def check(self, q: np.ndarray) -> Clearance:
        d = self.distances(q)
        k = int(np.argmin(d))
        return Clearance(float(d[k]), self.geometry.links[k], self.margin)


# ---------------------------------------------------------------------------
# The exact test
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ContactReport:
    """Per-link distances to the gantry (m) and the verdict against the margin.

    ``exact[i]`` is False where the link is beyond ``reach`` and its value is
    only a lower bound; ``enclosed[i]`` marks a link wholly inside the gantry
    (distance reported as 0).
    """

    links: tuple[str, ...]
    distances: np.ndarray
    exact: np.ndarray
    enclosed: np.ndarray
    margin: float
    reach: float
    pairs: int  # triangle pairs evaluated exactly

    @property
    def distance(self) -> float:
        return float(self.distances.min())

    @property
    def link(self) -> str:
        return self.links[int(np.argmin(self.distances))]

    @property
    def contact(self) -> bool:
        return self.distance < self.margin


class GantryContact:
    """The exact robot–gantry contact test with a safety margin (pruned; see module doc)."""

    def __init__(self, robot, margin: float = DEFAULT_MARGIN, gantry: Gantry | None = None,
                 reach: float | None = None, chunk: int = 4096) -> None:
        if not margin >= 0:
            raise ValueError(f"margin must be non-negative (m), got {margin}")
        self.geometry = _geometry(robot)
        self.gantry = gantry if gantry is not None else default_gantry()
        self.margin = float(margin)
        self.reach = float(reach) if reach is not None else self.margin + 0.010
        if not self.reach >= self.margin:
            raise ValueError(f"reach ({self.reach}) must be at least the margin ({self.margin})")
        self.chunk = chunk
        self._bound = (GantryClearance(self.geometry, margin, self.gantry)
                       if self.gantry.torus is not None else None)
        g = self.geometry
        t = g.tris_local
        self._tri_radius = np.linalg.norm(t - t.mean(axis=1, keepdims=True), axis=2).max(axis=1)
        self._link_centre = np.empty((len(g.links), 3))
        self._link_radius = np.empty(len(g.links))
        for k in range(len(g.links)):  # a ball around each link's mesh, in its frame
            pts = t[g.tri_start[k]:g.tri_stop[k]].reshape(-1, 3)
            self._link_centre[k] = (pts.min(axis=0) + pts.max(axis=0)) / 2
            self._link_radius[k] = np.linalg.norm(pts - self._link_centre[k], axis=1).max()

    def check(self, q: np.ndarray) -> ContactReport:
        q = np.asarray(q, dtype=float)
        g = self.geometry
        L = len(g.links)
        frames = g.link_frames(q)
        if self.gantry.torus is None:
            tris, tri_link = g.world_triangles(frames)
            tb, lower, maybe_inside = None, np.zeros(L), np.ones(L, dtype=bool)
        else:
            # each link's bounding ball first: most links are far from the gantry
            c = np.matmul(frames[:, :3, :3], self._link_centre[:, :, None])[:, :, 0] \
                + frames[:, :3, 3]
            f = self._bound._torus(c)[0]
            r = self._link_radius
            lower = np.maximum(f - r - self.gantry.slack_out, -f - r - self.gantry.slack_in)
            # a link wholly inside the mesh has no surface provably outside it
            maybe_inside = f - r <= self.gantry.slack_out
            links = np.flatnonzero(lower <= self.reach)
            tris, tri_link = g.world_triangles(frames, links)
            tb, f_low = self._triangle_bounds(tris, g.triangle_index(links))
            if links.size:
                start = np.searchsorted(tri_link, links)
                lower[links] = np.minimum.reduceat(tb, start)
                maybe_inside[links] = np.maximum.reduceat(f_low, start) <= self.gantry.slack_out
            near = tb <= self.reach
            tris, tri_link, tb = tris[near], tri_link[near], tb[near]
        best = np.full(L, np.inf)
        pairs = self._evaluate(tris, tri_link, best, tb) if len(tris) else 0
        exact = best <= self.reach
        distances = np.where(exact, best, np.maximum(lower, self.reach))
        # A link that touches no gantry surface could still lie wholly inside the gantry
        # (a surface distance alone cannot tell): test one vertex of each of its shapes.
        enclosed = np.zeros(L, dtype=bool)
        probes = np.flatnonzero(((best > 0.0) & maybe_inside)[g.probe_link])
        if probes.size:
            pl = g.probe_link[probes]
            pts = np.matmul(frames[pl, :3, :3], g.probes_local[probes][:, :, None])[:, :, 0] \
                + frames[pl, :3, 3]
            gantry = self.gantry
            if gantry.torus is not None:
                # the mesh lies in a thin shell around the torus surface: deeper in is
                # inside it, farther out is outside; only the shell needs the ray test
                f = self._bound._torus(pts)[0]
                inside = f < -gantry.slack_in
                shell = ~inside & (f <= gantry.slack_out)
                if shell.any():
                    inside[shell] = gantry.contains(pts[shell])
            else:
                inside = gantry.contains(pts)
            enclosed[pl[inside]] = True
            distances = np.where(enclosed, 0.0, distances)
            exact = exact | enclosed
        return ContactReport(tuple(g.links), distances, exact, enclosed, self.margin, self.reach,
                             pairs)

    def _triangle_bounds(self, tris: np.ndarray,
                         tri_index: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Lower bounds (m) of each robot triangle's distance to the gantry mesh, and of the
        torus' signed distance over it (None: no torus).

        The mesh lies in the shell ``-slack_in <= f <= slack_out`` of the torus'
        signed distance ``f``, which is 1-Lipschitz, so a point where ``f = s``
        is at least ``max(s - slack_out, -s - slack_in)`` from it. Over a
        triangle of enclosing radius ``r``, ``f`` strays from its vertex values
        by at most ``κr²/2`` (its Hessian is bounded by ``κ``, as in
        :class:`GantryClearance`) or, to first order, ``2r``.
        """
        if self.gantry.torus is None:
            return None
        r = self._tri_radius[tri_index]
        f, D, rho = (x.reshape(-1, 3) for x in self._bound._torus(tris.reshape(-1, 3)))
        R2 = 2 * r
        near = np.minimum(D.min(axis=1), rho.min(axis=1)) - R2  # to the core circle or axis
        kappa = np.where(near > 0, 1.0 / np.maximum(near, 1e-300), np.inf)
        slack = np.minimum(kappa * r * r / 2, R2)
        f_low, f_high = f.min(axis=1) - slack, f.max(axis=1) + slack
        return (np.maximum(f_low - self.gantry.slack_out, -f_high - self.gantry.slack_in),
                f_low)

    def _evaluate(self, tris: np.ndarray, tri_link: np.ndarray, best: np.ndarray,
                  tri_bound: np.ndarray | None = None) -> int:
        """Exact distances of the robot triangles' candidate pairs, smallest lower bound first,
        per-link branch and bound; returns how many pairs were evaluated.

        Candidates come from the gantry's box tree. A pair's lower bound is the
        largest of its boxes' gap, the robot triangle's torus bound and the
        prism bounds both ways (a triangle's plane and edge lines against the
        other's vertices, :func:`~bench.geometry.tri_distance.prism_bound`);
        a vertex of either standing over the other's face gives a realised
        distance that starts its link's best. Only pairs whose bound is below their link's best
        reach the exact kernel, nearest first.
        """
        gantry, reach = self.gantry, self.reach
        qi, gi, gap = gantry.index.query(tris.min(axis=1), tris.max(axis=1), reach)
        if not qi.size:
            return 0
        robot = TriangleSet.from_triangles(tris)
        G = gantry.prepared
        bound = np.maximum(gap, tri_bound[qi]) if tri_bound is not None else gap
        lower, up = prism_bounds(robot.planes(qi), G.vertices(gi))
        np.minimum.at(best, tri_link[qi], up)  # gantry vertices over a robot face
        bound = np.maximum(bound, lower)
        keep = (bound <= reach) & (bound < best[tri_link[qi]])
        qi, gi, bound, up = qi[keep], gi[keep], bound[keep], up[keep]
        lower, up_g = prism_bounds(G.planes(gi), robot.vertices(qi))
        np.minimum.at(best, tri_link[qi], up_g)  # robot vertices over a gantry face
        bound = np.maximum(bound, lower)
        up = np.minimum(up, up_g)  # each pair's vertex–face distances
        keep = (bound <= reach) & (bound < best[tri_link[qi]])
        order = np.flatnonzero(keep)[np.argsort(bound[keep], kind="stable")]
        qi, gi, bound, up = qi[order], gi[order], bound[order], up[order]
        link = tri_link[qi]
        done = 0
        start = 0
        n = len(qi)
        size = 64  # the nearest pairs first settle each link's distance; the rest mostly drop
        while start < n:
            sel = np.arange(start, min(n, start + size))
            sel = sel[bound[sel] < best[link[sel]]]
            if sel.size:
                A, B = robot.take(qi[sel]), G.take(gi[sel])
                if bound[sel[0]] > 0.0:
                    # disjoint pairs (a positive lower bound): the vertex–face distances
                    # are known, the edges remain
                    d2 = np.minimum(edge_distance2(A, B), up[sel] * up[sel])
                else:
                    d2 = pair_distance2(A, B)
                np.minimum.at(best, link[sel], np.sqrt(d2))
                done += sel.size
            start += size
            size = min(self.chunk, size * 2)
        return done


# ---------------------------------------------------------------------------
# The paper's all-pairs method
# ---------------------------------------------------------------------------


def all_pairs_distance(robot_tris: np.ndarray, gantry_tris: np.ndarray,
                       chunk: int = 50_000) -> float:
    """Minimum distance over every robot × gantry triangle pair (brute force, the oracle)."""
    A = TriangleSet.from_triangles(robot_tris)
    B = TriangleSet.from_triangles(gantry_tris)
    m, k = len(robot_tris), len(gantry_tris)
    best = np.inf
    for start in range(0, m * k, chunk):
        idx = np.arange(start, min(m * k, start + chunk))
        ia, ib = np.divmod(idx, k)
        best = min(best, float(np.sqrt(pair_distance2(A.take(ia), B.take(ib)).min())))
    return best


def all_pairs_contact(robot_tris: np.ndarray, gantry_tris: np.ndarray, margin: float = 0.0,
                      chunk: int = 50_000, stop_at_first: bool = True) -> bool:
    """Seed 001's brute force: every pair, stopping at the first contact (Fig. 9).

    ``margin == 0`` uses the paper's own test (eqs 4–6); a positive margin
    uses the triangle distance (distance below the margin is contact).
    """
    m, k = len(robot_tris), len(gantry_tris)
    robot_tris = np.asarray(robot_tris, dtype=float)
    gantry_tris = np.asarray(gantry_tris, dtype=float)
    hit = False
    for start in range(0, m * k, chunk):
        idx = np.arange(start, min(m * k, start + chunk))
        ia, ib = np.divmod(idx, k)
        if margin > 0:
            found = bool(np.any(triangle_distance(robot_tris[ia], gantry_tris[ib]) < margin))
        else:
            found = bool(np.any(paper_intersects(robot_tris[ia], gantry_tris[ib])))
        hit = hit or found
        if hit and stop_at_first:
            return True
    return hit
