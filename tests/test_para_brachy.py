"""Acceptance tests for the seed-003 parallel robot (bench.kinematics.para_brachy)."""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest

from bench.accuracy.workspace_figure import plot_workspace
from bench.kinematics import para_brachy as pb
from bench.kinematics.para_brachy import DEG
from bench.kinematics.para_brachy import SingularityCase as S

P = pb.DEFAULT_PARAMS
RNG_SEED = 20150605  # the paper's "received" date


def random_workspace_poses(n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform poses in the default CT-bed workspace (the box WorkspaceGrid.around spans)."""
    g = pb.WorkspaceGrid.around()
    lo = np.array([g.x[0], g.y[0], g.z[0], g.psi[0], g.theta[0]])
    hi = np.array([g.x[-1], g.y[-1], g.z[-1], g.psi[-1], g.theta[-1]])
    return lo + (hi - lo) * rng.random((n, 5))


def pose_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest component error; ψ compared across the ±π cut."""
    d = np.abs(a - b)
    d[..., 3] = np.abs(pb.wrap_angle(a[..., 3] - b[..., 3]))
    return d.max(axis=-1)


# ---------------------------------------------------------------------------
# Geometric models
# ---------------------------------------------------------------------------


def test_default_workspace_is_reachable_within_strokes_and_regular():
    m = pb.workspace_map()
    assert m.reachable.all()
    # every grid pose keeps every factor of det A and det B away from zero
    assert np.min(m.margin) >= np.sin(10 * DEG) - 1e-12
    assert np.min(m.inv_cond_A) > 1e-3 and np.min(m.inv_cond_B) > 0.1
    assert pb.architecture_violations(P) == []


def test_igm_then_dgm_contains_the_pose_1000_random():
    rng = np.random.default_rng(RNG_SEED)
    x = random_workspace_poses(1000, rng)
    q = pb.igm(x)  # strokes checked
    sols = pb.dgm(q)
    assert sols.shape == (1000, 2, 5)
    err = pose_error(sols, x[:, None, :]).min(axis=1)
    assert err.max() < 1e-9
    # the helper picks that solution
    assert pose_error(pb.dgm_closest(q, x), x).max() < 1e-9
    # and the IGM's branch is eq 1's: q2 above q1, G below A2 in Y
    assert (pb.working_mode(q, x) == 1).all()


def test_dgm_then_igm_returns_q_for_every_assembly_mode():
    rng = np.random.default_rng(RNG_SEED + 1)
    lo, hi = np.array(P.q_min), np.array(P.q_max)
    q = lo + (hi - lo) * rng.random((20000, 5))
    sols = pb.dgm(q, strict=False)
    ok = np.isfinite(sols[:, 0, 0])
    q, sols = q[ok][:1000], sols[ok][:1000]
    assert len(q) == 1000  # enough random joint vectors assemble
    for k in range(2):
        pose = sols[:, k]
        assert np.abs(pb.constraint(q, pose)).max() < 1e-12
        modes = pb.working_mode(q, pose)
        back = np.empty_like(q)
        for mode in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            sel = (modes == mode).all(axis=1)
            if sel.any():
                back[sel] = pb.igm(pose[sel], P, mode, check_limits=False)
        d = np.abs(back - q)
        d[:, 2] = np.abs(pb.wrap_angle(back[:, 2] - q[:, 2]))
        assert d.max() < 1e-9


def test_two_assembly_modes_are_distinct_and_mirror_across_A1G():
    q = pb.igm(pb.WORKSPACE_CENTRE)
    s0, s1 = pb.dgm(q)
    assert pose_error(s0, s1) > 0.01
    # same theta and C1 (A1 fixed by q1..q3), different psi
    c1a, _ = pb.needle_points(s0)
    c1b, _ = pb.needle_points(s1)
    assert np.allclose(c1a, c1b, atol=1e-12) and s0[4] == pytest.approx(s1[4], abs=1e-15)
    # the type-2 case-6 factor P sinψ − Q cosψ has opposite signs: the modes are separated by it
    assert np.sign(pb.det_A(q, s0)) == -np.sign(pb.det_A(q, s1))


def test_literal_paper_equations_hold_for_e_and_l3_zero():
    """With e = l3 = 0 (the defaults) eqs 1, 2 and 8 hold as printed."""
    assert P.e == 0.0 and P.l3 == 0.0
    rng = np.random.default_rng(RNG_SEED + 2)
    x = random_workspace_poses(200, rng)
    XE, YE, ZE, psi, th = x.T
    hl, h = P.h + P.lc, P.h
    r_a = np.hypot(P.dx - XE + hl * np.sin(th) * np.cos(psi), YE - hl * np.sin(th) * np.sin(psi))
    eq1 = np.stack([
        ZE + hl * np.cos(th) + P.l1,
        ZE + hl * np.cos(th) + P.l1 + np.sqrt(P.d**2 - (r_a - P.b) ** 2),
        np.pi - np.arctan2(YE - hl * np.sin(th) * np.sin(psi), P.dx - XE + hl * np.sin(th) * np.cos(psi)),
        ZE + h * np.cos(th) - P.l2,
        YE - h * np.sin(th) * np.sin(psi) - np.sqrt(P.c**2 - (XE - h * np.sin(th) * np.cos(psi)) ** 2),
    ], axis=-1)
    q = pb.igm(x)
    assert np.abs(q - eq1).max() < 1e-12
    # eq 2 (second circle) and eq 8 (det B as printed, sign of this F aside)
    sols = pb.dgm(q)
    _, c2 = pb.needle_points(sols)
    assert np.abs(c2[..., 0] ** 2 + (c2[..., 1] - q[:, None, 4]) ** 2 - P.c**2).max() < 1e-12
    s = np.sqrt(P.d**2 - (q[:, 1] - q[:, 0]) ** 2)
    eq8 = 2 * (q[:, 4] - YE + h * np.sin(psi) * np.sin(th)) * (s + P.b) / s * (q[:, 1] - q[:, 0])
    assert np.allclose(np.abs(pb.det_B(q, x)), np.abs(eq8), rtol=1e-12, atol=0)


# ---------------------------------------------------------------------------
# Jacobians (eqs 6–7)
# ---------------------------------------------------------------------------


def _params_variants():
    yield P
    yield dataclasses.replace(P, e=0.03, l3=-0.04, b=0.08, l1=0.07, l2=0.02)


@pytest.mark.parametrize("params", list(_params_variants()), ids=["default", "e_l3_nonzero"])
def test_analytic_jacobians_match_central_differences(params):
    rng = np.random.default_rng(RNG_SEED + 3)
    x = random_workspace_poses(300, rng)
    q = pb.igm(x, params, check_limits=False)
    A, B = pb.jacobian_A(q, x, params), pb.jacobian_B(q, x, params)
    step = 1e-6
    A_fd = np.empty_like(A)
    B_fd = np.empty_like(B)
    for k in range(5):
        e = np.zeros(5)
        e[k] = step
        A_fd[..., k] = (pb.constraint(q, x + e, params) - pb.constraint(q, x - e, params)) / (2 * step)
        B_fd[..., k] = (pb.constraint(q + e, x, params) - pb.constraint(q - e, x, params)) / (2 * step)
    # entries are O(0.1–1): absolute 1e-6 on small entries, relative 1e-6 on large ones
    assert np.all(np.abs(A - A_fd) <= 1e-6 * np.maximum(1.0, np.abs(A)))
    assert np.all(np.abs(B - B_fd) <= 1e-6 * np.maximum(1.0, np.abs(B)))
    # the closed-form determinants (eq 8 and det A) agree with the matrices
    assert np.allclose(pb.det_A(q, x, params), np.linalg.det(A), rtol=1e-9, atol=0)
    assert np.allclose(pb.det_B(q, x, params), np.linalg.det(B), rtol=1e-9, atol=0)
    # eq 6: A ẋ = −B q̇ along a DGM path
    dq = 1e-9 * rng.standard_normal((300, 5))
    x2 = pb.dgm_closest(q + dq, x, params)
    dx = x2 - x
    dx[:, 3] = pb.wrap_angle(dx[:, 3])
    lhs = np.einsum("nij,nj->ni", A, dx)
    rhs = -np.einsum("nij,nj->ni", B, dq)
    # first order in a 1e-9 step: the residual is second order, < 1e-4 of the terms
    assert np.all(np.linalg.norm(lhs - rhs, axis=1) < 1e-4 * np.linalg.norm(rhs, axis=1))


# ---------------------------------------------------------------------------
# Singularities (section 3)
# ---------------------------------------------------------------------------

CASE3_PARAMS = dataclasses.replace(P, b=-0.05, dx=0.40)  # b <= 0: A1 can reach the q3 axis
PARTICULAR_PARAMS = dataclasses.replace(P, dx=0.45)  # b + d = 0.5 >= dx - e: restriction broken

SINGULAR_CASES = [
    # case, params, offset far from the locus, which Jacobian degenerates
    (S.TYPE1_CASE1, P, 0.10, "B"),
    (S.TYPE1_CASE2, P, 0.20, "B"),
    (S.TYPE1_CASE3, CASE3_PARAMS, 0.10, "B"),
    (S.TYPE1_CASE4, P, 0.10, "B"),
    (S.TYPE2_CASE5, P, 20 * DEG, "A"),
    (S.TYPE2_CASE6, P, 20 * DEG, "A"),
    (S.TYPE2_CASE6_PSI_HALF_PI, PARTICULAR_PARAMS, 0.20, "A"),
]


@pytest.mark.parametrize("case,params,far,which", SINGULAR_CASES, ids=[c[0].value for c in SINGULAR_CASES])
def test_constructed_singular_pose_is_named_and_conditioning_worsens(case, params, far, which):
    q, x = pb.singular_configuration(case, 0.0, params)
    assert np.abs(pb.constraint(q, x, params)).max() < 1e-12
    expected = [case] if case is not S.TYPE2_CASE6_PSI_HALF_PI else [S.TYPE2_CASE6, case]
    assert pb.classify_singularity(pose=x, tol=1e-6, params=params) == expected
    assert pb.classify_singularity(q=q, pose=x, tol=1e-6, params=params) == expected
    if case is not S.TYPE2_CASE5:  # at θ = 0 the DGM's ψ is undefined
        assert pb.classify_singularity(q=q, tol=1e-6, params=params) == expected
    # far from the locus the configuration is regular
    qf, xf = pb.singular_configuration(case, far, params)
    assert pb.classify_singularity(pose=xf, tol=1e-3, params=params) == []
    # approaching it, the relevant inverse condition number falls monotonically towards 0
    offsets = far * np.logspace(0.0, -4.0, 13)
    inv = []
    for off in offsets:
        qo, xo = pb.singular_configuration(case, off, params)
        ica, icb = pb.inverse_condition(qo, xo, params)
        inv.append(float(ica if which == "A" else icb))
    inv = np.array(inv)
    assert np.all(np.diff(inv) < 0.0), inv
    assert inv[-1] < 1e-3 * inv[0]
    ica, icb = pb.inverse_condition(q, x, params)
    assert float(ica if which == "A" else icb) < 1e-6
    # and the other matrix stays regular: the case is of the named type only
    assert float(icb if which == "A" else ica) > 1e-3


def test_cases_that_need_a_design_flaw_are_refused_for_the_default_design():
    with pytest.raises(ValueError, match="b <= 0"):
        pb.singular_configuration(S.TYPE1_CASE3)
    with pytest.raises(ValueError, match="dx - e"):
        pb.singular_configuration(S.TYPE2_CASE6_PSI_HALF_PI)
    assert any("type1.case3" in v for v in pb.architecture_violations(CASE3_PARAMS))
    assert any("psi_half_pi" in v for v in pb.architecture_violations(PARTICULAR_PARAMS))


def test_type1_and_type2_together_are_architecture_singular():
    base = pb.WORKSPACE_CENTRE.copy()
    base[4] = 0.0  # lc parallel to OZ (case 5) ...
    q, x = pb.singular_configuration(S.TYPE1_CASE2, 0.0, P, base_pose=base)  # ... and d perpendicular to OZ
    assert pb.classify_singularity(pose=x) == [S.TYPE1_CASE2, S.TYPE2_CASE5, S.TYPE3_ARCHITECTURE]
    ica, icb = pb.inverse_condition(q, x)
    assert ica < 1e-12 and icb < 1e-12


def test_classify_rejects_inconsistent_or_bad_input():
    q = pb.igm(pb.WORKSPACE_CENTRE)
    with pytest.raises(ValueError, match="eq \\(7\\)"):
        pb.classify_singularity(q=q + 0.01, pose=pb.WORKSPACE_CENTRE)
    with pytest.raises(ValueError, match="tol must be positive"):
        pb.classify_singularity(pose=pb.WORKSPACE_CENTRE, tol=0.0)
    with pytest.raises(ValueError, match="needs q, pose"):
        pb.classify_singularity()


# ---------------------------------------------------------------------------
# Unreachable poses and joint vectors
# ---------------------------------------------------------------------------


def _shifted(dx=0.0, dy=0.0, dz=0.0, psi=None, theta=None):
    x = pb.WORKSPACE_CENTRE.copy()
    x[:3] += (dx, dy, dz)
    if psi is not None:
        x[3] = psi
    if theta is not None:
        x[4] = theta
    return x


@pytest.mark.parametrize(
    "pose,pattern",
    [
        (_shifted(dx=-0.35), r"eq \(1\) q2: r_A - b = 0\.[0-9]+ m exceeds d = 0\.4 m"),
        (_shifted(dx=0.25), r"eq \(1\) q2: C1 is r_A = 0\.079[0-9]* m .* less than b = 0\.1 m"),
        (_shifted(dx=0.2), r"eq \(1\) q5: \|X_C2 - e\| = 0\.4[0-9]* m exceeds c = 0\.38 m"),
        (_shifted(theta=-5 * DEG), r"theta = -0\.0872665 rad is outside \[0, pi\]"),
        (_shifted(dz=0.3), r"eq \(1\) gives q1 = 0\.57[0-9]* m, outside its stroke \[0\.15, 0\.4\] m"),
        (_shifted(dx=0.1, dy=0.25), r"eq \(1\) gives q5 = 0\.037[0-9]* m, outside its stroke \[-0\.6, 0\] m"),
    ],
    ids=["rA_beyond_d", "rA_below_b", "c_too_short", "theta_negative", "q1_stroke", "q5_stroke"],
)
def test_unreachable_pose_raises_clear_error(pose, pattern):
    with pytest.raises(pb.UnreachableError, match=pattern) as info:
        pb.igm(pose)
    assert isinstance(info.value, ValueError)


def test_unreachable_error_names_the_offending_pose_in_a_batch():
    x = np.stack([pb.WORKSPACE_CENTRE, pb.WORKSPACE_CENTRE, _shifted(dx=0.25)])
    with pytest.raises(pb.UnreachableError, match=r"pose\[2\] = \[ 0\.5 .* r_A = 0\.079"):
        pb.igm(x)


@pytest.mark.parametrize(
    "dq,pattern",
    [
        ((0.0, 0.5, 0.0, 0.0, 0.0), r"eq \(3\) needs \|q2 - q1\| = 0\.8[0-9]* m <= d = 0\.4 m"),
        ((0.0, 0.0, 0.0, 0.2, 0.0), r"eq \(5\) needs \|Z_C1 - Z_C2\| .* <= lc = 0\.1 m"),
        ((0.0, 0.0, 0.0, 0.0, 0.5), r"eq \(2\) circles about A1 .* do not meet"),
    ],
    ids=["d_too_short", "lc_too_short", "circles_apart"],
)
def test_dgm_without_assembly_raises_clear_error(dq, pattern):
    q = pb.igm(pb.WORKSPACE_CENTRE) + np.array(dq)
    with pytest.raises(pb.UnreachableError, match=pattern):
        pb.dgm(q)
    assert np.isnan(pb.dgm(q, strict=False)).all()


def test_bad_inputs_name_the_value():
    with pytest.raises(ValueError, match=r"ParaBrachyParams.lc must be a positive length in m, got -0.1"):
        pb.ParaBrachyParams(lc=-0.1)
    with pytest.raises(ValueError, match=r"stroke of q2 is empty"):
        pb.ParaBrachyParams(q_min=(0, 1, 0, 0, 0), q_max=(1, 0.5, 1, 1, 1))
    with pytest.raises(ValueError, match=r"pose\[3\] is not finite: nan"):
        pb.igm([0.2, 0.0, 0.0, np.nan, 0.3])
    with pytest.raises(ValueError, match=r"5 components .* shape \(4,\)"):
        pb.igm([0.2, 0.0, 0.0, 0.3])
    with pytest.raises(ValueError, match=r"working_mode must be two signs"):
        pb.igm(pb.WORKSPACE_CENTRE, P, (1, 0))


# ---------------------------------------------------------------------------
# Accuracy assessment (section 4, eqs 12–14)
# ---------------------------------------------------------------------------


def test_paper_accuracy_sweep_over_q1():
    """The paper's reference pose has link d perpendicular to OZ (q2 = q1).

    There q2 changes r_A only to second order: stepping it by ε moves the tip
    about ε·ε/(2d)·lever; the paper's n = 5.244e-5 equals ε/(2d) for d ≈ 0.48 m.
    Measured here (d = 0.40 m), q1 swept 20 mm below to 2 mm above q2:
      q2: tip motion / ε from 5.9e-5 (at q1 = q2) to 0.044 — always ≪ ε;
      q3: tip motion per 0.05° from 0.85 to 2.4 mm (paper: 1.22 mm);
      q1: 3.2–15.4 ε, q4: 3.7–15.2 ε, q5: 2.7–6.1 ε;
      θ changes only with q1 and q4 (eq 5: θ depends on q1 − q4 alone).
    """
    q_ref, x_ref = pb.singular_configuration(S.TYPE1_CASE2, 0.0)
    values = q_ref[0] + np.linspace(-0.020, 0.002, 45)
    sw = pb.perturbation_sweep(0, values, q_ref=q_ref, reference_pose=x_ref)
    assert sw.pos_err.shape == sw.psi_err.shape == sw.theta_err.shape == (45, 5)
    assert np.allclose(sw.eps, [0.05e-3, 0.05e-3, 0.05 * DEG, 0.05e-3, 0.05e-3])
    ratio = sw.ratio
    # q2 moves the tip far less than ε, vanishing to second order at q1 = q2
    assert ratio[:, 1].max() < 0.05
    assert 1e-5 < ratio[:, 1].min() < 1e-4
    assert np.argmin(ratio[:, 1]) == np.argmin(np.abs(values - q_ref[1]))
    # q3 leaves θ untouched (so do q2 and q5); q1 and q4 do not
    assert np.abs(sw.theta_err[:, [1, 2, 4]]).max() < 1e-14
    assert np.abs(sw.theta_err[:, [0, 3]]).min() > 0.01 * DEG
    # q3 by 0.05° moves the tip by about a millimetre, as in the paper's Fig. 11
    assert 0.5e-3 < sw.pos_err[:, 2].min() and sw.pos_err[:, 2].max() < 3e-3
    # q1, q4 and q5 move the tip more than ε
    assert ratio[:, [0, 3, 4]].min() > 2.0
    # the swept joint's column is the paper's consecutive-difference series (eq 12)
    fine = pb.perturbation_sweep(0, q_ref[0] - 0.01 + 0.05e-3 * np.arange(4), q_ref=q_ref, reference_pose=x_ref)
    steps = np.linalg.norm(np.diff(fine.poses[:, :3], axis=0), axis=1)
    assert np.allclose(steps, fine.pos_err[:-1, 0], rtol=1e-6)


def test_sweep_at_workspace_centre_q2_acts_at_first_order():
    """Away from type-1 case 2, q2 moves the tip by about ε or more: the paper's
    small q2 ratio is a property of its reference pose, not of the design."""
    q0 = pb.igm(pb.WORKSPACE_CENTRE)
    sw = pb.perturbation_sweep(0, q0[0] + np.linspace(-0.02, 0.005, 11), q_ref=q0)
    assert sw.ratio[:, 1].min() > 0.5
    assert np.abs(sw.theta_err[:, [1, 2, 4]]).max() < 1e-14


def test_perturbation_sweep_rejects_bad_arguments():
    with pytest.raises(ValueError, match="joint_index must be 0..4"):
        pb.perturbation_sweep(5, [0.3])
    with pytest.raises(ValueError, match="eps must be positive"):
        pb.perturbation_sweep(0, [0.3], eps_linear=0.0)


# ---------------------------------------------------------------------------
# Workspace map files
# ---------------------------------------------------------------------------


def test_workspace_map_save_and_plot(tmp_path):
    grid = pb.WorkspaceGrid.around(half_width=0.2, n=(9, 9, 3, 3, 3))
    m = pb.workspace_map(grid)
    assert 0.0 < m.reachable_fraction < 1.0
    assert np.isnan(m.inv_cond_A[~m.reachable]).all() and np.isfinite(m.inv_cond_A[m.reachable]).all()
    assert (m.fail_code[~m.reachable] > 0).all()
    path = pb.save_workspace(m, tmp_path / "ws.npz", csv_path=tmp_path / "ws.csv")
    data = np.load(path)
    assert data["reachable"].shape == grid.shape
    np.testing.assert_array_equal(data["reachable"], m.reachable)
    np.testing.assert_array_equal(data["inv_cond_B"], m.inv_cond_B)
    assert json.loads(str(data["params"]))["d"] == P.d
    with open(tmp_path / "ws.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == int(np.prod(grid.shape))
    assert {r["fail_reason"] for r in rows if r["reachable"] == "0"} <= set(pb.IGM_FAILURES.values())
    png = plot_workspace(m, tmp_path / "ws.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="must end in .npz"):
        pb.save_workspace(m, tmp_path / "ws.txt")
