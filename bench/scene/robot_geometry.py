"""A robot's collision geometry posed by its kinematic model.

The URDF link frames follow from the DH chain exactly as
:func:`bench.scene.urdf_writer.chain_to_urdf` writes them: joint ``i``
sits at ``trail_{i−1} · lead_i`` in its parent link and moves about/along its
z axis (see :func:`bench.kinematics.dh.joint_split`), the tool link hangs at
``trail_n · tool``. So the link meshes are posed from the model with one 4×4
product per joint, and a check at construction refuses a URDF that no longer
matches the chain (a stale ``urdf/``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bench.geometry.mesh_ops import enclosing_radius, refine
from bench.geometry.urdf_shapes import parse_collisions, parse_joints
from bench.kinematics.dh import DHChain, joint_split
from bench.paths import robot_urdf

__all__ = ["RobotGeometry", "ChainPoser"]


#: RobotGeometry.for_model results; the geometry is never changed once built.
_GEOMETRY_CACHE: dict = {}

class ChainPoser:
    """World poses of a chain's URDF links: ``base_link``, one per row, and the tool."""

    def __init__(self, chain: DHChain) -> None:
        self.chain = chain
        n = len(chain.rows)
        splits = [joint_split(r) for r in chain.rows]
        trails = [chain.base] + [s[1] for s in splits]
        self.origins = np.array([trails[i] @ splits[i][0] for i in range(n)])
        self.tool = trails[n] @ chain.tool
        self.revolute = np.array([r.kind == "revolute" for r in chain.rows])
        self.n = n
        self._rev = np.flatnonzero(self.revolute)
        self._pri = np.flatnonzero(~self.revolute)
        self._identity = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()

    def frames(self, q: np.ndarray) -> np.ndarray:
        """Link frames (n + 2, 4, 4) for one joint vector: base, each joint's link, tool."""
        q = np.asarray(q, dtype=float)
        c, s = np.cos(q[self._rev]), np.sin(q[self._rev])
        M = self._identity.copy()
        M[self._rev, 0, 0] = c
        M[self._rev, 0, 1] = -s
        M[self._rev, 1, 0] = s
        M[self._rev, 1, 1] = c
        M[self._pri, 2, 3] = q[self._pri]
        A = self.origins @ M
        out = np.empty((self.n + 2, 4, 4))
        out[0] = np.eye(4)
        for i in range(self.n):
            np.matmul(out[i], A[i], out=out[i + 1])
        np.matmul(out[self.n], self.tool, out=out[-1])
        return out

    def frames_batch(self, Q: np.ndarray) -> np.ndarray:
        """Link frames (N, n + 2, 4, 4) for joint vectors (N, n)."""
        Q = np.asarray(Q, dtype=float)
        N = len(Q)
        out = np.empty((N, self.n + 2, 4, 4))
        T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
        out[:, 0] = T
        for i in range(self.n):
            T = T @ self.origins[i]
            v = Q[:, i]
            if self.revolute[i]:
                c, s = np.cos(v)[:, None], np.sin(v)[:, None]
                x = T[:, :, 0].copy()
                T[:, :, 0] = c * x + s * T[:, :, 1]
                T[:, :, 1] = c * T[:, :, 1] - s * x
            else:
                T[:, :, 3] += v[:, None] * T[:, :, 2]
            out[:, i + 1] = T
        out[:, -1] = T @ self.tool
        return out


def _patches(points: np.ndarray, size: int) -> list[np.ndarray]:
    """Split points into spatially compact groups of at most ``size`` (median splits)."""
    if len(points) <= size:
        return [points]
    axis = int(np.argmax(np.ptp(points, axis=0)))
    order = np.argsort(points[:, axis], kind="stable")
    half = len(points) // 2
    return _patches(points[order[:half]], size) + _patches(points[order[half:]], size)


