"""Contact with the CT gantry: the triangle kernels, the exact test, the per-cycle bound,
and the cross-check against PyBullet for both robots."""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest

from bench.contact.validation import PyBulletDistances, interesting_poses
from bench.geometry.bvh import BoxIndex, box_gap
from bench.geometry.mesh_ops import enclosing_radius, refine
from bench.geometry.torus import box_point_distance
from bench.geometry.tri_distance import (
    TriangleSet,
    paper_intersects,
    point_triangle_distance,
    prism_bound,
    prism_bounds,
    segment_distance,
    triangle_distance,
)
from bench.geometry.urdf_shapes import CollisionShape
from bench.kinematics.registry import get_robot
from bench.scene.contact import (
    DEFAULT_MARGIN,
    Gantry,
    GantryClearance,
    GantryContact,
    all_pairs_contact,
    all_pairs_distance,
    default_gantry,
)
from bench.scene.robot_geometry import RobotGeometry
from bench.scene.room import URDF_DIR

MARGIN = DEFAULT_MARGIN

# ---------------------------------------------------------------------------
# Triangle kernels against a brute-force reference
# ---------------------------------------------------------------------------


def _faces(T: np.ndarray) -> list[np.ndarray]:
    return [T[list(idx)] for k in (1, 2, 3) for idx in itertools.combinations(range(3), k)]


def reference_distance(A: np.ndarray, B: np.ndarray) -> float:
    """Distance between two triangles by brute force over every pair of faces (vertex, edge,
    triangle) of the two: least squares in their affine hulls, kept where the closest points
    fall inside both faces. The minimum over all 49 pairs is the exact distance."""
    best = np.inf
    for FA in _faces(A):
        for FB in _faces(B):
            DA, DB = (FA[1:] - FA[0]).T, (FB[1:] - FB[0]).T
            M = np.hstack([DA, -DB])
            sol = np.linalg.lstsq(M, FB[0] - FA[0], rcond=None)[0] if M.shape[1] else np.zeros(0)
            la, mb = sol[:DA.shape[1]], sol[DA.shape[1]:]
            if (la >= -1e-12).all() and la.sum() <= 1 + 1e-12 and (mb >= -1e-12).all() \
                    and mb.sum() <= 1 + 1e-12:
                best = min(best, float(np.linalg.norm(FA[0] + DA @ la - FB[0] - DB @ mb)))
    return best


