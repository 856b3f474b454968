"""Write a URDF from a DH chain, so the physics scene and the DH model share one parameter set.

URDF link ``i`` sits at DH frame ``i`` minus the row's trailing ``Tx(a)·Rx(alpha)``
(see :func:`bench.kinematics.dh.joint_split`); the trailing part moves into the
next joint's origin. The link frames PyBullet reports therefore satisfy
``F_i = L_i · Tx(a_i)·Rx(alpha_i)``, which the tests hold to 1e-6.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np

from bench.kinematics.dh import DHChain, joint_split, rpy_from_matrix


@dataclass(frozen=True)
class Shape:
    """A primitive in a link's frame: 'box' (size xyz), 'cylinder' (radius, length along z) or 'sphere'."""

    kind: str
    size: tuple[float, ...]
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.75, 1.0)
    collide: bool = True

    def xml(self) -> str:
        if self.kind == "box":
            geom = f'<box size="{_f(self.size[0])} {_f(self.size[1])} {_f(self.size[2])}"/>'
        elif self.kind == "cylinder":
            geom = f'<cylinder radius="{_f(self.size[0])}" length="{_f(self.size[1])}"/>'
        elif self.kind == "sphere":
            geom = f'<sphere radius="{_f(self.size[0])}"/>'
        elif self.kind == "mesh":
            raise ValueError("mesh shapes are written with MeshShape")
        else:
            raise ValueError(f"unknown shape kind {self.kind!r}")
        return geom


@dataclass(frozen=True)
class LinkSpec:
    """Geometry and mass of one URDF link; inertia is that of a solid box around the shapes."""

    shapes: tuple[Shape, ...] = ()
    mass: float = 0.0
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia_box: tuple[float, float, float] = (0.02, 0.02, 0.02)
    mesh_visual: str | None = None  # a mesh file (relative to the URDF) drawn in addition


def _f(x: float) -> str:
    return repr(float(x))


def _origin(T: np.ndarray) -> str:
    r, p, y = rpy_from_matrix(T[:3, :3])
    x, yy, z = T[:3, 3]
    return f'<origin xyz="{_f(x)} {_f(yy)} {_f(z)}" rpy="{_f(r)} {_f(p)} {_f(y)}"/>'


def segment(p: np.ndarray, radius: float, rgba=(0.75, 0.75, 0.8, 1.0)) -> Shape:
    """A cylinder from the link origin to point ``p`` (link frame)."""
    p = np.asarray(p, dtype=float)
    length = float(np.linalg.norm(p))
    z = p / length
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p / 2
    return Shape("cylinder", (radius, length), T, rgba)


def _inertial(spec: LinkSpec) -> str:
    m = spec.mass
    if m <= 0:
        return ('<inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="0"/>'
                '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>')
    a, b, c = spec.inertia_box
    ixx, iyy, izz = m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12
    cx, cy, cz = spec.com
    return (f'<inertial><origin xyz="{_f(cx)} {_f(cy)} {_f(cz)}" rpy="0 0 0"/>'
            f'<mass value="{_f(m)}"/><inertia ixx="{_f(ixx)}" ixy="0" ixz="0" '
            f'iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/></inertial>')


def _link(name: str, spec: LinkSpec) -> str:
    parts = [f"  <link name={quoteattr(name)}>", "    " + _inertial(spec)]
    for s in spec.shapes:
        mat = ('<material name="m_{}_{}_{}"><color rgba="{} {} {} {}"/></material>'
               .format(*(int(255 * v) for v in s.rgba[:3]), *s.rgba))
        parts.append(f"    <visual>{_origin(s.pose)}<geometry>{s.xml()}</geometry>{mat}</visual>")
        if s.collide:
            parts.append(f"    <collision>{_origin(s.pose)}<geometry>{s.xml()}</geometry></collision>")
    if spec.mesh_visual:
        parts.append(f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename='
                     f'{quoteattr(spec.mesh_visual)}/></geometry><material name="rail">'
                     f'<color rgba="0.3 0.35 0.45 1"/></material></visual>')
    parts.append("  </link>")
    return "\n".join(parts)


def next_joint_offsets(chain: DHChain) -> list[np.ndarray]:
    """For URDF link i (0 = base), the position of the next joint (or tool) in link i's frame."""
    out = []
    trails = [chain.base] + [joint_split(r)[1] for r in chain.rows]
    leads = [joint_split(r)[0] for r in chain.rows] + [chain.tool]
    for trail, lead in zip(trails, leads):
        out.append((trail @ lead)[:3, 3])
    return out


