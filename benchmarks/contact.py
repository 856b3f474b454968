"""Robot-vs-gantry contact checks timed against each other, in one run.

For each robot, at poses 15-25 mm from the gantry (where pruning helps least)
and at home:

* the exact test (``GantryContact.check``: box tree + triangle distances), as
  configured by default (every link's distance exact up to margin + 10 mm) and
  answering what the paper's test answers (``reach`` = margin: the verdict at
  the margin, with exact distances below it). Each is set against the brute
  force that gives the same answer: all pairs' distances, and the paper's
  yes/no test of every pair (whose margin comes from inflating the robot),
* the per-cycle interlock (``GantryClearance.check``, all links; target
  <= 0.5 ms for the arc robot, to fit a 1 kHz loop), and the safety
  interlock built on it along a path from home to a near pose,
* the paper's all-pairs method on the same meshes, both with the triangle
  distance (needed for a margin) and with the paper's own yes/no test of
  eqs 4-6. All pairs take seconds to minutes, so a random subset of pairs is
  timed and the time scaled to the full count (said so in the output), each
  kernel in the batch size (of a few tried) it runs fastest at.

Then PyBullet's step cost with the concave gantry mesh in the arc robot's
contact pairs against filtered out (``SceneObject(collide=False)``), at
Target 1 and at a pose near the gantry.

Times are CPU seconds of this process (``time.process_time``), the best of a
few repeats, so other load on the machine disturbs them little.

    python benchmarks/contact.py [--pairs 200000] [--steps 3000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.geometry.tri_distance import paper_intersects, triangle_distance
from bench.kinematics.arc_train import TARGET_1
from bench.kinematics.registry import get_robot
from bench.scene.contact import GantryClearance, GantryContact, default_gantry

ALL_PAIRS_CHUNKS = (1024, 4096, 16384, 65536)  # batch sizes tried for the brute force


def best_time(fn, repeats: int = 5, number: int = 10) -> float:
    """Best per-call CPU time of ``fn`` over ``repeats`` runs of ``number`` calls."""
    fn()
    out = []
    for _ in range(repeats):
        t = time.process_time()
        for _ in range(number):
            fn()
        out.append((time.process_time() - t) / number)
    return min(out)


def all_pairs_time(robot_tris: np.ndarray, gantry_tris: np.ndarray, pairs: int,
                   rng: np.random.Generator,
                   chunks: tuple[int, int] | None = None) -> tuple[float, float, int, tuple[int, int]]:
    """Extrapolated CPU time of every robot × gantry pair: (distance, paper's test, total),
    each kernel run in the batch size it is fastest at (found here unless ``chunks`` gives
    them), and those sizes."""
    total = len(robot_tris) * len(gantry_tris)
    k = min(pairs, total)
    idx = rng.choice(total, size=k, replace=False)
    ia, ib = np.divmod(idx, len(gantry_tris))
    A, B = robot_tris[ia], gantry_tris[ib]

    def run(kernel, chunk: int, n: int) -> float:
        t = time.process_time()
        for s in range(0, n, chunk):
            kernel(A[s:s + chunk], B[s:s + chunk])
        return (time.process_time() - t) / n

    kernels = (triangle_distance, paper_intersects)
    if chunks is None:
        trial = min(k, 100_000)
        chunks = tuple(min(ALL_PAIRS_CHUNKS, key=lambda c: min(run(f, c, trial) for _ in range(2)))
                       for f in kernels)
    t_dist, t_paper = (run(f, c, k) * total for f, c in zip(kernels, chunks))
    return t_dist, t_paper, total, chunks


def interlock_along_path(model, cycle: GantryClearance, q_from: np.ndarray, q_to: np.ndarray,
                         steps: int = 2000) -> tuple[float, float, int]:
    """The safety interlock (measured and commanded, last result carried forward while it
    provably clears the margin) along a straight joint path: median and worst CPU time per
    control cycle, and how many cycles tripped."""
    from bench.core.safety import GantryClearanceInterlock
    from drivers import JointState

    il = GantryClearanceInterlock(model, cycle.margin, cycle)
    n = len(q_from)
    times, trips = [], 0
    for s in np.linspace(0.0, 1.0, steps):
        q = q_from + s * (q_to - q_from)
        st = JointState(0.0, q, np.zeros(n), np.zeros(n))
        t = time.process_time()
        trips += il.check(0.0, st, q) is not None
        times.append(time.process_time() - t)
    return float(np.median(times)), float(np.max(times)), trips


def near_poses(model, clearance: GantryClearance, exact: GantryContact, n: int,
               rng: np.random.Generator) -> np.ndarray:
    """Poses whose exact distance to the gantry lies between 15 and 25 mm."""
    Q = rng.uniform(model.chain.lower, model.chain.upper, (20_000, len(model.joint_names)))
    d = clearance.distances_batch(Q).min(axis=1)
    keep = [q for q in Q[(d > 0.010) & (d < 0.025)] if 0.015 <= exact.check(q).distance <= 0.025]
    if len(keep) < n:
        raise RuntimeError(f"only {len(keep)} random poses lie 15-25 mm from the gantry")
    return np.array(keep[:n])


def pybullet_step_cost(q: np.ndarray, steps: int) -> tuple[float, float]:
    """CPU seconds per physics step of the arc robot held at ``q``, with the gantry in the
    contact pairs and filtered out."""
    from bench.scene.room import URDF_DIR
    from drivers.pybullet.backend import PyBulletActuators, PyBulletSettings, SceneObject

    model = get_robot("arc-train")
    out = []
    for collide in (True, False):
        scene = [SceneObject(URDF_DIR / "ct_gantry.urdf", collide=collide),
                 SceneObject(URDF_DIR / "ct_bed.urdf"), SceneObject(URDF_DIR / "phantom.urdf")]
        settings = PyBulletSettings(URDF_DIR / "arc_train.urdf", model.joint_names, scene,
                                    physics_hz=1000.0, control_period=0.001,
                                    initial_position=q)
        with PyBulletActuators(settings) as sim:
            sim.enable()
            sim.command(q)
            sim.wait_until(0.05)
            t0 = sim.now()
            t = time.process_time()
            sim.wait_until(t0 + steps * sim.physics_dt)
            out.append((time.process_time() - t) / steps)
    return out[0], out[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=200_000, help="pairs timed for all-pairs")
    ap.add_argument("--poses", type=int, default=5, help="near poses per robot")
    ap.add_argument("--steps", type=int, default=3000, help="PyBullet steps timed")
    ap.add_argument("--passes", type=int, default=3, help="interleaved passes; best kept")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--save-poses", metavar="PREFIX", help="save the near poses to PREFIX_ROBOT.npy")
    args = ap.parse_args()
    gantry = default_gantry()
    print(f"gantry mesh: {len(gantry.tris)} triangles (torus, 70 cm bore); margin 20 mm; "
          f"CPU time per check, best of 5 x 10 calls in each of {args.passes} passes")
    near_arc = None
    for k, name in enumerate(("arc-train", "zerobot")):
        model = get_robot(name)
        rng = np.random.default_rng([args.seed, k])  # the same poses whatever else runs
        exact = GantryContact(model, gantry=gantry)
        verdict = GantryContact(model, gantry=gantry, reach=exact.margin)
        cycle = GantryClearance(model, gantry=gantry)
        g = exact.geometry
        poses = near_poses(model, cycle, exact, args.poses, rng)
        if near_arc is None:
            near_arc = poses[0]
        if args.save_poses:
            np.save(f"{args.save_poses}_{name}.npy", poses)
        home = model.chain.home
        robot_tris = g.world_triangles(g.link_frames(poses[0]))[0]
        # passes interleave the checks and the brute force, and each figure keeps its best:
        # a shared machine slows the overhead-bound checks and the throughput-bound brute
        # force differently from minute to minute
        runs, chunks = [], None
        for _ in range(args.passes):
            t_all, t_paper, total, chunks = all_pairs_time(robot_tris, gantry.tris, args.pairs,
                                                           rng, chunks)
            runs.append(([best_time(lambda q=q: exact.check(q)) for q in poses],
                         [best_time(lambda q=q: cycle.check(q), number=50) for q in poses],
                         best_time(lambda: exact.check(home)),
                         best_time(lambda: cycle.check(home), number=50), t_all, t_paper,
                         [best_time(lambda q=q: verdict.check(q)) for q in poses]))
        t_exact, t_cycle, t_verdict = (np.min([r[i] for r in runs], axis=0) for i in (0, 1, 6))
        t_exact_home, t_cycle_home, t_all, t_paper = (min(r[i] for r in runs) for i in range(2, 6))
        c_all, c_paper = chunks
        worst_exact, worst_cycle, worst_verdict = max(t_exact), max(t_cycle), max(t_verdict)
        print(f"\n{name}: {len(g.links)} links, {len(robot_tris)} robot triangles; "
              f"{len(poses)} poses 15-25 mm from the gantry")
        print(f"  exact test (pruned)        {worst_exact * 1e3:9.3f} ms worst near, "
              f"{np.median(t_exact) * 1e3:.3f} ms median, {t_exact_home * 1e3:.3f} ms at home "
              f"(near poses: {' '.join(f'{t * 1e3:.2f}' for t in t_exact)} ms)")
        print(f"  exact test, reach = margin {worst_verdict * 1e3:9.3f} ms worst near, "
              f"{np.median(t_verdict) * 1e3:.3f} ms median "
              f"(near poses: {' '.join(f'{t * 1e3:.2f}' for t in t_verdict)} ms)")
        print(f"  per-cycle interlock        {worst_cycle * 1e3:9.3f} ms worst near, "
              f"{np.median(t_cycle) * 1e3:.3f} ms median, {t_cycle_home * 1e3:.3f} ms at home"
              + ("   (target <= 0.5 ms)" if name == "arc-train" else ""))
        med, worst, trips = interlock_along_path(model, cycle, home, poses[0])
        print(f"  safety interlock per cycle {med * 1e3:9.3f} ms median, {worst * 1e3:.3f} ms worst "
              f"(measured + commanded; 2000 cycles straight in joint space from home to a near "
              f"pose, {trips} of them inside the margin)")
        print(f"  all pairs, distance        {t_all:9.3f} s   ({total:,} pairs; {args.pairs:,} "
              f"timed and scaled; batches of {c_all:,}, the fastest tried)")
        print(f"  all pairs, paper eqs 4-6   {t_paper:9.3f} s   (yes/no only; same extrapolation; "
              f"batches of {c_paper:,})")
        print(f"  ratios, worst near pose, like for like (target >= 1000x): distances, all pairs / "
              f"exact = {t_all / worst_exact:,.0f}x; the verdict at the margin, paper's test / "
              f"exact at the margin = {t_paper / worst_verdict:,.0f}x")
        print(f"  other ratios: paper's yes/no test / exact with distances to margin + 10 mm = "
              f"{t_paper / worst_exact:,.0f}x; exact / interlock = {worst_exact / worst_cycle:,.1f}x")
    arc = get_robot("arc-train")
    print("\nPyBullet step of the arc robot (1 kHz, position control, bed and phantom colliding):")
    for label, q in (("at Target 1", arc.ik(TARGET_1)), ("15-25 mm from the gantry", near_arc)):
        with_g, without = pybullet_step_cost(q, args.steps)
        print(f"  {label:26s} gantry in the contact pairs {with_g * 1e6:6.1f} us, filtered out "
              f"{without * 1e6:6.1f} us (ratio {with_g / without:.2f}x)")

if __name__ == "__main__":
    main()