def special_cases(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Touching, intersecting, parallel and coplanar pairs."""
    A, B = [], []
    for _ in range(150):
        T = rng.normal(size=(3, 3))
        n = np.cross(T[1] - T[0], T[2] - T[0])
        n /= np.linalg.norm(n)
        kind = rng.integers(6)
        if kind == 0:  # coplanar, overlapping or not
            U = T.mean(0) + (rng.normal(size=(3, 3)) @ np.eye(3)) * 0.8
            U -= np.outer((U - T[0]) @ n, n)
        elif kind == 1:  # parallel planes
            U = T + rng.normal(size=(3, 3)) * 0.5
            U -= np.outer((U - T[0]) @ n, n)
            U += rng.choice([1e-9, 0.1, 0.7]) * n
        elif kind == 2:  # a vertex touching the interior
            w = rng.dirichlet(np.ones(3))
            p = w @ T
            U = np.array([p, p + rng.normal(size=3) + n, p + rng.normal(size=3) + 2 * n])
        elif kind == 3:  # edge through the interior (intersecting)
            w = rng.dirichlet(np.ones(3))
            p = w @ T
            U = np.array([p - n, p + n, p + rng.normal(size=3)])
        elif kind == 4:  # sharing an edge
            U = np.array([T[0], T[1], T[0] + rng.normal(size=3)])
        else:  # identical
            U = T.copy()
        A.append(T)
        B.append(U)
    return np.array(A), np.array(B)


def test_triangle_distance_matches_brute_force():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(800, 3, 3))
    B = rng.normal(size=(800, 3, 3)) + rng.normal(size=(800, 1, 3)) * 0.6
    SA, SB = special_cases(rng)
    A, B = np.concatenate([A, SA]), np.concatenate([B, SB])
    d = triangle_distance(A, B)
    ref = np.array([reference_distance(a, b) for a, b in zip(A, B)])
    assert np.max(np.abs(d - ref)) < 1e-9
    assert (ref < 1e-12).sum() > 200  # plenty of touching/intersecting pairs
    assert np.all(d[ref < 1e-12] < 1e-9)
    # symmetric and unchanged by vertex order
    assert np.max(np.abs(triangle_distance(B, A) - d)) < 1e-12
    assert np.max(np.abs(triangle_distance(A[:, ::-1], B[:, [1, 2, 0]]) - d)) < 1e-12


def test_prism_bounds_bracket_the_distance_and_are_tight_over_a_face():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(5000, 3, 3))
    B = rng.normal(size=(5000, 3, 3)) * 0.3 + rng.normal(size=(5000, 1, 3)) * 1.5
    d = triangle_distance(A, B)
    SA, SB = TriangleSet.from_triangles(A), TriangleSet.from_triangles(B)
    idx = np.arange(len(A))
    lower, upper = prism_bounds(SA.planes(idx), SB.vertices(idx))
    assert np.all(lower <= d + 1e-12) and np.all(d <= upper + 1e-12)
    assert np.array_equal(prism_bound(SA.planes(idx), SB.vertices(idx)), lower)
    assert np.all(prism_bound(SB.planes(idx), SA.vertices(idx)) <= d + 1e-12)
    # where B's nearest point is a vertex standing over A's face, both bounds are exact
    over = np.isfinite(upper) & (np.abs(upper - d) < 1e-12)
    assert over.sum() > 300 and np.allclose(lower[over], d[over], atol=1e-12)
    # a point set (a mesh patch) bounds its convex hull: here, the pair's two triangles
    hull = np.concatenate([SB.vertices(idx), SB.vertices(idx[::-1])], axis=1)
    both = np.minimum(d, triangle_distance(A, B[::-1]))
    assert np.all(prism_bound(SA.planes(idx), hull) <= both + 1e-12)
    # a degenerate triangle bounds nothing
    flat = np.repeat(A[:1, :1], 3, axis=1)
    zero = prism_bound(TriangleSet.from_triangles(flat).planes(np.zeros(1, int)), SB.vertices(idx[:1]))
    assert zero[0] == 0.0


def test_points_and_segments():
    rng = np.random.default_rng(2)
    P, T = rng.normal(size=(300, 3)), rng.normal(size=(300, 3, 3))
    ref = np.array([reference_distance(np.array([p, p, p]), t) for p, t in zip(P, T)])
    assert np.max(np.abs(point_triangle_distance(P, T) - ref)) < 1e-12
    # parallel, collinear-overlapping and crossing segments
    p = np.zeros(3)
    x = np.array([1.0, 0, 0])
    cases = [((p, x, [0.5, 1, 0], [2, 1, 0]), 1.0), ((p, x, [0.5, 0, 0], [2, 0, 0]), 0.0),
             ((p, x, [2, 0, 0], [3, 0, 0]), 1.0), ((p, x, [0.5, -1, 0], [0.5, 1, 0]), 0.0),
             ((p, x, [0.5, -1, 2], [0.5, 1, 2]), 2.0)]
    for (a, b, c, d), want in cases:
        assert float(segment_distance(a, b, np.array(c, float), np.array(d, float))) == \
            pytest.approx(want, abs=1e-15)


def test_paper_test_agrees_with_the_distance_in_general_position():
    """Eqs 4-6 (both ways) find exactly the intersecting pairs of random triangles; like the
    paper's strict inequalities they miss coplanar overlap, which the distance catches."""
    rng = np.random.default_rng(4)
    A, B = rng.normal(size=(20000, 3, 3)), rng.normal(size=(20000, 3, 3))
    hit = paper_intersects(A, B)
    assert 2000 < hit.sum() < 18000
    assert np.array_equal(hit, triangle_distance(A, B) == 0.0)
    T = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    U = T + np.array([0.2, 0.2, 0.0])
    assert not paper_intersects(T, U)[0] and triangle_distance(T, U)[0] == 0.0


# ---------------------------------------------------------------------------
# Meshes, index and the torus
# ---------------------------------------------------------------------------


def test_box_index_finds_every_pair_within_the_pad():
    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 1, (700, 3))
    hi = lo + rng.uniform(0, 0.1, (700, 3))
    qlo = rng.uniform(0, 1, (60, 3))
    qhi = qlo + rng.uniform(0, 0.3, (60, 3))
    G = box_gap(qlo[:, None], qhi[:, None], lo[None], hi[None])
    for leaf, branch, top in ((16, 8, 64), (1, 2, 1), (8, 4, 8), (1000, 8, 64)):
        index = BoxIndex.build(lo, hi, leaf_size=leaf, branch=branch, top_size=top)
        qi, ii, gap = index.query(qlo, qhi, 0.05)
        assert sorted(zip(qi.tolist(), ii.tolist())) == sorted(zip(*np.nonzero(G <= 0.05)))
        assert np.allclose(gap, G[qi, ii])


