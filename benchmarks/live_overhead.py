"""What ``--live`` costs the control loop, with a browser connected, measured in one run.

The loop is the trial as the rig would run it in simulation (the lab's servo
table through the servo model, interlocks on, the log journaled to its run
directory as a trial does), once plain and once with the live view serving that
run directory to headless Chromium polling it as a person's browser would. The
two run interleaved ``--repeats`` times; the best and the median of each are
printed with their ratio (target: live/plain <= 1.05).

    python benchmarks/live_overhead.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.core.runner import Runner
from bench.live.follow import RunFollower
from bench.live.server import LiveServer
from bench.rig.backends import make_backend
from bench.trial.plan import interlocks_for, plan, prepare

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "hil_configs" / "sim_target1.yaml"
LAB = ROOT / "hil_configs" / "lab_real.yaml"


def _config():
    lab = load_trial_config(LAB).backend
    return load_trial_config(CONFIG, {"backend": {
        "kind": "pybullet", "servo_model": "datasheet",
        "servos": {n: s.model_dump() for n, s in lab.servos.items()},
        "ultrasonic": lab.ultrasonic.model_dump()}})


def loop(live: bool) -> float:
    """Wall time of one trial's control loop (s), with or without the live view and a browser."""
    cfg = _config()
    prep = prepare(cfg)
    out = Path(tempfile.mkdtemp(prefix="live-bench-"))
    profile = Path(tempfile.mkdtemp(prefix="live-bench-browser-"))  # beside the runs, not among them
    server = browser = None
    try:
        if live:
            server = LiveServer(RunFollower(out, lambda: prep), on_stop=lambda: None).start()
            browser = subprocess.Popen([shutil.which("chromium") or "chromium", "--headless=new", "--no-sandbox",
                                        "--disable-gpu", f"--user-data-dir={profile}", server.url],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            deadline = time.monotonic() + 20
            while server._last_poll < 0 and time.monotonic() < deadline:  # the page is polling
                time.sleep(0.05)
        run_dir = out / "run"
        run_dir.mkdir()
        act = make_backend(prep.config, prep.robot)
        with act:
            segments = plan(prep, act.read().position, act.limits.velocity)
            log = TrialLog(list(prep.robot.joint_names), metadata={"config": {}})
            log.journal_to(run_dir)
            runner = Runner(act, cfg.control_period, interlocks=interlocks_for(prep, act))
            t0 = time.perf_counter()
            runner.run(segments, log)
            wall = time.perf_counter() - t0
            log.close_journal()
        return wall
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
    args = ap.parse_args()
    plain, live = [], []
    for _ in range(args.repeats):
        plain.append(loop(False))
        live.append(loop(True))
    for name, times in (("plain", plain), ("live + browser", live)):
        print(f"{name:>15}: best {min(times):.3f} s, median {statistics.median(times):.3f} s")
    print(f"live/plain: best {min(live) / min(plain):.3f}, median "
          f"{statistics.median(live) / statistics.median(plain):.3f} (target <= 1.05)")


if __name__ == "__main__":
    main()
