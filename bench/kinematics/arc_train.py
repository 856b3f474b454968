"""The 9-DOF arc-and-train biopsy robot of seed 000 (Shah & Mishra).

Frame (the *bed frame*, every target and result is expressed in it):
    origin on the bed top, at the bed's left edge (Y = 0), in the plane that
    holds the needle when the robot is at home (X = 0);
    X along the bed towards the gantry, Y across the bed to the right, Z up.
Target 1 of Tables 2–3 is X = 0, Y = 88.2 mm, Z = 66 mm, insertion 30.1 mm
at 47°.

Insertion angle: the needle always lies in a plane X = const (the axial CT
slice, so the doctor sees it in the image; that is what the joint
constraints of eqs 7–9 keep). Its angle is measured in that plane from the
downward vertical (−Z) towards +Y: direction ``(0, sin β, −cos β)``, as the
paper's eqs 5–6 have ``+d10·S8`` in Y and ``−d10·C8`` in Z.

Chain (standard DH, eq 1). Table 1 is used as printed for θ3…θ8, with
three documented repairs where the paper contradicts itself:

1. Table 1's rows for d1 and d2 are two prismatic joints, but the text
   (eqs 10–18) says one train on an arc moves d1 (Z), d2 (Y) and Ω together.
   Here the arc is one revolute joint, ``train``, about an X-parallel axis at
   the arc centre (Y = R, Z = 0): the train at arc angle ε sits at
   ``d1 = R sin(ψ+ε)``, ``d2 = R − R cos(ψ+ε)`` and is tilted by
   ``Ω = ε − Φ/2``, exactly eqs 13–18. Its joint value is ε in rad, from the
   arc's left end.
2. Table 1 gives every row after θ8 zero twist, which would put the needle
   insertion d10 on θ8's own axis (θ8 would spin the needle instead of
   tilting it). Row d9 gets twist −π/2, so d9 slides along X (eq 4) and d10
   runs perpendicular to it, tilted by θ8 (eqs 5–6).
3. The lengths of eqs 4–6 missing from Table 1 (l3, l7…l10, d4…d7) are zero;
   the needle guide-to-tip length (not in the paper) is 100 mm.

Under the constraints θ3 = 0, θ4 = θ7, θ5 = −θ6 (eqs 7–9) Table 1's rows
reduce, in the train's frame, to eqs 4–6:
    radial  = l5 sin θ6
    lateral = −(l4 + l6 + l5 cos θ6) sin θ7
    along X = d3 + d8 + d9 + (l4 + l6 + l5 cos θ6) cos θ7,
so the closed-form inverse (eqs 19–20, and eq 4 for d9) holds for every
train position. The train position is chosen by eq 11 (ε = ΦY/W); where that
position leaves the closed form without an answer the solver searches the arc
for one that has an answer (the only numerical step).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from bench.kinematics.dh import DHChain, DHRow, check_rows, translation
from bench.kinematics.needle import NeedlePose, NeedleTarget, UnreachableError, pose_from_axis

__all__ = ["ArcTrainParams", "ArcTrainRobot", "NeedlePose", "NeedleTarget", "TARGET_1",
           "TABLE3_TARGET", "TABLE3_MEASURED", "table3_deviations", "SERVO_TOL_DEG", "PINION_RADIUS",
           "UnreachableError", "build_chain", "train_pose", "epsilon_from_d2"]

DEG = np.pi / 180.0


@dataclass(frozen=True)
class ArcTrainParams:
    """One parameter set for the DH model and the URDF (SI units).

    Table 1 gives d3, l4, l5, l6, d8 and d9's nominal 4.9 cm. Chosen here:
    the arc radius (20 cm, Table 1's d2 at the top of the arc, so the arc
    spans the 40 cm bed), the arc's angular span Φ = 120° (ψ = 30° each side),
    the stroke of the two prismatic joints (0–100 mm) and the needle length.
    """

    bed_width: float = 0.400  # W, seed 000 section 3
    arc_radius: float = 0.200  # R
    arc_span: float = 120.0 * DEG  # Φ
    d3: float = 0.0102
    l4: float = 0.099
    l5: float = 0.199
    l6: float = 0.107
    d8: float = 0.029
    d9_home: float = 0.049
    d9_stroke: float = 0.100
    d10_stroke: float = 0.100
    needle_length: float = 0.100
    revolute_limit: float = 90.0 * DEG
    # Joint speed and effort limits: Dynamixel XM430-W350 at 12 V (46 rpm no
    # load, 4.1 N·m stall); the prismatic joints are rack-and-pinion (10 mm
    # pinion radius, effort limited for the 3D-printed racks); the train's
    # pinion runs on a rack of radius R.
    revolute_velocity: float = 4.8
    revolute_effort: float = 4.1
    prismatic_velocity: float = 0.048
    prismatic_effort: float = 40.0
    train_velocity: float = 0.5
    train_effort: float = 20.0

    @property
    def psi(self) -> float:
        """ψ: angle between the bed and the arc's left end (arc symmetric about the top)."""
        return np.pi / 2 - self.arc_span / 2

    @property
    def arc_length(self) -> float:
        """G = RΦ (eq 10)."""
        return self.arc_radius * self.arc_span

    @property
    def arm_reach(self) -> float:
        return self.d3 + self.l4 + self.l5 + self.l6 + self.d8

    @property
    def arc_x(self) -> float:
        """X of the arc's plane: home puts the needle in the plane X = 0."""
        return -(self.arm_reach + self.d9_home)


