"""What ``--live`` costs the control loop, with a browser connected, measured in one run.

The loop is the trial as the rig would run it in simulation (the lab's servo
table through the servo model, interlocks on, the log journaled to its run
directory as a trial does), once plain and once with the live view serving that
run directory to headless Chromium polling it as a person's browser would. The
two run interleaved ``--repeats`` times; the best and the median of each are
printed with their ratio (target: live/plain <= 1.05).

"A browser connected" means a page already open and polling, as a technician's is
when the trial starts: the loop is timed once Chromium has loaded the page and gone
quiet (its start-up, about half a second of a core, is not the live view's cost).
Beside the ratios (best, median, and the median of each interleaved pair's, which a
machine whose load drifts disturbs least) it prints the loop's own CPU time live/plain
(what the server's threads cost the loop through the interpreter's lock and the caches)
and where the live side's time went: the CPU the server's threads took in the trial's
process (polls: reading the journal, the margins of its newest row, JSON) and the CPU
the browser took while the loop ran; then the machine's load average.

``--pin`` puts the trial's process on one core and the browser on the other, as a quiet
two-core machine's scheduler would: on a shared machine whose load exceeds its cores, the
browser otherwise takes its share of the loop's core too.

    python benchmarks/live_overhead.py [--repeats 5] [--pin]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.core.runner import Runner
from bench.live.follow import RunFollower
from bench.live.server import LiveServer
from bench.rig.backends import make_backend
from bench.trial.plan import interlocks_for, plan, prepare
from figures import record

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "hil_configs" / "sim_target1.yaml"
LAB = ROOT / "hil_configs" / "lab_real.yaml"
_TICK = os.sysconf("SC_CLK_TCK")


def _config(velocity_scale: float):
    lab = load_trial_config(LAB).backend
    return load_trial_config(CONFIG, {"plan": {"velocity_scale": velocity_scale}, "backend": {
        "kind": "pybullet", "servo_model": "datasheet",
        "servos": {n: s.model_dump() for n, s in lab.servos.items()},
        "ultrasonic": lab.ultrasonic.model_dump()}})


def group_cpu_s(pgid: int) -> float:
    """CPU time (user + system, s) of every live process in a process group (the browser's)."""
    total = 0.0
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            if int(fields[2]) == pgid:  # after the name: state, ppid, pgrp, ..., utime (11), stime (12)
                total += _cpu_s(f"/proc/{pid}/stat")
        except OSError:
            continue
    return total


def _cpu_s(stat: str) -> float:
    fields = Path(stat).read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICK


def _threads_cpu_s(but: int) -> float:
    """CPU time of this process's threads other than ``but`` (a native thread id), those that
    have ended included (the server answers each request on a thread of its own)."""
    return _cpu_s("/proc/self/stat") - _cpu_s(f"/proc/self/task/{but}/stat")


def _settle(server: LiveServer, pgid: int, timeout_s: float = 20.0) -> None:
    """Until the page polls and the browser has used under 5 % of a core for half a second."""
    deadline = time.monotonic() + timeout_s
    while server._last_poll < 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    before = group_cpu_s(pgid)
    while time.monotonic() < deadline:
        time.sleep(0.5)
        now = group_cpu_s(pgid)
        if now - before < 0.025:
            return
        before = now


def _cores() -> tuple[set[int], set[int]] | None:
    """One core for the trial's process and another for the browser, or None if there are not two."""
    cpus = sorted(os.sched_getaffinity(0))
    return ({cpus[0]}, {cpus[-1]}) if len(cpus) >= 2 else None


def loop(live: bool, browser_cores: set[int] | None = None, velocity_scale: float = 0.01) -> dict[str, float]:
    """One trial's control loop: its wall time and CPU time (s), with the live view the CPU (s)
    the server's threads and the browser took meanwhile and the page's polls."""
    cfg = _config(velocity_scale)
    prep = prepare(cfg)
    out = Path(tempfile.mkdtemp(prefix="live-bench-"))
    profile = Path(tempfile.mkdtemp(prefix="live-bench-browser-"))  # beside the runs, not among them
    server = browser = None
    try:
        if live:
            server = LiveServer(RunFollower(out, lambda: prep), on_stop=lambda: None).start()
            browser = subprocess.Popen([shutil.which("chromium") or "chromium", "--headless=new", "--no-sandbox",
                                        "--disable-gpu", f"--user-data-dir={profile}", server.url],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                       start_new_session=True,
                                       preexec_fn=(lambda: os.sched_setaffinity(0, browser_cores))
                                       if browser_cores else None)
            _settle(server, browser.pid)
        run_dir = out / "run"
        run_dir.mkdir()
        act = make_backend(prep.config, prep.robot)
        with act:
            segments = plan(prep, act.read().position, act.limits.velocity)
            log = TrialLog(list(prep.robot.joint_names), metadata={"config": {}})
            log.journal_to(run_dir)
            runner = Runner(act, cfg.control_period, interlocks=interlocks_for(prep, act))
            me = threading.get_native_id()
            threads0, browser0 = _threads_cpu_s(me), group_cpu_s(browser.pid) if browser else 0.0
            polls0 = server.polls if server else 0
            t0, cpu0 = time.perf_counter(), time.thread_time()
            runner.run(segments, log)
            wall, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
            threads = _threads_cpu_s(me) - threads0
            browser_cpu = group_cpu_s(browser.pid) - browser0 if browser else 0.0
            log.close_journal()
            polls = server.polls - polls0 if server else 0
        return {"wall": wall, "loop_cpu": cpu, "server": threads, "browser": browser_cpu, "polls": polls}
    finally:
        if browser is not None:
            browser.kill()
            browser.wait()
        if server is not None:
            server.close(linger=False)
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(profile, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--pin", action="store_true", help="the trial on one core, the browser on another")
    ap.add_argument("--velocity-scale", type=float, default=0.01,
                    help="the plan's speed: at 0.01 the loop lasts seconds, so the page polls during it "
                         "(at the configured 0.5 it ends before the page's first poll)")
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    cores = _cores() if args.pin else None
    if cores:
        os.sched_setaffinity(0, cores[0])
    plain, live = [], []
    for _ in range(args.repeats):
        plain.append(loop(False, velocity_scale=args.velocity_scale))
        live.append(loop(True, cores and cores[1], args.velocity_scale))
    for name, runs in (("plain", plain), ("live + browser", live)):
        times = [r["wall"] for r in runs]
        print(f"{name:>15}: best {min(times):.3f} s, median {statistics.median(times):.3f} s")
    best = min(r["wall"] for r in live) / min(r["wall"] for r in plain)
    median = statistics.median(r["wall"] for r in live) / statistics.median(r["wall"] for r in plain)
    paired = statistics.median(b["wall"] / a["wall"] for a, b in zip(plain, live))
    print(f"live/plain: best {best:.3f}, median {median:.3f}, median of the interleaved pairs {paired:.3f} "
          f"(target <= 1.05)")
    cpu = statistics.median(b["loop_cpu"] / a["loop_cpu"] for a, b in zip(plain, live))
    print(f"the loop's own CPU time, live/plain (median of pairs): {cpu:.3f}")
    wall = statistics.median(r["wall"] for r in live)
    print(f"while the live loop ran (median): the server's threads {statistics.median(r['server'] for r in live):.3f} s"
          f" of CPU, the browser {statistics.median(r['browser'] for r in live):.3f} s, in {wall:.3f} s; "
          f"the page polled {statistics.median(r['polls'] for r in live):.0f} times")
    print(f"load average over the run: {os.getloadavg()[1]:.1f} on {os.cpu_count()} cores"
          + (f"; the trial pinned to core {min(cores[0])}, the browser to core {min(cores[1])}" if cores else ""))
    if args.write_table:
        record("benchmarks/live_overhead.py", {
            "live.overhead": ("servo-model trial loop with the live view / without, best, median, median of "
                              "pairs (target ≤ 1.05)", f"{best:.3f}, {median:.3f}, {paired:.3f}"),
            "live.cpu": ("the live view's CPU: loop live/plain; server threads; browser",
                         f"{cpu:.3f}; {statistics.median(r['server'] for r in live):.2f} s per loop; "
                         f"{statistics.median(r['browser'] for r in live):.2f} s")},
            f"{args.repeats} interleaved pairs")

if __name__ == "__main__":
    main()