def test_gantry_mesh_stays_within_its_slack_of_the_torus():
    g = default_gantry()
    assert len(g.tris) == 96 * 32 * 2
    assert np.max(np.abs(g.torus.sdf(g.tris.reshape(-1, 3)))) < 1e-12  # vertices on the torus
    assert 0.0 < g.slack_out < 0.0005 and 0.0005 < g.slack_in < 0.0015
    pts = refine(g.tris[::7], 0.002)
    sdf = g.torus.sdf(pts.reshape(-1, 3))
    assert sdf.max() <= g.slack_out and -sdf.min() <= g.slack_in
    c = np.asarray(g.torus.centre)
    assert g.contains(np.array([c + [0, 0.5, 0], c, c + [0, 0, 0.9]])).tolist() == [True, False, False]


def test_shape_meshes_contain_their_shapes_and_refine_keeps_the_surface():
    cyl = CollisionShape("cylinder", (0.01, 0.2), np.eye(4))
    v, _ = cyl.local_mesh()
    tris = cyl.triangles()
    # every face plane of the prism clears the true cylinder (radius 10 mm)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    side = np.abs(n[:, 2]) < 1e-9
    assert np.all(np.abs(np.einsum("ij,ij->i", n[side], tris[side, 0])) >= 0.01 - 1e-15)
    assert np.all(np.abs(np.einsum("ij,ij->i", n[side], tris[side, 0])) <= 0.0101)
    fine = refine(tris, 0.005)
    assert enclosing_radius(fine).max() <= 0.005
    area = lambda t: np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
    assert area(fine) == pytest.approx(area(tris), rel=1e-12)


def test_torus_distance_of_a_box_is_the_minimum_over_the_box():
    """The caliper's search along the core circle against a direct minimisation of the
    torus' signed distance over the box (from its best surface samples)."""
    from scipy.optimize import minimize

    torus = default_gantry().torus
    rng = np.random.default_rng(8)
    compared = 0
    for _ in range(25):
        pose = np.eye(4)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        pose[:3, :3] = q * np.sign(np.linalg.det(q))
        pose[:3, 3] = torus.centre + rng.normal(size=3) * 0.3
        half = rng.uniform(0.01, 0.15, 3)
        d = torus.distance_to(box_point_distance(pose, half), pose[:3, 3], np.linalg.norm(half))
        u = rng.uniform(-1, 1, (20_000, 3))
        ax = rng.integers(0, 3, len(u))
        u[np.arange(len(u)), ax] = np.sign(u[np.arange(len(u)), ax])
        local = u * half
        f = torus.sdf(local @ pose[:3, :3].T + pose[:3, 3])
        if f.min() <= 0.01:
            continue  # overlapping or grazing: the signed distance is not smooth there
        assert d <= f.min() + 1e-12
        best = min(minimize(lambda x: float(torus.sdf(pose[:3, :3] @ x + pose[:3, 3])), x0,
                            method="L-BFGS-B", bounds=list(zip(-half, half)),
                            options={"ftol": 1e-15, "gtol": 1e-12}).fun
                   for x0 in local[np.argsort(f)[:5]])
        assert d == pytest.approx(best, abs=1e-7)
        compared += 1
    assert compared >= 10