JOINTS = ("train", "theta3", "theta4", "theta5", "theta6", "theta7", "theta8", "d9", "d10")


def build_chain(p: ArcTrainParams = ArcTrainParams()) -> DHChain:
    """The DH chain from the bed frame to the needle tip."""
    # DH frame 0 at the arc centre: x0 = +Z (up), y0 = +Y, z0 = -X, so that a
    # rotation of Omega about z0 swings the train towards +Y for Omega > 0.
    base = translation(p.arc_x, p.arc_radius, 0.0)
    base[:3, :3] = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    lim, rv, re = p.revolute_limit, p.revolute_velocity, p.revolute_effort
    rows = (
        # the train on the arc: theta = epsilon - Phi/2 = Omega
        DHRow("train", "revolute", -p.arc_span / 2, 0.0, p.arc_radius, np.pi,
              0.0, p.arc_span, p.arc_span / 2, p.train_velocity, p.train_effort),
        DHRow("theta3", "revolute", -np.pi / 2, p.d3, 0.0, -np.pi / 2, -lim, lim, 0.0, rv, re),
        DHRow("theta4", "revolute", -np.pi / 2, 0.0, p.l4, -np.pi / 2, -lim, lim, 0.0, rv, re),
        DHRow("theta5", "revolute", 0.0, 0.0, p.l5, 0.0, -lim, lim, 0.0, rv, re),
        DHRow("theta6", "revolute", 0.0, 0.0, p.l6, -np.pi / 2, -lim, lim, 0.0, rv, re),
        DHRow("theta7", "revolute", np.pi / 2, 0.0, 0.0, np.pi / 2, -lim, lim, 0.0, rv, re),
        DHRow("theta8", "revolute", 0.0, p.d8, 0.0, 0.0, -lim, lim, 0.0, rv, re),
        DHRow("d9", "prismatic", 0.0, 0.0, 0.0, -np.pi / 2, 0.0, p.d9_stroke, p.d9_home,
              p.prismatic_velocity, p.prismatic_effort),
        DHRow("d10", "prismatic", 0.0, 0.0, 0.0, 0.0, 0.0, p.d10_stroke, 0.0,
              p.prismatic_velocity, p.prismatic_effort),
    )
    check_rows(rows)
    return DHChain(base=base, rows=rows, tool=translation(0.0, 0.0, p.needle_length))


# ---------------------------------------------------------------------------
# The arc and the train: eqs 10-18 both ways
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainPose:
    """Where the train is on the arc: d1 (Z, m), d2 (Y, m), Ω (rad, signed)."""

    d1: float
    d2: float
    omega: float


