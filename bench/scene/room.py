"""The CT room: the arc-and-train robot's URDF, the gantry, the bed and the phantom.

Everything here is generated from :class:`ArcTrainParams` and :class:`SceneParams`
by ``hilbench urdf build``; the files under ``urdf/`` are its output, and a test
holds them equal to what these functions write.

Scene choices (seed 000 section 3 gives the bore and the bed width only):
the gantry is a torus with a 70 cm bore and a 15 cm tube radius, its axis along
X through the isocentre 15 cm above the bed top at the bed's centre line, its
scan plane at X = 0 (the home needle plane); the bed is 40 cm wide, 2 m long
and 5 cm thick; the phantom is a soft block whose top face holds Target 1's
entry point (66 mm high). The phantom has no collision shape because the
needle must pass through it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.geometry.shape_cache import cached_mesh, mesh_key
from bench.kinematics.arc_train import TARGET_1, ArcTrainParams, build_chain
from bench.paths import URDF_DIR
from bench.scene.urdf_writer import LinkSpec, Shape, chain_to_urdf, next_joint_offsets, segment, stand_urdf
from bench.scene.zerobot_urdf import zerobot_urdf
from drivers.pybullet.backend import SceneObject

SERVO_MASS = 0.082  # kg, Dynamixel XM430-W350
SERVO_BOX = (0.0285, 0.0465, 0.034)  # m


@dataclass(frozen=True)
class SceneParams:
    bore_radius: float = 0.350
    gantry_tube_radius: float = 0.150
    isocentre_height: float = 0.150
    bed_length: float = 2.0
    bed_thickness: float = 0.05
    bed_x_min: float = -1.2
    phantom_size: tuple[float, float, float] = (0.15, 0.20, 0.066)
    phantom_origin: tuple[float, float] = (-0.075, 0.0)  # X, Y of its corner

    def gantry_centre(self, bed_width: float) -> np.ndarray:
        return np.array([0.0, bed_width / 2, self.isocentre_height])


# Link masses (kg) beyond their servo, 3D-printed ABS and aluminium parts.
LINK_MASS = {
    "train": 0.25, "theta3": 0.05, "theta4": 0.08, "theta5": 0.12, "theta6": 0.07,
    "theta7": 0.03, "theta8": 0.05, "d9": 0.10, "d10": 0.03,
}
HAS_SERVO = {"train", "theta3", "theta4", "theta5", "theta6", "theta7", "theta8", "d9", "d10"}


def _link_spec(name: str, next_joint: np.ndarray, p: ArcTrainParams) -> LinkSpec:
    servo_m = SERVO_MASS if name in HAS_SERVO else 0.0
    m_link = LINK_MASS[name]
    shapes: list[Shape] = []
    if name == "train":
        # The carriage sits on the arc (at the end of the radius), not at the centre.
        T = np.eye(4)
        T[:3, 3] = next_joint
        shapes.append(Shape("box", (0.03, 0.07, 0.06), T, (0.2, 0.45, 0.8, 1.0)))
        com = tuple(next_joint)
        box = (0.06, 0.07, 0.06)
    else:
        if name.startswith("theta"):
            shapes.append(Shape("box", SERVO_BOX, np.eye(4), (0.15, 0.15, 0.15, 1.0)))
        if np.linalg.norm(next_joint) > 1e-6:
            shapes.append(segment(next_joint, 0.010))
        total = servo_m + m_link
        com = tuple(m_link * next_joint / 2 / total)
        box = tuple(np.abs(next_joint) + 0.04)
    return LinkSpec(tuple(shapes), servo_m + m_link, com, box)  # type: ignore[arg-type]


def arc_train_urdf(p: ArcTrainParams = ArcTrainParams()) -> str:
    chain = build_chain(p)
    offsets = next_joint_offsets(chain)
    base = LinkSpec(mesh_visual="meshes/arc_rail.obj")
    links = [base] + [_link_spec(r.name, offsets[i + 1], p) for i, r in enumerate(chain.rows)]
    # The d10 link carries the needle itself, from the guide to the tip.
    d10 = links[-1]
    needle = segment(np.array([0.0, 0.0, p.needle_length]), 0.0006, (0.85, 0.85, 0.9, 1.0))
    carriage = Shape("box", (0.02, 0.02, 0.03), np.eye(4), (0.2, 0.45, 0.8, 1.0))
    links[-1] = LinkSpec((carriage, needle), d10.mass, (0.0, 0.0, 0.0), (0.03, 0.03, 0.04))
    tip = LinkSpec((Shape("sphere", (0.0015,), np.eye(4), (0.9, 0.1, 0.1, 1.0), False),),
                   0.001, (0.0, 0.0, 0.0), (0.003, 0.003, 0.003))
    return chain_to_urdf("arc_train", chain, links, tip)


def arc_rail_mesh(p: ArcTrainParams = ArcTrainParams(), tube: float = 0.012,
                  n_arc: int = 48, n_tube: int = 12):
    """The arc as a tube of radius ``tube`` along the train's path (vertices, faces)."""
    a = np.linspace(p.psi, np.pi - p.psi, n_arc)
    phi = np.linspace(0.0, 2 * np.pi, n_tube, endpoint=False)
    A, P = np.meshgrid(a, phi, indexing="ij")
    u = np.stack([np.zeros_like(A), -np.cos(A), np.sin(A)], axis=-1)
    x_hat = np.array([1.0, 0.0, 0.0])
    centre = np.array([p.arc_x, p.arc_radius, 0.0])
    rr = (p.arc_radius + tube * np.cos(P))[..., None]
    verts = centre + rr * u + (tube * np.sin(P))[..., None] * x_hat
    verts = verts.reshape(-1, 3)
    faces = []
    for i in range(n_arc - 1):
        for j in range(n_tube):
            k, kn = i * n_tube + j, i * n_tube + (j + 1) % n_tube
            faces += [(k, k + n_tube, kn), (kn, k + n_tube, kn + n_tube)]
    return verts, np.array(faces)