def test_stale_urdf_is_refused(tmp_path):
    text = (URDF_DIR / "zerobot.urdf").read_text()
    moved = re.sub(r'(<joint name="q4".*?<origin xyz=")([^ ]+)',
                   lambda m: m.group(1) + repr(float(m.group(2)) + 0.01), text, count=1, flags=re.S)
    assert moved != text
    bad = tmp_path / "zerobot.urdf"
    bad.write_text(moved)
    with pytest.raises(ValueError, match="does not match the kinematic model"):
        RobotGeometry(get_robot("zerobot").chain, bad)


# ---------------------------------------------------------------------------
# The exact test, the per-cycle bound, and PyBullet
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module", params=["arc-train", "zerobot"])
def robot(request):
    model = get_robot(request.param)
    geometry = RobotGeometry.for_model(model)
    return model, geometry, GantryContact(geometry), GantryClearance(geometry)


def test_exact_test_equals_all_pairs_on_a_coarse_gantry(robot):
    """On a 16 x 6 torus the pruned test's per-link distances equal the brute force's where
    it reports them exactly, and the links it prunes really lie beyond its reach."""
    model, geometry, _, _ = robot
    from bench.scene.room import SceneParams, gantry_mesh

    v, f = gantry_mesh(SceneParams(), 0.4, 16, 6)
    coarse = Gantry.from_mesh(v, f, default_gantry().torus)
    exact = GantryContact(geometry, MARGIN, coarse, reach=0.05)
    cycle = GantryClearance(geometry, MARGIN, coarse)
    rng = np.random.default_rng(12)
    Q = interesting_poses(model, cycle, 10, rng, contact_share=0.2, near_share=0.6, pool=100)
    exact_links = 0
    for q in Q:
        rep = exact.check(q)
        frames = geometry.link_frames(q)
        for k in range(len(geometry.links)):
            tris = geometry.world_triangles(frames, np.array([k]))[0]
            brute = all_pairs_distance(tris, coarse.tris)
            if rep.enclosed[k]:
                assert rep.distances[k] == 0.0
            elif rep.exact[k]:
                assert rep.distances[k] == pytest.approx(brute, abs=1e-12)
                exact_links += 1
            else:
                assert brute > exact.reach and rep.distances[k] <= brute
    assert exact_links >= 5


def test_pybullet_agrees_on_1000_poses_and_the_interlock_is_conservative(robot):
    """>= 1000 poses biased to the gantry: the exact verdict equals PyBullet's
    getClosestPoints verdict (gantry as its concave mesh) on every pose more than 1 mm
    from the margin, and the per-cycle bound never exceeds the exact distance."""
    model, geometry, exact, cycle = robot
    rng = np.random.default_rng(2024)
    Q = interesting_poses(model, cycle, 1100, rng, pool=8)
    name = model.name.replace("-", "_")
    stats = dict(poses=len(Q), near=0, contact=0, boundary=0, enclosed=0, compared=0)
    with PyBulletDistances(URDF_DIR / f"{name}.urdf", URDF_DIR / "ct_gantry.urdf") as pbd:
        for q in Q:
            rep = exact.check(q)
            bound = cycle.distances(q)
            ex = rep.exact  # elsewhere both are lower bounds of a distance beyond reach
            assert np.all(bound[ex] <= rep.distances[ex] + 1e-12), (q, bound, rep.distances)
            if rep.contact:
                assert bound.min() < MARGIN
            stats["contact"] += rep.contact
            stats["near"] += abs(rep.distance - MARGIN) < 0.03
            if rep.enclosed.any():  # PyBullet's mesh has no inside; the interlock sees it
                stats["enclosed"] += 1
                continue
            if abs(rep.distance - MARGIN) <= 0.001:
                stats["boundary"] += 1
                continue
            pb_contact = pbd.min_distance(q, MARGIN + 0.002) < MARGIN
            assert pb_contact == rep.contact, (q, rep.distance, pbd.min_distance(q, 0.1))
            stats["compared"] += 1
    assert stats["poses"] >= 1000
    assert stats["compared"] >= 950, stats
    assert stats["near"] >= 0.4 * stats["poses"], stats
    assert stats["contact"] >= 0.15 * stats["poses"], stats