def train_pose(epsilon: float | np.ndarray, p: ArcTrainParams = ArcTrainParams()):
    """Eqs 12–18: arc angle ε → (d1, d2, Ω), with the paper's two branches.

    The paper gives Ω's magnitude on each side of the top (eq 15 for h > G/2,
    eq 18 for h < G/2); here Ω is signed, positive when the train leans
    towards +Y, so it is ε − Φ/2 on both sides and continuous at h = G/2.
    """
    eps = np.asarray(epsilon, dtype=float)
    R, psi, phi = p.arc_radius, p.psi, p.arc_span
    h = R * eps  # eq 12
    upper = h > p.arc_length / 2
    d1 = np.where(upper, R * np.sin(np.pi - (eps + psi)), R * np.sin(eps + psi))  # eqs 13, 16
    d2 = np.where(upper, R * np.cos(np.pi - (eps + psi)) + R, R - R * np.cos(eps + psi))  # 14, 17
    omega = np.where(upper, eps - phi / 2, -(phi / 2 - eps))  # eqs 15, 18 (signed)
    if np.ndim(epsilon) == 0:
        return TrainPose(float(d1), float(d2), float(omega))
    return TrainPose(d1, d2, omega)  # type: ignore[arg-type]


def epsilon_from_d2(d2: float | np.ndarray, p: ArcTrainParams = ArcTrainParams()):
    """Invert eq 14/17: a measured d2 (e.g. the ultrasonic sensor) → arc angle ε.

    d2 = R(1 − cos(ψ+ε)) is monotonic in ε on the arc, so the inverse is unique.
    """
    c = 1.0 - np.asarray(d2, dtype=float) / p.arc_radius
    return np.arccos(np.clip(c, -1.0, 1.0)) - p.psi


def epsilon_from_omega(omega: float | np.ndarray, p: ArcTrainParams = ArcTrainParams()):
    return np.asarray(omega, dtype=float) + p.arc_span / 2


def epsilon_for_target_y(y: float, p: ArcTrainParams = ArcTrainParams()) -> float:
    """Eq 11: the paper places the train at ε = ΦY/W for a target at Y."""
    return p.arc_span * y / p.bed_width


# ---------------------------------------------------------------------------
# Forward kinematics to the needle
# ---------------------------------------------------------------------------


TARGET_1 = NeedleTarget(entry=np.array([0.0, 0.0882, 0.066]), depth=0.0301, angle=47.0 * DEG)

#: Seed 000 Tables 2–3: Target 1 as asked (mm, degrees) and the five repeats as measured.
TABLE3_TARGET: dict[str, float] = {"x": 0.0, "y": 88.2, "z": 66.0, "insertion": 30.1, "angle": 47.0}
TABLE3_MEASURED: dict[str, tuple[float, ...]] = {
    "x": (1.33, 1.34, 1.42, 1.26, 1.23),
    "y": (87.50, 87.93, 88.94, 87.84, 87.80),
    "z": (65.09, 66.71, 64.99, 66.90, 65.59),
    "insertion": (29.88, 30.23, 30.43, 29.92, 30.16),
    "angle": (47.22, 46.50, 46.12, 47.13, 46.64),
}

#: Seed 000 section 6: the Dynamixel servos hold position to ±0.29°.
SERVO_TOL_DEG = 0.29
#: The rig's rack-and-pinion radius (m): a servo-driven slide moves this much per radian of its servo.
PINION_RADIUS = 0.010


def table3_deviations() -> dict[str, np.ndarray]:
    """Table 3's five repeats of Target 1 minus the target, per quantity (mm; the angle in degrees)."""
    return {k: np.asarray(v, dtype=float) - TABLE3_TARGET[k] for k, v in TABLE3_MEASURED.items()}