class RobotGeometry:
    """Collision meshes of a robot's links, in link frames, with what the checks reuse.

    ``links`` lists the links that have collision shapes; ``frame_index[k]``
    says which of :meth:`ChainPoser.frames` poses link ``k``. For the
    per-cycle check every shape's mesh is refined until no triangle's
    enclosing radius exceeds ``sample_radius``; its vertices (*surface
    points*) are grouped into patches of at most ``patch_size`` nearby points,
    each with a ball that holds its part of the surface.
    """

    def __init__(self, chain: DHChain, urdf: Path, sample_radius: float = 0.012,
                 patch_size: int = 48) -> None:
        urdf = Path(urdf)
        if not urdf.is_file():
            raise FileNotFoundError(f"robot URDF not found: {urdf}")
        self.urdf = urdf
        self.poser = ChainPoser(chain)
        joints = parse_joints(urdf)
        moving = [j for j in joints if j.kind != "fixed"]
        names = [r.name for r in chain.rows]
        if [j.name for j in moving] != names:
            raise ValueError(f"{urdf.name}: joints {[j.name for j in moving]} do not match the "
                             f"model's {names}")
        fixed = [j for j in joints if j.kind == "fixed"]
        frame_of = {"base_link": 0}
        frame_of.update({j.child: i + 1 for i, j in enumerate(moving)})
        if fixed:
            frame_of[fixed[-1].child] = len(names) + 1
        self._check_against_urdf(joints, frame_of)
        shapes = parse_collisions(urdf)
        unknown = sorted(set(shapes) - set(frame_of))
        if unknown:
            raise ValueError(f"{urdf.name}: links {unknown} are not on the model's chain")
        self.links: list[str] = [name for name in frame_of if name in shapes]
        self.frame_index = np.array([frame_of[n] for n in self.links])
        self.sample_radius = float(sample_radius)
        tris, tri_link = [], []
        patch_link, centres, radii, refine_r, points = [], [], [], [], []
        probes, probe_link = [], []
        self.shapes: list[tuple[int, object]] = []  # (link index, CollisionShape)
        for k, name in enumerate(self.links):
            for s in shapes[name]:
                self.shapes.append((k, s))
                t = s.triangles()
                tris.append(t)
                tri_link.append(np.full(len(t), k))
                probes.append(t[0, 0])
                probe_link.append(k)
                fine = refine(t, self.sample_radius)
                r = float(enclosing_radius(fine).max())
                for pts in _patches(np.unique(fine.reshape(-1, 3), axis=0), patch_size):
                    c = (pts.min(axis=0) + pts.max(axis=0)) / 2
                    patch_link.append(k)
                    centres.append(c)
                    # every surface point is within 2r of a vertex of its triangle
                    radii.append(float(np.linalg.norm(pts - c, axis=1).max()) + 2 * r)
                    refine_r.append(r)
                    points.append(pts)
        self.tris_local = np.concatenate(tris)  # (M, 3, 3), link frames, sorted by link
        self.tri_link = np.concatenate(tri_link)
        self.tri_start = np.searchsorted(self.tri_link, np.arange(len(self.links)))
        self.tri_stop = np.append(self.tri_start[1:], len(self.tri_link))
        self.patch_link = np.array(patch_link)  # (P,), sorted by link
        self.patch_centre = np.array(centres)  # link frame
        self.patch_radius = np.array(radii)  # ball around the centre holding the patch's surface
        self.patch_refine = np.array(refine_r)  # enclosing radius of the refined triangles
        self.patch_pcount = np.array([len(p) for p in points])
        self.patch_pstart = np.cumsum(self.patch_pcount) - self.patch_pcount
        self.points_local = np.concatenate(points)  # (V, 3), sorted by patch
        self.point_link = np.repeat(self.patch_link, self.patch_pcount)
        # the same points padded (by repeating one) to (P, patch_size, 3), and |p|^2
        self.patch_points = np.array([np.concatenate([p, np.repeat(p[:1], patch_size - len(p), 0)])
                                      for p in points])
        self.patch_points_sq = np.einsum("pkj,pkj->pk", self.patch_points, self.patch_points)
        self.link_pstart = np.searchsorted(self.patch_link, np.arange(len(self.links)))
        self.probes_local = np.array(probes)  # one vertex per shape, for the containment test
        self.probe_link = np.array(probe_link)
        self.levers = self._levers()

    def _levers(self) -> np.ndarray:
        """Per joint, how far any collision point can move per unit of joint motion.

        A prismatic joint moves what follows by 1 m/m; a revolute one by at
        most the distance from its origin to the farthest point downstream,
        bounded over all configurations by walking the chain from the tool
        (offset to the next joint, plus its stroke if prismatic, plus that
        joint's reach). So moving from q to q' displaces no point by more
        than ``sum(levers · |q' − q|)``.
        """
        chain = self.poser.chain
        n = self.poser.n
        frame_radius = np.zeros(n + 2)
        for k, idx in enumerate(self.frame_index):
            pts = self.tris_local[self.tri_link == k].reshape(-1, 3)
            frame_radius[idx] = max(frame_radius[idx], float(np.linalg.norm(pts, axis=1).max()))
        reach = np.zeros(n + 2)
        reach[n + 1] = frame_radius[n + 1]
        reach[n] = max(frame_radius[n], float(np.linalg.norm(self.poser.tool[:3, 3])) + reach[n + 1])
        for i in range(n - 1, 0, -1):  # frame i is joint i-1's link; the next joint is row i
            row = chain.rows[i]
            stroke = max(abs(row.lower), abs(row.upper)) if row.kind == "prismatic" else 0.0
            step = float(np.linalg.norm(self.poser.origins[i][:3, 3])) + stroke
            reach[i] = max(frame_radius[i], step + reach[i + 1])
        return np.array([reach[i + 1] if r.kind == "revolute" else 1.0
                         for i, r in enumerate(chain.rows)])

    def _check_against_urdf(self, joints, frame_of: dict[str, int]) -> None:
        """The URDF's own joint tree at home must put every link where the chain does."""
        home = self.poser.chain.home
        ours = self.poser.frames(home)
        world = {"base_link": np.eye(4)}
        values = dict(zip([r.name for r in self.poser.chain.rows], home))
        for j in joints:
            T = world[j.parent] @ j.origin
            if j.kind == "revolute":
                c, s = math.cos(values[j.name]), math.sin(values[j.name])
                T = T @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
            elif j.kind == "prismatic":
                M = np.eye(4)
                M[2, 3] = values[j.name]
                T = T @ M
            world[j.child] = T
        for name, idx in frame_of.items():
            err = float(np.abs(world[name] - ours[idx]).max())
            if err > 1e-6:
                raise ValueError(f"{self.urdf.name} does not match the kinematic model: link "
                                 f"{name} is {err:.3g} off at home; run `hilbench urdf build`")

    @classmethod
    def for_model(cls, model, urdf: Path | None = None, sample_radius: float = 0.012,
                  patch_size: int = 48):
        """Geometry of a bench robot model (its URDF under ``urdf/`` unless given)."""
        if urdf is None:
            urdf = robot_urdf(model.name)
        # Built once per chain and mesh file: every trial (and the plan replay before it)
        # needs the same geometry, and building it costs tens of milliseconds.
        try:
            stamp = Path(urdf).stat().st_mtime_ns
        except OSError:
            stamp = None
        key = (cls, repr(model.chain.rows), str(urdf), stamp, sample_radius, patch_size)
        geometry = _GEOMETRY_CACHE.get(key)
        if geometry is None:
            geometry = _GEOMETRY_CACHE[key] = cls(model.chain, urdf, sample_radius, patch_size)
        return geometry

    def link_frames(self, q: np.ndarray) -> np.ndarray:
        """World frames (L, 4, 4) of :attr:`links` at joint vector ``q``."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.poser.n,):
            raise ValueError(f"expected {self.poser.n} joint values "
                             f"{[r.name for r in self.poser.chain.rows]}, got shape {q.shape}")
        return self.poser.frames(q)[self.frame_index]

    def link_frames_batch(self, Q: np.ndarray) -> np.ndarray:
        return self.poser.frames_batch(Q)[:, self.frame_index]

    def triangle_index(self, links: np.ndarray) -> np.ndarray:
        """Indices of the given links' triangles (in :attr:`tris_local`), link by link."""
        count = self.tri_stop[links] - self.tri_start[links]
        return np.repeat(self.tri_start[links] - np.cumsum(count) + count, count) \
            + np.arange(int(count.sum()))

    def world_triangles(self, frames: np.ndarray, links: np.ndarray | None = None):
        """World triangles of the given links (all by default) and each one's link index."""
        if links is None:
            links, lk = range(len(self.links)), self.tri_link
        else:
            links = np.asarray(links, dtype=int)
            lk = np.repeat(links, self.tri_stop[links] - self.tri_start[links])
        out = np.empty((len(lk) * 3, 3))
        local = self.tris_local.reshape(-1, 3)
        at = 0
        for k in links:  # one matrix product per link: far cheaper than a batched einsum
            a, b = 3 * self.tri_start[k], 3 * self.tri_stop[k]
            F = frames[k]
            np.add(local[a:b] @ F[:3, :3].T, F[:3, 3], out=out[at:at + b - a])
            at += b - a
        return out.reshape(-1, 3, 3), lk
