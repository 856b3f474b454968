"""A URDF's collision geometry as triangle meshes and sphere covers, per link.

Reads what :mod:`bench.scene.urdf_writer` writes (and any URDF with box,
cylinder, sphere and mesh collisions). Every primitive becomes a closed
triangle mesh that *contains* the true shape (boxes exactly; cylinders as
circumscribed prisms; spheres as circumscribed icospheres), so a distance to
the mesh never exceeds the distance to the shape it stands for.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.geometry.shape_cache import cached_mesh, mesh_key
from bench.kinematics.dh import matrix_from_rpy

__all__ = ["CollisionShape", "JointSpec", "parse_collisions", "parse_joints"]

MESH_TOLERANCE = 1e-4  # m: a cylinder's prism may stand this far outside the cylinder


def cylinder_sections(radius: float, tolerance: float = MESH_TOLERANCE) -> int:
    """Sides of the circumscribed prism standing at most ``tolerance`` outside the cylinder."""
    n = np.pi / np.arccos(radius / (radius + tolerance))
    return int(min(64, max(6, np.ceil(n))))


def _origin(elem: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if elem is None:
        return T
    xyz = [float(v) for v in elem.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in elem.get("rpy", "0 0 0").split()]
    T[:3, :3] = matrix_from_rpy(*rpy)
    T[:3, 3] = xyz
    return T


@dataclass(frozen=True)
class CollisionShape:
    """One ``<collision>``: kind, size (box xyz; cylinder radius, length; sphere radius), pose."""

    kind: str
    size: tuple[float, ...]
    pose: np.ndarray  # link frame <- shape frame
    mesh_file: Path | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def local_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) in the shape's own frame, containing the true shape (kept on disk
        between commands: :mod:`bench.geometry.shape_cache`)."""
        if self.kind == "mesh" and self.mesh_file is None:
            raise ValueError("mesh collision without a filename")
        key = mesh_key(self.kind, self.size, self.scale, self.mesh_file)
        return cached_mesh(key, self._make_mesh)

    def _make_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        import trimesh  # heavy: loaded only when a mesh is made

        if self.kind == "box":
            m = trimesh.creation.box(extents=self.size)
        elif self.kind == "cylinder":
            r, length = self.size
            n = cylinder_sections(r)
            m = trimesh.creation.cylinder(radius=r / np.cos(np.pi / n), height=length, sections=n)
        elif self.kind == "sphere":
            m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
            # scale so every face plane clears the unit sphere: the mesh contains the ball
            tri = m.triangles
            normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
            inner = np.abs(np.einsum("ij,ij->i", normals, tri[:, 0])).min()
            m.apply_scale(self.size[0] / inner)
        elif self.kind == "mesh":
            m = trimesh.load(self.mesh_file, force="mesh")
            m.apply_scale(self.scale)
        else:
            raise ValueError(f"unknown collision geometry {self.kind!r}")
        return np.asarray(m.vertices, dtype=float), np.asarray(m.faces)

    def triangles(self) -> np.ndarray:
        """Triangles (n, 3, 3) in the link frame, degenerate ones dropped."""
        v, f = self.local_mesh()
        v = v @ self.pose[:3, :3].T + self.pose[:3, 3]
        tris = v[f]
        area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        return tris[area > 1e-14]


def parse_collisions(urdf: Path) -> dict[str, list[CollisionShape]]:
    """Link name → its collision shapes (links without any are left out)."""
    urdf = Path(urdf)
    root = ET.parse(urdf).getroot()
    out: dict[str, list[CollisionShape]] = {}
    for link in root.findall("link"):
        shapes = []
        for col in link.findall("collision"):
            geom = col.find("geometry")
            if geom is None or len(geom) == 0:
                raise ValueError(f"{urdf.name}: link {link.get('name')} has a collision "
                                 "without geometry")
            g = geom[0]
            pose = _origin(col.find("origin"))
            if g.tag == "box":
                shapes.append(CollisionShape("box", tuple(float(v) for v in g.get("size").split()),
                                             pose))
            elif g.tag == "cylinder":
                shapes.append(CollisionShape("cylinder", (float(g.get("radius")),
                                                          float(g.get("length"))), pose))
            elif g.tag == "sphere":
                shapes.append(CollisionShape("sphere", (float(g.get("radius")),), pose))
            elif g.tag == "mesh":
                scale = tuple(float(v) for v in g.get("scale", "1 1 1").split())
                shapes.append(CollisionShape("mesh", (), pose, urdf.parent / g.get("filename"),
                                             scale))  # type: ignore[arg-type]
            else:
                raise ValueError(f"{urdf.name}: link {link.get('name')}: unsupported collision "
                                 f"geometry <{g.tag}>")
        if shapes:
            out[link.get("name")] = shapes
    return out


@dataclass(frozen=True)
class JointSpec:
    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray


def parse_joints(urdf: Path) -> list[JointSpec]:
    """The URDF's joints in file order."""
    root = ET.parse(Path(urdf)).getroot()
    out = []
    for j in root.findall("joint"):
        axis = j.find("axis")
        out.append(JointSpec(j.get("name"), j.get("type"), j.find("parent").get("link"),
                             j.find("child").get("link"), _origin(j.find("origin")),
                             np.array([float(v) for v in (axis.get("xyz").split() if axis is not None
                                                          else (1, 0, 0))])))
    return out