def oracle_contact(geometry: RobotGeometry, gantry_tris: np.ndarray, q: np.ndarray,
                   margin: float) -> bool:
    """Brute force: every pair of a link's triangles and the gantry triangles whose boxes come
    within the margin of the link's box (a box gap is a lower bound, so nothing is lost)."""
    frames = geometry.link_frames(q)
    glo, ghi = gantry_tris.min(axis=1), gantry_tris.max(axis=1)
    for k in range(len(geometry.links)):
        tris = geometry.world_triangles(frames, np.array([k]))[0]
        near = box_gap(tris.min(axis=(0, 1)), tris.max(axis=(0, 1)), glo, ghi) < margin
        if near.any() and all_pairs_contact(tris, gantry_tris[near], margin):
            return True
    return False


def crossing_path(model, exact: GantryContact, rng: np.random.Generator):
    """A pose and a prismatic joint whose stroke carries the robot across the margin."""
    prismatic = [i for i, r in enumerate(model.chain.rows) if r.kind == "prismatic"]
    lo, hi = model.chain.lower, model.chain.upper
    for _ in range(500):
        q0 = rng.uniform(lo, hi)
        j = int(rng.choice(prismatic))
        ends = []
        for v in (lo[j], hi[j]):
            q = q0.copy()
            q[j] = v
            ends.append(exact.check(q).distance)
        if min(ends) < MARGIN - 0.005 and max(ends) > MARGIN + 0.005:
            return q0, j
    raise AssertionError("no pose found whose prismatic stroke crosses the margin")


def test_margin_is_honoured_exactly(robot):
    """Poses at margin +- 0.1 mm get the right verdict, and the brute force agrees."""
    from scipy.optimize import brentq

    model, geometry, exact, cycle = robot
    q0, joint = crossing_path(model, exact, np.random.default_rng(21))

    def q_at(v: float) -> np.ndarray:
        q = q0.copy()
        q[joint] = v
        return q

    grid = np.linspace(model.chain.lower[joint], model.chain.upper[joint], 101)
    d = np.array([exact.check(q_at(v)).distance for v in grid])
    for offset, contact in ((1e-4, False), (-1e-4, True)):
        target = MARGIN + offset
        k = np.flatnonzero((d[:-1] - target) * (d[1:] - target) < 0)[0]
        v = brentq(lambda v: exact.check(q_at(v)).distance - target, grid[k], grid[k + 1],
                   xtol=1e-14)
        q = q_at(v)
        rep = exact.check(q)
        assert rep.distance == pytest.approx(MARGIN + offset, abs=1e-9)
        assert rep.contact is contact
        assert oracle_contact(geometry, exact.gantry.tris, q, MARGIN) is contact
        assert cycle.check(q).distance <= rep.distance


def test_a_link_wholly_inside_the_gantry_is_contact():
    """The needle carriage of the arc robot pushed through the bore wall into the gantry's
    tube: 24 mm from the nearest surface, but inside. A surface distance (and PyBullet's
    concave mesh) cannot tell; the ray-parity test and the interlock's bound do."""
    model = get_robot("arc-train")
    exact, cycle = GantryContact(model), GantryClearance(model)
    q = np.array([1.93933416, 0.78526894, 0.53738164, -0.04532589, -0.50410689, 0.99244904,
                  1.14917698, 0.0741995, 0.08924421])
    rep = exact.check(q)
    k = rep.links.index("d10_link")
    assert rep.enclosed[k] and rep.distances[k] == 0.0 and rep.contact
    assert cycle.distances(q)[k] < -0.1
    with PyBulletDistances(URDF_DIR / "arc_train.urdf", URDF_DIR / "ct_gantry.urdf") as pbd:
        assert pbd.min_distance(q) > 0.015  # PyBullet sees no surface closer than ~2 cm
