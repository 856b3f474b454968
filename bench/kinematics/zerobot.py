"""Zerobot, the 6-DOF CT-guided needle-puncturing robot of seed 001 (Matsuno et al.).

Joints (section 2): q1, q2, q3 linear stages (m), q4 and q5 rotary joints that
set the needle's posture (rad), q6 the needle insertion along the axis q4 and
q5 chose (m). The chain is Table 1 as printed, in modified (Craig) DH
(eq 1), and the world pose of the needle tip is eq 3.

Frame: the bed frame of the README (origin on the bed top at its left edge,
X along the bed towards the gantry, Y across the bed, Z up) is the paper's
world frame Σ_W. With α3 = +90° (the robot in front of the gantry, eq 2) Σ_W
and the paper's axes agree: q1 lifts the arm along +Z, q2 moves it along −X
(away from the gantry), q3 along −Y, q4 turns the whole end-effector about
its long X-parallel beam (the insertion angle in the axial plane, what the
CT slice shows) and q5 tilts the needle holder out of that plane (eq 3's
third column is the needle direction ``(−S5·Sα3, S4·C5·Sα3, −C4·C5)``), so
in the vocabulary of :mod:`bench.kinematics.needle`

    insertion angle = Sα3 · q4,        tilt = −Sα3 · q5.

With α3 = −90° (the robot mounted behind the gantry) the beam points along
−X and both signs flip; everything below works for either.

The paper leaves out every length. Chosen here (see :class:`ZerobotParams`):
the end-effector beam l1 = 900 mm (the paper: "approximately 900 mm"), the
drop from the beam axis to the needle-holder pivot l2 = 120 mm, the needle
15 mm beside that pivot (l7), 80 mm from the pivot to the needle guide (l9)
and a 60 mm needle stick-out below the guide at q6 = 0 (l_E); l3, l4, l5,
l6 place home (q1 = 0.15 m, q2 = 0.20 m, q3 = 0.35 m, q4 = q5 = q6 = 0) with
the needle tip 100 mm above the bed centre line in the scan plane,
(0, 200, 100) mm, pointing straight down — the arc robot's home needle. The
needle is 1.1 mm in diameter (section 4.3) and 160 mm long.

Needle vocabulary: the *entry* is where the tip is at q6 = 0 (the needle
touching the skin); the tip is ``entry + q6 · direction`` and the depth is q6.
Because q1–q3 are Cartesian stages ahead of the wrist, inverse kinematics and
the remote-centre motion of section 2.2 are closed form: q4, q5 from the
direction, then one 3×3 linear solve for q1–q3.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from bench.kinematics.dh import DHChain, DHRow, check_rows
from bench.kinematics.needle import (
    NeedlePose,
    NeedleTarget,
    UnreachableError,
    angles_of,
    needle_direction,
    pose_from_axis,
)

__all__ = ["JOINTS", "ZerobotParams", "ZerobotRobot", "build_chain", "eq3_tip_pose",
           "NeedlePose", "NeedleTarget", "UnreachableError"]

DEG = np.pi / 180.0
JOINTS = ("q1", "q2", "q3", "q4", "q5", "q6")
_JOINT_ROLE = {"q1": "the vertical stage", "q2": "the X stage", "q3": "the Y stage",
               "q4": "insertion-angle roll", "q5": "needle tilt", "q6": "needle insertion"}


@dataclass(frozen=True)
class ZerobotParams:
    """One parameter set for the DH model and the URDF (SI units).

    Table 1 names l1, l2, l3 and eq 3 adds l4…l7, l9 and l_E without values;
    the values here are chosen (module docstring). Strokes: the linear stages
    cover the CT bore around the bed (q3 moves the needle across Y ∈
    [−150, 550] mm, the bore's full width at the isocentre); q4 ±60° and
    q5 ±30° cover the paper's postures (±30°, ±15°); q6 inserts up to 100 mm.
    """

    l1: float = 0.900  # q4 axis: head to the far end of the end-effector beam
    l2: float = 0.120  # beam axis to the needle-holder pivot (the q5 axis)
    l3: float = 0.050  # q3 zero offset (Table 1: d3 = q3 - l3)
    l4: float = 0.715  # eq 3 world offsets of frame 0: x_W = -r0y - l4,
    l5: float = -0.500  # y_W = r0x - l5,
    l6: float = 0.210  # z_W = r0z + l6
    l7: float = 0.015  # needle axis beside the pivot (along -x6)
    l9: float = 0.080  # pivot to the needle guide, along the needle
    l_e: float = 0.060  # guide to the tip at q6 = 0
    alpha3: float = 90.0 * DEG  # Table 1: +90° in front of the gantry, -90° behind it
    needle_length: float = 0.160
    needle_diameter: float = 0.0011  # section 4.3
    q1_range: tuple[float, float] = (0.0, 0.35)
    q2_range: tuple[float, float] = (0.0, 0.60)
    q3_range: tuple[float, float] = (0.0, 0.70)
    q4_limit: float = 60.0 * DEG
    q5_limit: float = 30.0 * DEG
    q6_stroke: float = 0.100
    home_linear: tuple[float, float, float] = (0.15, 0.20, 0.35)
    # Ball-screw stages and geared rotary joints (typical for a clinical
    # positioner; the paper gives none): speed and force/torque limits.
    linear_velocity: float = 0.05
    linear_effort: float = 300.0
    rotary_velocity: float = 0.5
    rotary_effort: float = 20.0
    insertion_velocity: float = 0.02
    insertion_effort: float = 40.0

    def __post_init__(self) -> None:
        if abs(abs(self.alpha3) - np.pi / 2) > 1e-12:
            raise ValueError(f"alpha3 must be +90° or -90° (Table 1, eq 2), got "
                             f"{np.degrees(self.alpha3):.6g}°")

    @property
    def s_alpha3(self) -> float:
        """S_α3 = ±1 (C_α3 = 0, as eq 2 notes)."""
        return float(np.sign(np.sin(self.alpha3)))

    @property
    def tip_offset(self) -> float:
        """l9 + l_E: pivot to tip at q6 = 0 along the needle."""
        return self.l9 + self.l_e


def world_base(p: ZerobotParams) -> np.ndarray:
    """Eq 3's W_T_0: x_W = −r0y − l4, y_W = r0x − l5, z_W = r0z + l6."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T[:3, 3] = (-p.l4, -p.l5, p.l6)
    return T


def build_chain(p: ZerobotParams = ZerobotParams()) -> DHChain:
    """Table 1 row by row (modified DH), from the bed frame to the needle tip (eq 3)."""
    m = "modified"
    h1, h2, h3 = p.home_linear
    rows = (
        DHRow("q1", "prismatic", 0.0, 0.0, 0.0, 0.0, *p.q1_range, h1,
              p.linear_velocity, p.linear_effort, m),
        DHRow("q2", "prismatic", -np.pi / 2, 0.0, 0.0, -np.pi / 2, *p.q2_range, h2,
              p.linear_velocity, p.linear_effort, m),
        DHRow("q3", "prismatic", 0.0, -p.l3, 0.0, np.pi / 2, *p.q3_range, h3,
              p.linear_velocity, p.linear_effort, m),
        DHRow("q4", "revolute", np.pi, p.l1, 0.0, p.alpha3, -p.q4_limit, p.q4_limit, 0.0,
              p.rotary_velocity, p.rotary_effort, m),
        DHRow("q5", "revolute", np.pi / 2, 0.0, p.l2, -np.pi / 2, -p.q5_limit, p.q5_limit, 0.0,
              p.rotary_velocity, p.rotary_effort, m),
        DHRow("q6", "prismatic", 0.0, 0.0, 0.0, np.pi / 2, 0.0, p.q6_stroke, 0.0,
              p.insertion_velocity, p.insertion_effort, m),
    )
    check_rows(rows)
    tool = np.eye(4)  # eq 3: Σ_E is Σ_6 moved -l7 along x6 and l9 + l_E along z6
    tool[:3, 3] = (-p.l7, 0.0, p.tip_offset)
    return DHChain(base=world_base(p), rows=rows, tool=tool)


def eq3_tip_pose(q: np.ndarray, p: ZerobotParams = ZerobotParams()) -> np.ndarray:
    """Eq 3 as printed: W_T_E for joint vectors of shape (..., 6) (kept as a check on the chain)."""
    q = np.asarray(q, dtype=float)
    q1, q2, q3, q4, q5, q6 = np.moveaxis(q, -1, 0)
    s, S4, C4, S5, C5 = p.s_alpha3, np.sin(q4), np.cos(q4), np.sin(q5), np.cos(q5)
    n = q6 + p.l9 + p.l_e
    rx = p.l3 - q3 + p.l2 * S4 * s + n * S4 * C5 * s + p.l7 * S4 * S5 * s
    ry = n * S5 * s + q2 - p.l1 * s - p.l7 * s * C5
    rz = q1 - p.l2 * C4 - n * C4 * C5 - p.l7 * S5 * C4
    T = np.zeros(q.shape[:-1] + (4, 4))
    T[..., 0, :] = np.stack([-C5 * s, np.zeros_like(q4), -S5 * s, -ry - p.l4], -1)
    T[..., 1, :] = np.stack([-S4 * S5 * s, C4 * s, S4 * C5 * s, rx - p.l5], -1)
    T[..., 2, :] = np.stack([C4 * S5, S4, -C4 * C5, rz + p.l6], -1)
    T[..., 3, 3] = 1.0
    return T


@dataclass
class ZerobotRobot:
    """Kinematics of Zerobot: FK (eq 3), IK to a needle target, remote-centre motion."""

    params: ZerobotParams = field(default_factory=ZerobotParams)

    name = "zerobot"

    def __post_init__(self) -> None:
        self.chain = build_chain(self.params)
        # q1-q3 translate everything after them along fixed world axes, so
        # the entry point is c(q4, q5) + A·(q1, q2, q3) with A constant.
        F = self.chain.frames(np.zeros(6))
        self._stage_axes = np.column_stack([F[1][:3, 2], F[2][:3, 2], F[3][:3, 2]])
        self._stage_inv = np.linalg.inv(self._stage_axes)

    @property
    def joint_names(self) -> list[str]:
        return list(JOINTS)

    def joint_vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Joint dict → vector, missing joints at home; unknown names refused."""
        return self.chain.vector_from(values, "zerobot")

    # -- forward kinematics ------------------------------------------------

    def tip_pose(self, q: np.ndarray) -> np.ndarray:
        """World pose of Σ_E (the needle tip), shape (..., 4, 4): eq 3 through the DH chain."""
        return self.chain.tool_pose(np.asarray(q, dtype=float))

    def needle(self, q: np.ndarray) -> NeedlePose:
        """Forward kinematics of one configuration to the needle."""
        q = np.asarray(q, dtype=float)
        T = self.tip_pose(q)
        axis = T[:3, 2]
        return pose_from_axis(T[:3, 3] - q[5] * axis, axis, float(q[5]))

    def needle_batch(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised FK: (entry, tip, angle) for q of shape (N, 6)."""
        q = np.asarray(q, dtype=float)
        T = self.tip_pose(q)
        axis = T[:, :3, 2]
        tip = T[:, :3, 3]
        return tip - q[:, 5:6] * axis, tip, np.arctan2(axis[:, 1], -axis[:, 2])

    def posture_for(self, angle: float, tilt: float) -> tuple[float, float]:
        """(q4, q5) that point the needle at insertion angle ``angle`` and ``tilt``."""
        s = self.params.s_alpha3
        return s * angle, -s * tilt

    # -- inverse kinematics ------------------------------------------------

    def _entry_offset(self, q4: float, q5: float) -> np.ndarray:
        """Entry point (tip at q6 = 0) with q1 = q2 = q3 = 0."""
        return self.tip_pose(np.array([0.0, 0.0, 0.0, q4, q5, 0.0]))[:3, 3]

    def place(self, entry: np.ndarray, angle: float, tilt: float, depth: float) -> np.ndarray:
        """Joint values putting the tip at q6 = 0 on ``entry`` with the given direction.

        Raises :class:`UnreachableError` naming the joint whose limit fails.
        """
        p = self.params
        lo, hi = self.chain.lower, self.chain.upper
        entry = np.asarray(entry, dtype=float)
        if entry.shape != (3,) or not np.all(np.isfinite(entry)) or not np.isfinite(angle) \
                or not np.isfinite(tilt) or not np.isfinite(depth):
            raise UnreachableError(f"target is not finite: entry {entry}, angle {angle}, "
                                   f"tilt {tilt}, depth {depth}")
        if not 0.0 <= depth <= p.q6_stroke:
            raise UnreachableError(
                f"insertion depth {depth * 1e3:.1f} mm is outside q6's stroke "
                f"[0, {p.q6_stroke * 1e3:.0f}] mm")
        q4, q5 = self.posture_for(angle, tilt)
        for name, v, i in (("insertion angle", q4, 3), ("tilt", q5, 4)):
            if not lo[i] - 1e-12 <= v <= hi[i] + 1e-12:
                what = angle if name == "insertion angle" else tilt
                raise UnreachableError(
                    f"{name} {np.degrees(what):.2f}° needs {JOINTS[i]} = {np.degrees(v):.2f}°, "
                    f"outside its range [{np.degrees(lo[i]):.0f}°, {np.degrees(hi[i]):.0f}°]")
        q123 = self._stage_inv @ (entry - self._entry_offset(q4, q5))
        for i in range(3):
            if not lo[i] - 1e-12 <= q123[i] <= hi[i] + 1e-12:
                raise UnreachableError(
                    f"{JOINTS[i]} ({_JOINT_ROLE[JOINTS[i]]}) would be {q123[i] * 1e3:.1f} mm, "
                    f"outside its stroke [{lo[i] * 1e3:.0f}, {hi[i] * 1e3:.0f}] mm")
        q = np.array([*np.clip(q123, lo[:3], hi[:3]), q4, q5, depth])
        return q

    def ik(self, target: NeedleTarget) -> np.ndarray:
        """Joint values that put the needle on ``target``; raises UnreachableError."""
        q = self.place(np.asarray(target.entry, dtype=float), float(target.angle),
                       float(target.tilt), float(target.depth))
        pose = self.needle(q)
        err = float(np.max(np.abs(pose.entry - target.entry)))
        err = max(err, float(np.linalg.norm(pose.direction - target.direction)))
        if err > 1e-9:  # never hand back a wrong answer
            raise UnreachableError(f"inverse kinematics did not converge (residual {err:.2e})")
        return q

    def remote_centre(self, q: np.ndarray, angle: float, tilt: float = 0.0) -> np.ndarray:
        """Re-orient the needle about its tip (section 2.2, Fig. 5b).

        Returns joint values with the needle at ``angle``/``tilt`` and the tip
        (at the present insertion q6) where it is now; q1–q3 move to keep it there.
        """
        q = np.asarray(q, dtype=float)
        tip = self.tip_pose(q)[:3, 3]
        depth = float(q[5])
        entry = tip - depth * needle_direction(angle, tilt)
        return self.place(entry, angle, tilt, depth)

    def remote_centre_path(self, q: np.ndarray, angles: np.ndarray,
                           tilts: np.ndarray) -> np.ndarray:
        """:meth:`remote_centre` along a sequence of postures, shape (N, 6)."""
        angles = np.atleast_1d(np.asarray(angles, dtype=float))
        tilts = np.broadcast_to(np.asarray(tilts, dtype=float), angles.shape)
        return np.array([self.remote_centre(q, a, t) for a, t in zip(angles, tilts)])

    def angles(self, q: np.ndarray) -> tuple[float, float]:
        """(insertion angle, tilt) of the needle at ``q``."""
        return angles_of(self.tip_pose(q)[:3, 2])
