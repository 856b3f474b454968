"""The bench's control loop against a bare PyBullet loop on the same scene, in one run.

Both run Target 1's plan (home -> entry -> insertion -> retract) with the same
commanded trajectory, one physics step per control cycle (1 kHz), then at the
configured 500 Hz. The bare loop is what a hand-written script would do:
setJointMotorControlArray + stepSimulation + getJointStates. Prints the time
ratio (target <= 1.3) and the bench's real-time factor (target >= 20).

    python benchmarks/sim_overhead.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench.config import load_trial_config
from bench.log import TrialLog
from bench.runner import Runner
from bench.trial import interlocks_for, make_backend, plan, prepare

CONFIG = Path(__file__).resolve().parent.parent / "hil_configs" / "sim_target1.yaml"


def bench_loop(control_hz: float, interlocks: bool = False) -> tuple[float, float, int]:
    cfg = load_trial_config(CONFIG, {"control_hz": control_hz})
    prep = prepare(cfg)
    act = make_backend(prep)
    with act:
        segments = plan(prep, act.read().position, act.limits.velocity)
        log = TrialLog(list(prep.robot.joint_names))
        runner = Runner(act, cfg.control_period,
                        interlocks=interlocks_for(prep, act) if interlocks else None)
        t0 = time.perf_counter()
        runner.run(segments, log)
        wall = time.perf_counter() - t0
        return wall, act.now(), len(log)


def bare_loop(control_hz: float) -> tuple[float, float, int]:
    """Same scene and commands, no bench: the reference a script would write."""
    cfg = load_trial_config(CONFIG, {"control_hz": control_hz})
    prep = prepare(cfg)
    act = make_backend(prep)  # the same world, built the same way; driven by hand below
    pb, c, body = act._pb, act.client, act.robot
    idx = act._joint_index
    n = len(idx)
    segments = plan(prep, act.read().position, act.limits.velocity)
    dt = cfg.control_period
    steps = int(round(dt * cfg.backend.physics_hz))
    q_cmd, qd_cmd = [], []
    for seg in segments:
        k = int(np.ceil((seg.trajectory.duration + seg.settle) / dt - 1e-9)) + 1
        q, qd, _ = seg.trajectory.sample(np.arange(k) * dt)
        q_cmd.append(q)
        qd_cmd.append(qd)
    q_cmd = np.concatenate(q_cmd).tolist()
    qd_cmd = np.concatenate(qd_cmd).tolist()
    forces = act.limits.effort.tolist()
    kp = [cfg.backend.position_gain] * n
    kd = [cfg.backend.velocity_gain] * n
    t0 = time.perf_counter()
    for q, qd in zip(q_cmd, qd_cmd):
        pb.setJointMotorControlArray(body, idx, pb.POSITION_CONTROL, targetPositions=q,
                                     targetVelocities=qd, forces=forces, positionGains=kp,
                                     velocityGains=kd, physicsClientId=c)
        for _ in range(steps):
            pb.stepSimulation(physicsClientId=c)
        pb.getJointStates(body, idx, physicsClientId=c)
    wall = time.perf_counter() - t0
    sim_time = len(q_cmd) * dt
    act.close()
    return wall, sim_time, len(q_cmd)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="best of N for each loop")
    args = ap.parse_args()
    print(f"{'control':>8} {'loop':>8} {'cycles':>7} {'wall (s)':>9} {'us/cycle':>9} {'RTF':>7}")
    for hz in (1000.0, 500.0):
        best = {}
        loops = (("bench", bench_loop), ("+safety", lambda h: bench_loop(h, True)),
                 ("bare", bare_loop))
        for name, fn in loops:
            runs = [fn(hz) for _ in range(args.repeats)]
            wall, sim_t, cycles = min(runs, key=lambda r: r[0])
            best[name] = wall
            print(f"{hz:>6.0f}Hz {name:>8} {cycles:>7} {wall:>9.4f} {1e6 * wall / cycles:>9.1f} "
                  f"{sim_t / wall:>7.1f}")
        print(f"{'':>8} ratio bench/bare at {hz:.0f} Hz: {best['bench'] / best['bare']:.3f} "
              f"(target <= 1.3); with the trial's interlocks: {best['+safety'] / best['bare']:.3f}")
    print("real-time factor target: >= 20 on one core (bench loop, 1 kHz physics)")


if __name__ == "__main__":
    main()
