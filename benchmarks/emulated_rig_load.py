"""The emulated rig on a loaded machine: emulated trials and compares beside CPU hogs.

Starts ``--hogs`` CPU-bound processes (default 2, one per core of the CI
machine), then runs ``hilbench trial CONFIG --emulate`` ``--trials`` times and
``hilbench compare CONFIG --emulate --repeats 2`` ``--compares`` times, and
prints the pass counts; then, with the hogs gone, the idle CPU of ``hilbench
emulate`` (nothing commanded) over a few seconds. The hogs are killed on
every exit path.

    python benchmarks/emulated_rig_load.py [--hogs 2] [--trials 10] [--compares 3]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def start_hogs(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        p.wait()


def run(cmd: list[str], timeout: float) -> tuple[int, str, float]:
    t0 = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        return out.returncode, (out.stderr.strip().splitlines() or [""])[-1], time.perf_counter() - t0
    except subprocess.TimeoutExpired:
        return -1, f"timed out after {timeout:.0f} s", time.perf_counter() - t0


def idle_cpu(config: Path, seconds: float = 5.0) -> float:
    """CPU share of one core the emulator takes while nothing is commanded."""
    proc = subprocess.Popen([HILBENCH, "emulate", str(config), "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        json.loads(proc.stdout.readline())
        time.sleep(1.0)  # start-up over

        def cpu() -> float:
            fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

        c0, t0 = cpu(), time.perf_counter()
        time.sleep(seconds)
        return (cpu() - c0) / (time.perf_counter() - t0)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=REPO / "hil_configs" / "lab_real.yaml")
    ap.add_argument("--hogs", type=int, default=2)
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--compares", type=int, default=3)
    args = ap.parse_args()
    hogs = start_hogs(args.hogs)
    try:
        with tempfile.TemporaryDirectory() as out:
            passed = 0
            for i in range(args.trials):
                rc, last, wall = run([HILBENCH, "trial", str(args.config), "--emulate", "--json",
                                      "--out", out], 300)
                passed += rc == 0
                print(f"trial {i + 1}: exit {rc} in {wall:.1f} s" + (f"  ({last})" if rc else ""),
                      flush=True)
            cpassed = 0
            for i in range(args.compares):
                rc, last, wall = run([HILBENCH, "compare", str(args.config), "--emulate",
                                      "--repeats", "2", "--json", "--out", out], 900)
                cpassed += rc in (0, 1)  # ran to its verdict (1: the comparison failed a limit)
                print(f"compare {i + 1}: exit {rc} in {wall:.1f} s" + (f"  ({last})" if rc else ""),
                      flush=True)
    finally:
        stop(hogs)
    print(f"with {args.hogs} CPU hogs: trials passed {passed}/{args.trials}, compares ran to their "
          f"verdict {cpassed}/{args.compares}")
    print(f"emulator idle CPU (nothing commanded, no hogs): {100 * idle_cpu(args.config):.1f} % of a core")


if __name__ == "__main__":
    main()
