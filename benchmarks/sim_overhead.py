"""The bench's control loop against a bare PyBullet loop on the same scene, in one run.

Both run Target 1's plan (home -> entry -> insertion -> retract) with the same
commanded trajectory, one physics step per control cycle (1 kHz), then at the
configured 500 Hz. The bare loop is what a hand-written script would do:
setJointMotorControlArray + stepSimulation + getJointStates, its commands
sampled and converted before the clock starts. The loops run interleaved,
``--repeats`` times each; the best and the median are printed with the
ratios (targets: bench <= 1.1, bench with the trial's interlocks <= 1.3) and
the real-time factor (target >= 20), then Target 1 sim trials per minute on
one and two worker processes. The ``+servo`` row is the trial as the rig would
run it in simulation: ``backend.servo_model: datasheet`` with the lab's servo
table and ultrasonic sensor, interlocks on (target: +servo/bare <= 1.3, a
real-time factor >= 15).

    python benchmarks/sim_overhead.py [--repeats 7] [--trials 8]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.core.runner import Runner
from bench.rig.backends import make_backend
from bench.trial.plan import interlocks_for, plan, prepare
from figures import record

CONFIG = Path(__file__).resolve().parent.parent / "hil_configs" / "sim_target1.yaml"
LAB = CONFIG.with_name("lab_real.yaml")


def _servo_backend() -> dict:
    """The PyBullet backend running the lab's servo table through the servo model."""
    lab = load_trial_config(LAB).backend
    return {"kind": "pybullet", "servo_model": "datasheet",
            "servos": {n: s.model_dump() for n, s in lab.servos.items()},
            "ultrasonic": lab.ultrasonic.model_dump()}


def bench_loop(control_hz: float, interlocks: bool = False, servo: bool = False) -> tuple[float, float, int]:
    overrides: dict = {"control_hz": control_hz}
    if servo:
        overrides["backend"] = _servo_backend()
    cfg = load_trial_config(CONFIG, overrides)
    prep = prepare(cfg)
    act = make_backend(prep.config, prep.robot)
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
    act = make_backend(prep.config, prep.robot)  # the same world, built the same way; driven by hand below
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


def trials_per_minute(workers: int, trials: int) -> float:
    """Target 1 sim trials (the config as a user runs it: interlocks on, log, no report
    figures) per minute on ``workers`` processes."""
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        list(pool.map(_one_trial, range(trials)))
    return trials / (time.perf_counter() - t0) * 60.0


def _one_trial(i: int) -> bool:
    import tempfile

    from bench.trial.run import TrialHooks, run_trial

    cfg = load_trial_config(CONFIG)
    with tempfile.TemporaryDirectory() as out:
        return run_trial(prepare(cfg), Path(out), TrialHooks(report=False)).passed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="runs of each loop, interleaved")
    ap.add_argument("--trials", type=int, default=8, help="trials for the trials-per-minute rows")
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    loops = (("bench", bench_loop), ("+safety", lambda h: bench_loop(h, True)), ("bare", bare_loop),
             ("+servo", lambda h: bench_loop(h, True, servo=True)))
    print(f"{'control':>8} {'loop':>8} {'cycles':>7} {'best us':>8} {'median us':>10} "
          f"{'RTF best':>9} {'RTF med':>8}")
    table: dict[str, tuple[str, str]] = {}
    for hz in (1000.0, 500.0):
        runs: dict[str, list] = {name: [] for name, _ in loops}
        for _ in range(args.repeats):  # interleaved, so a noisy minute hits every loop alike
            for name, fn in loops:
                runs[name].append(fn(hz))
        best, med = {}, {}
        for name, _ in loops:
            per_cycle = sorted(w / c for w, _, c in runs[name])
            sim_t, cycles = runs[name][0][1], runs[name][0][2]
            best[name], med[name] = per_cycle[0], statistics.median(per_cycle)
            print(f"{hz:>6.0f}Hz {name:>8} {cycles:>7} {1e6 * best[name]:>8.1f} "
                  f"{1e6 * med[name]:>10.1f} {sim_t / (best[name] * cycles):>9.1f} "
                  f"{sim_t / (med[name] * cycles):>8.1f}")
        for name, target in (("bench", 1.1), ("+safety", 1.3), ("+servo", 1.3)):
            print(f"{'':>8} {name}/bare at {hz:.0f} Hz: best {best[name] / best['bare']:.3f}, "
                  f"median {med[name] / med['bare']:.3f} (target <= {target})")
            key = {"bench": "sim.bench_bare", "+safety": "sim.safety_bare", "+servo": "sim.servo_bare"}[name]
            what = {"bench": "bench loop / bare PyBullet loop", "+safety": "with the interlocks / bare",
                    "+servo": "servo-model trial (interlocks on) / bare"}[name]
            before = table.get(key, ("", ""))[1]
            value = f"{best[name] / best['bare']:.2f} / {med[name] / med['bare']:.2f} at {hz / 1000:g} kHz"
            table[key] = (f"{what}, best / median (target ≤ {target})", f"{before}; {value}" if before else value)
        if hz == 1000.0:
            sim_t, cycles = runs["bench"][0][1], runs["bench"][0][2]
            table["sim.rtf"] = ("real-time factor of the bench loop at 1 kHz (target ≥ 20)",
                                f"about {sim_t / (med['bench'] * cycles):.0f}")
    print("real-time factor target: >= 20 on one core (bench loop, 1 kHz physics); "
          ">= 15 with the servo model (+servo)")
    rates = []
    for workers in (1, 2):
        rate = trials_per_minute(workers, args.trials)
        rates.append(rate)
        print(f"Target 1 sim trials (interlocks on, no figures), {workers} worker"
              f"{'s' if workers > 1 else ''}: {rate:.1f} trials/min")
    table["sim.trials_per_min"] = ("Target 1 sim trials per minute, one / two workers", f"{rates[0]:.0f} / {rates[1]:.0f}")
    if args.write_table:
        record("benchmarks/sim_overhead.py", table, f"{args.repeats} interleaved repeats")


if __name__ == "__main__":
    main()