def gantry_mesh(s: SceneParams = SceneParams(), bed_width: float = ArcTrainParams().bed_width,
                major_sections: int = 96, minor_sections: int = 32):
    """The CT gantry: a torus around the X axis with the bore radius of seed 000 (70 cm) (kept on
    disk between commands: :mod:`bench.geometry.shape_cache`)."""
    major, minor = s.bore_radius + s.gantry_tube_radius, s.gantry_tube_radius
    centre = s.gantry_centre(bed_width)

    def make() -> tuple[np.ndarray, np.ndarray]:
        import trimesh  # heavy: trimesh, only when the mesh is made

        ring = trimesh.creation.torus(major, minor, major_sections=major_sections,
                                      minor_sections=minor_sections)
        T = np.eye(4)
        T[:3, :3] = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # z -> X
        T[:3, 3] = centre
        ring.apply_transform(T)
        return np.asarray(ring.vertices), np.asarray(ring.faces)

    key = mesh_key("gantry torus about X", (major, minor, major_sections, minor_sections, *centre))
    return cached_mesh(key, make)


def obj_text(verts: np.ndarray, faces: np.ndarray) -> str:
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def _static_urdf(name: str, body: str, mass_note: str = "") -> str:
    return ('<?xml version="1.0"?>\n<!-- Generated by `hilbench urdf build`; do not edit. -->\n'
            f'<robot name="{name}">\n  <link name="{name}_link">\n'
            '    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="0"/>'
            '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>\n'
            f"{body}  </link>\n</robot>\n")


def gantry_urdf() -> str:
    geom = '<geometry><mesh filename="meshes/ct_gantry.obj"/></geometry>'
    body = (f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/>{geom}<material name="gantry">'
            '<color rgba="0.92 0.92 0.9 0.6"/></material></visual>\n'
            f'    <collision concave="yes"><origin xyz="0 0 0" rpy="0 0 0"/>{geom}</collision>\n')
    return _static_urdf("ct_gantry", body)


def bed_urdf(p: ArcTrainParams = ArcTrainParams(), s: SceneParams = SceneParams()) -> str:
    cx = s.bed_x_min + s.bed_length / 2
    box = f'<box size="{s.bed_length} {p.bed_width} {s.bed_thickness}"/>'
    o = f'<origin xyz="{cx} {p.bed_width / 2} {-s.bed_thickness / 2}" rpy="0 0 0"/>'
    body = (f'    <visual>{o}<geometry>{box}</geometry><material name="bed">'
            '<color rgba="0.35 0.35 0.38 1"/></material></visual>\n'
            f"    <collision>{o}<geometry>{box}</geometry></collision>\n")
    return _static_urdf("ct_bed", body)


def phantom_urdf(s: SceneParams = SceneParams()) -> str:
    sx, sy, sz = s.phantom_size
    x0, y0 = s.phantom_origin
    o = f'<origin xyz="{x0 + sx / 2} {y0 + sy / 2} {sz / 2}" rpy="0 0 0"/>'
    tip = TARGET_1.tip
    body = (f'    <visual>{o}<geometry><box size="{sx} {sy} {sz}"/></geometry>'
            '<material name="tissue"><color rgba="0.95 0.75 0.65 0.45"/></material></visual>\n'
            f'    <visual><origin xyz="{tip[0]!r} {tip[1]!r} {tip[2]!r}" rpy="0 0 0"/>'
            '<geometry><sphere radius="0.003"/></geometry><material name="target">'
            '<color rgba="0.1 0.8 0.2 1"/></material></visual>\n')
    return _static_urdf("phantom", body)


def generated_files(p: ArcTrainParams = ArcTrainParams(),
                    s: SceneParams = SceneParams()) -> dict[str, str]:
    """Relative path under ``urdf/`` → file text, for every generated scene file."""
    return {
        "arc_train.urdf": arc_train_urdf(p),
        "meshes/arc_rail.obj": obj_text(*arc_rail_mesh(p)),
        "ct_gantry.urdf": gantry_urdf(),
        "meshes/ct_gantry.obj": obj_text(*gantry_mesh(s, p.bed_width)),
        "ct_bed.urdf": bed_urdf(p, s),
        "phantom.urdf": phantom_urdf(s),
        "zerobot.urdf": zerobot_urdf(),
        "test_stand_xl330.urdf": stand_urdf(),
    }


def write_scene(out_dir: Path = URDF_DIR) -> list[Path]:
    written = []
    for rel, text in generated_files().items():
        path = out_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        written.append(path)
    return written


def default_scene(urdf_dir: Path | None = None) -> list[SceneObject]:
    """The CT room of seed 000 as generated in ``urdf/``: the gantry (out of the contact pairs), bed, phantom."""
    d = Path(urdf_dir) if urdf_dir else URDF_DIR
    return [SceneObject(d / "ct_gantry.urdf", collide=False), SceneObject(d / "ct_bed.urdf"),
            SceneObject(d / "phantom.urdf")]