def chain_to_urdf(robot: str, chain: DHChain, links: list[LinkSpec], tool_link: LinkSpec,
                  tool_name: str = "needle_tip") -> str:
    """URDF text: ``base_link`` (world), one link per DH row named after its joint, and the tool."""
    if len(links) != len(chain.rows) + 1:
        raise ValueError(f"need {len(chain.rows) + 1} link specs (base + one per joint)")
    xml = ['<?xml version="1.0"?>',
           "<!-- Generated by `hilbench urdf build` from bench/kinematics; do not edit. -->",
           f"<robot name={quoteattr(robot)}>", _link("base_link", links[0])]
    parent = "base_link"
    trail = chain.base
    for row, spec in zip(chain.rows, links[1:]):
        lead, next_trail = joint_split(row)
        child = f"{row.name}_link"
        xml.append(_link(child, spec))
        xml.append(
            f"  <joint name={quoteattr(row.name)} type={quoteattr(row.kind)}>"
            f"<parent link={quoteattr(parent)}/><child link={quoteattr(child)}/>"
            f"{_origin(trail @ lead)}<axis xyz=\"0 0 1\"/>"
            f'<limit lower="{_f(row.lower)}" upper="{_f(row.upper)}" '
            f'effort="{_f(row.effort)}" velocity="{_f(row.velocity)}"/>'
            f'<dynamics damping="0.0" friction="0.0"/></joint>')
        parent, trail = child, next_trail
    xml.append(_link(tool_name, tool_link))
    xml.append(f"  <joint name={quoteattr(tool_name + '_joint')} type=\"fixed\">"
               f"<parent link={quoteattr(parent)}/><child link={quoteattr(tool_name)}/>"
               f"{_origin(trail @ chain.tool)}</joint>")
    xml.append("</robot>")
    return "\n".join(xml) + "\n"


#: BAM's XL330 pendulum stand (Rhoban, "Better Actuator Models"): the mass and arm of its logs.
STAND_MASS_KG = 0.49
STAND_LENGTH_M = 0.1


def stand_urdf(mass: float = STAND_MASS_KG, length: float = STAND_LENGTH_M, arm_mass: float = 0.0) -> str:
    """A one-servo pendulum stand: a fixed base holding the servo, the revolute joint ``pendulum``
    about X, a mass ``mass`` (kg) at ``length`` (m) below the shaft at q = 0 on an arm of
    ``arm_mass`` (kg, uniform). Gravity's torque is −(m + m_arm/2)·g·L·sin q and the inertia
    about the shaft m·L² + m_arm·L²/3, as the stand's analytic dynamics (bench/stand/simulate.py)
    step it; a test holds PyBullet's to them."""
    bob = 0.01  # m, the radius of the drawn mass (its own inertia is kept out: a point mass)
    arm_izz = arm_mass * length ** 2 / 12.0  # a rod about its centre, across its length
    total = mass + arm_mass
    com = (mass * length + arm_mass * length / 2.0) / total if total > 0 else 0.0
    # inertia about the centre of mass (parallel axis back from the shaft)
    ixx = mass * length ** 2 + arm_mass * length ** 2 / 3.0 - total * com ** 2
    return ('<?xml version="1.0"?>\n<!-- Generated by `hilbench urdf build`; do not edit. -->\n'
            '<robot name="test_stand">\n'
            '  <link name="stand_base">\n'
            '    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="0"/>'
            '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>\n'
            '    <visual><origin xyz="0 0.03 0" rpy="0 0 0"/><geometry><box size="0.034 0.02 0.0235"/></geometry>'
            '<material name="servo"><color rgba="0.15 0.15 0.15 1"/></material></visual>\n'
            '  </link>\n'
            '  <joint name="pendulum" type="revolute">\n'
            '    <parent link="stand_base"/><child link="pendulum_link"/>\n'
            '    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/>\n'
            f'    <limit lower="{_f(-np.pi)}" upper="{_f(np.pi)}" effort="10" velocity="100"/>\n'
            '  </joint>\n'
            '  <link name="pendulum_link">\n'
            f'    <inertial><origin xyz="0 0 {_f(-com)}" rpy="0 0 0"/><mass value="{_f(total)}"/>'
            f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(ixx + 1e-9)}" iyz="0" izz="{_f(arm_izz + 1e-9)}"/>'
            '</inertial>\n'
            f'    <visual><origin xyz="0 0 {_f(-length / 2)}" rpy="0 0 0"/><geometry>'
            f'<cylinder radius="0.004" length="{_f(length)}"/></geometry>'
            '<material name="arm"><color rgba="0.7 0.7 0.75 1"/></material></visual>\n'
            f'    <visual><origin xyz="0 0 {_f(-length)}" rpy="0 0 0"/><geometry><sphere radius="{_f(bob)}"/>'
            '</geometry><material name="mass"><color rgba="0.8 0.3 0.2 1"/></material></visual>\n'
            '  </link>\n'
            '</robot>\n')