@dataclass
class ArcTrainRobot:
    """Kinematics of the arc-and-train robot: FK, the arc mapping and IK."""

    params: ArcTrainParams = field(default_factory=ArcTrainParams)

    def __post_init__(self) -> None:
        self.chain = build_chain(self.params)

    name = "arc-train"
    insertion_joint = "d10"

    @property
    def joint_names(self) -> list[str]:
        return list(JOINTS)

    def joint_vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Joint dict → vector, missing joints at home; unknown names refused."""
        return self.chain.vector_from(values, self.name)

    def needle(self, q: np.ndarray) -> NeedlePose:
        """Forward kinematics of one configuration to the needle."""
        T = self.chain.frames(np.asarray(q, dtype=float))
        F8 = T[8]  # frame after d9: z along the needle, origin on theta8's axis
        axis = F8[:3, 2]
        entry = F8[:3, 3] + self.params.needle_length * axis
        return pose_from_axis(entry, axis, float(q[8]))

    def needle_batch(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised FK: (entry, tip, angle) for q of shape (N, 9)."""
        T = self.chain.frames(q)
        axis = T[:, 8, :3, 2]
        entry = T[:, 8, :3, 3] + self.params.needle_length * axis
        tip = entry + q[:, 8:9] * axis
        return entry, tip, np.arctan2(axis[:, 1], -axis[:, 2])

    # -- inverse kinematics -------------------------------------------------

    def _closed_form(self, target: NeedleTarget, eps: np.ndarray):
        """Eqs 19–20 and 4 for an array of train positions.

        Returns the joint vectors, the first failed constraint per ε ("" when
        it has an answer) and the total violation (rad or m, 0 when feasible),
        which the numerical fallback drives to zero.
        """
        p = self.params
        eps = np.atleast_1d(np.asarray(eps, dtype=float))
        n = eps.size
        fail = np.full(n, "", dtype=object)
        equation = np.full(n, "", dtype=object)
        violation = np.zeros(n)
        lim = p.revolute_limit
        q = np.zeros((n, 9))
        q[:, 0] = eps
        omega = eps - p.arc_span / 2
        # The needle stays in its X-plane; train tilt adds to theta8 (both about X).
        theta8 = target.angle + omega
        guide = np.asarray(target.entry, dtype=float) - p.needle_length * target.direction
        # Train frame (DH frame 1) for every eps: origin and axes.
        frames = self.chain.frames(np.column_stack([eps, np.zeros((n, 8))]))
        F1 = frames[:, 1]
        r = np.einsum("nji,nj->ni", F1[:, :3, :3], guide - F1[:, :3, 3])
        rx, ry, rz = r[:, 0], r[:, 1], r[:, 2]

        def check(bad_amount: np.ndarray, eq: str, words) -> None:
            """``words(k)``: the reason at train position k, worded only for one position."""
            bad = bad_amount > 1e-12
            violation[:] += np.maximum(bad_amount, 0.0)
            first = bad & (fail == "")
            if first.any():
                fail[first] = words(0) if n == 1 else eq
                equation[first] = eq

        check(np.abs(rx) - p.l5, "eq 19", lambda k: (
            f"the needle guide would be {(abs(rx[k]) - p.l5) * 1e3:.1f} mm out of the arm's "
            f"reach from the train (it reaches {p.l5 * 1e3:.0f} mm)"))
        theta6 = np.arcsin(np.clip(rx / p.l5, -1, 1))
        reach = p.l4 + p.l6 + p.l5 * np.cos(theta6)
        check(np.abs(ry) - reach, "eq 20", lambda k: (
            f"the needle guide would be {(abs(ry[k]) - reach[k]) * 1e3:.1f} mm further across "
            f"the bed than the arm reaches"))
        theta7 = np.arcsin(np.clip(-ry / reach, -1, 1))
        d9 = rz - p.d3 - p.d8 - reach * np.cos(theta7)
        q[:, 1] = 0.0  # eq 7
        q[:, 2] = theta7  # eq 8
        q[:, 3] = -theta6  # eq 9
        q[:, 4] = theta6
        q[:, 5] = theta7
        q[:, 6] = theta8
        q[:, 7] = d9
        q[:, 8] = target.depth
        for val, lo, hi, what, eq, scale, unit in (
            (theta6, -lim, lim, "theta5/theta6 (the sideways swing)", "eq 19", np.degrees(1), "°"),
            (theta7, -lim, lim, "theta4/theta7 (the reach across the bed)", "eq 20", np.degrees(1), "°"),
            (theta8, -lim, lim, "theta8 (the needle angle on the train)", "eqs 8-9", np.degrees(1), "°"),
            (d9, 0.0, p.d9_stroke, "d9 (the travel along the bed)", "eq 4", 1e3, " mm"),
        ):
            check(np.maximum(lo - val, val - hi), eq, lambda k, val=val, lo=lo, hi=hi, what=what,
                  scale=scale, unit=unit: (
                      f"{what} would need {val[k] * scale:.1f}{unit}, outside its range "
                      f"[{lo * scale:.1f}{unit}, {hi * scale:.1f}{unit}]"))
        return q, fail, violation, equation

    def ik(self, target: NeedleTarget) -> np.ndarray:
        """Joint values that put the needle on ``target``; raises UnreachableError."""
        p = self.params
        if not 0.0 <= target.depth <= p.d10_stroke:
            raise UnreachableError(
                f"insertion depth {target.depth * 1e3:.1f} mm is outside d10's stroke "
                f"[0, {p.d10_stroke * 1e3:.0f}] mm")
        if not np.all(np.isfinite(target.entry)) or not np.isfinite(target.angle):
            raise UnreachableError(f"target is not finite: {target}")
        if abs(target.tilt) > 1e-12:
            raise UnreachableError(
                "the arc-and-train robot keeps the needle in the axial plane: tilt_deg must be 0",
                "eqs 7-9")
        eps0 = epsilon_for_target_y(float(target.entry[1]), p)  # eq 11
        if 0.0 <= eps0 <= p.arc_span:
            q, fail, _, eq = self._closed_form(target, np.array([eps0]))
            if fail[0] == "":
                return self._verified(q[0], target)
            reason, equations = fail[0], f"eq 11, {eq[0]}"
        else:
            reason = (f"no train position on the arc faces the entry point's "
                      f"Y = {target.entry[1] * 1e3:.1f} mm")
            equations = "eq 11"
        # Numerical fallback: search the arc for the train position closest to
        # eq 11's choice where the closed form has an answer.
        grid = np.linspace(0.0, p.arc_span, 1201)
        q, fail, violation, _ = self._closed_form(target, grid)
        ok = np.flatnonzero(fail == "")
        if ok.size:
            best = ok[np.argmin(np.abs(grid[ok] - eps0))]
            return self._verified(q[best], target)
        # Feasible sets narrower than the grid: minimise the violation near the
        # best grid points.
        from scipy.optimize import minimize_scalar  # heavy: loaded only when fitting

        step = grid[1] - grid[0]
        # Violations change by at most ~(R + reach) per radian of arc, so a
        # feasible set between grid points leaves a small violation beside it.
        near = np.argsort(violation)[:4]
        for i in near[violation[near] < 10 * step]:
            lo, hi = max(grid[i] - step, 0.0), min(grid[i] + step, p.arc_span)
            res = minimize_scalar(lambda e: self._closed_form(target, np.array([e]))[2][0],
                                  bounds=(lo, hi), method="bounded", options={"xatol": 1e-13})
            qq, ff, _, _ = self._closed_form(target, np.array([res.x]))
            if ff[0] == "":
                return self._verified(qq[0], target)
        raise UnreachableError(
            f"target unreachable: {reason}, and no train position on the arc reaches it within "
            f"the joint limits; move the target or the bed", f"{equations}; eqs 19-20 searched along the arc")

    def _verified(self, q: np.ndarray, target: NeedleTarget) -> np.ndarray:
        pose = self.needle(q)
        err = max(float(np.max(np.abs(pose.entry - target.entry))),
                  abs(pose.angle - target.angle) * self.params.arc_radius)
        if err > 1e-9:  # never hand back a wrong answer
            raise UnreachableError(f"inverse kinematics did not converge (residual {err:.2e})")
        return q
