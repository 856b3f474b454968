"""Zerobot's URDF: the links' shapes and masses on top of its DH chain.

The paper shows the robot (Fig. 2) but gives no drawing, so the bodies are
chosen boxes in the spirit of the photograph, laid out in the bed frame at
home and carried into each link's frame by the chain, so the URDF and the DH
model stay one parameter set:

* ``base_link``: a column on a floor cart beside the bed (X = −1.05 m,
  Y = 0.80 m, reaching down to a floor 0.8 m below the bed top), far from
  the gantry.
* ``q1_link``: the carriage that rides up the column and the X rail it carries.
* ``q2_link``: the Y arm across the bed, moved along X by q2.
* ``q3_link``: the head on the Y arm, holding the q4 bearing.
* ``q4_link``: the end-effector: a 50 × 50 mm beam along the q4 axis from the
  head to its far end (l1 = 900 mm from the head's joint) and the end block
  (the "upper cover") that hangs from it down past the needle-holder pivot;
  the parallel mechanism keeps these from tilting with q5 (section 3.2).
* ``q5_link``: the needle holder, hinged at the pivot: an arm to the needle
  axis and the guide along the needle.
* ``q6_link``: the needle (1.1 mm, 160 mm long) and the carriage at its back end.
"""

from __future__ import annotations

import numpy as np

from bench.kinematics.dh import translation
from bench.kinematics.zerobot import ZerobotParams, build_chain
from bench.scene.urdf_writer import LinkSpec, Shape, chain_to_urdf

STEEL = (0.55, 0.57, 0.6, 1.0)
COVER = (0.9, 0.9, 0.92, 1.0)
BLUE = (0.2, 0.45, 0.8, 1.0)
NEEDLE = (0.85, 0.85, 0.9, 1.0)

COLUMN_Y = 0.80  # beside the bed (bed top Y in [0, 0.4])
COLUMN_BEHIND_HEAD = 0.135  # the column stands this far behind the head at home
STAGE_ABOVE_AXIS = 0.11  # the Y arm runs this far above the beam axis
BEAM_SECTION = 0.05
HEAD = (0.12, 0.10, 0.14)


def _box(centre, size, rgba=COVER) -> tuple[str, tuple, np.ndarray, tuple]:
    return ("box", tuple(float(s) for s in size), translation(*centre), rgba)


def world_layout(p: ZerobotParams = ZerobotParams()) -> dict[str, list[tuple]]:
    """Each link's shapes in the bed frame at home: (kind, size, world pose, rgba)."""
    chain = build_chain(p)
    F = chain.frames(chain.home)
    s = p.s_alpha3
    head = F[3][:3, 3]  # q4 joint: the head, on the beam axis
    far = F[4][:3, 3]  # far end of the beam (above the pivot)
    pivot = F[5][:3, 3]
    tip = (F[6] @ chain.tool)[:3, 3]
    ax, ay, az = head
    stage_z = az + STAGE_ABOVE_AXIS
    cx, cy = ax - s * COLUMN_BEHIND_HEAD, COLUMN_Y
    q2_travel = np.array(p.q2_range) - p.home_linear[1]
    arm_x = head[0] - s * q2_travel  # X of the head at both ends of q2
    q3_travel = np.array(p.q3_range) - p.home_linear[2]
    head_y = head[1] - q3_travel  # q3 moves the head along -Y
    rail_lo, rail_hi = arm_x.min() - HEAD[0] / 2 - 0.02, arm_x.max() + HEAD[0] / 2 + 0.02
    yarm_lo, yarm_hi = head_y.min() - HEAD[1] / 2 - 0.02, cy - 0.08
    beam_from = ax + s * HEAD[0] / 2
    beam_to = far[0] - s * 0.02
    block_x = far[0] - s * 0.03
    needle_x = tip[0]
    layout = {
        "base_link": [
            _box((cx, cy, 0.0), (0.14, 0.14, 1.60), STEEL),
            _box((cx, cy, -0.76), (0.60, 0.50, 0.08), STEEL),
        ],
        "q1_link": [
            _box((cx, cy, stage_z), (0.20, 0.20, 0.12), BLUE),
            _box(((rail_lo + rail_hi) / 2, cy - 0.11, stage_z), (rail_hi - rail_lo, 0.06, 0.06),
                 STEEL),
        ],
        "q2_link": [
            _box((ax, (yarm_lo + yarm_hi) / 2, stage_z), (0.08, yarm_hi - yarm_lo, 0.06), STEEL),
        ],
        "q3_link": [
            _box((ax, ay, az + 0.01), HEAD, BLUE),
        ],
        "q4_link": [
            _box(((beam_from + beam_to) / 2, ay, az), (abs(beam_to - beam_from), BEAM_SECTION,
                                                       BEAM_SECTION), COVER),
            _box((block_x, ay, (az + BEAM_SECTION / 2 + pivot[2] - 0.015) / 2),
                 (0.04, 0.06, az + BEAM_SECTION / 2 - pivot[2] + 0.015), COVER),
        ],
        "q5_link": [
            _box(((pivot[0] + needle_x) / 2 + s * 0.0025, ay, pivot[2]),
                 (abs(needle_x - pivot[0]) + 0.02, 0.03, 0.03), BLUE),
            _box((needle_x, ay, pivot[2] - p.l9 / 2), (0.016, 0.016, p.l9 - 0.015), BLUE),
        ],
        "q6_link": [
            ("cylinder", (p.needle_diameter / 2, p.needle_length),
             translation(needle_x, ay, tip[2] + p.needle_length / 2), NEEDLE),
            _box((needle_x, ay + 0.02, tip[2] + p.needle_length - 0.005), (0.02, 0.02, 0.03),
                 BLUE),
        ],
    }
    return layout


LINK_MASS = {"q1_link": 3.0, "q2_link": 2.0, "q3_link": 1.5, "q4_link": 1.2, "q5_link": 0.2,
             "q6_link": 0.05}


def _spec(name: str, shapes: list[tuple], link_frame: np.ndarray) -> LinkSpec:
    inv = np.linalg.inv(link_frame)
    out = []
    centres = []
    for kind, size, T_world, rgba in shapes:
        T = inv @ T_world
        out.append(Shape(kind, size, T, rgba))
        centres.append(T[:3, 3])
    mass = LINK_MASS.get(name, 0.0)
    # COM at the first (largest) body; inertia of a box spanning the shapes.
    pts = np.array(centres)
    extent = np.ptp(pts, axis=0) + 0.05
    return LinkSpec(tuple(out), mass, tuple(float(v) for v in pts[0]),
                    tuple(float(v) for v in extent))


def zerobot_urdf(p: ZerobotParams = ZerobotParams()) -> str:
    """The URDF text of Zerobot, from the same parameter set as the DH model."""
    chain = build_chain(p)
    F = chain.frames(chain.home)
    layout = world_layout(p)
    links = [_spec("base_link", layout["base_link"], np.eye(4))]
    for i, row in enumerate(chain.rows):
        name = f"{row.name}_link"
        links.append(_spec(name, layout[name], F[i + 1]))
    tip = LinkSpec((Shape("sphere", (0.0015,), np.eye(4), (0.9, 0.1, 0.1, 1.0), False),),
                   0.001, (0.0, 0.0, 0.0), (0.003, 0.003, 0.003))
    return chain_to_urdf("zerobot", chain, links, tip)
