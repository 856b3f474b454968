"""What ``--live`` costs an emulated-rig trial, with Chromium drawing the page, measured in one run.

The trial is the one a technician rehearses: ``hilbench trial hil_configs/lab_real.yaml --emulate``
(the real Dynamixel driver, the emulated servo bus and ultrasonic sensor on pseudo-terminals, the
interlocks on), on the wall clock at 100 Hz. It runs ``--repeats`` times plain and, interleaved,
with ``--live`` and headless Chromium opened on the page's address as a person would (the trial
waits for the page, then the page polls and draws while the trial runs). For each side it prints
the share of the loop's deadlines missed (median, best, worst), the worst lateness, the bus
time's p99, and the trials that lost their bus; then the loop's priority and the load average.

Everything shares the machine's cores, as on a two-core bench computer: the trial, the emulated
rig, the live view's server and the browser.

    python benchmarks/live_overhead.py [--repeats 3] [--write-table]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from figures import record

ROOT = Path(__file__).resolve().parent.parent
LAB = ROOT / "hil_configs" / "lab_real.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _trial(live: bool) -> dict:
    """One emulated-rig trial, plain or with a browser on its live view: its --json result."""
    out = Path(tempfile.mkdtemp(prefix="live-bench-"))
    profile = Path(tempfile.mkdtemp(prefix="live-bench-browser-"))
    cmd = [HILBENCH, "trial", str(LAB), "--emulate", "--out", str(out), "--json"] + (["--live"] if live else [])
    browser = None
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if live:
            line = proc.stderr.readline()
            found = re.search(r"live view: (\S+)", line)
            if not found:
                raise SystemExit(f"no live view address: {line!r}")
            browser = subprocess.Popen(
                [shutil.which("chromium") or "chromium", "--headless=new", "--no-sandbox", "--disable-gpu",
                 "--disable-background-networking", "--disable-component-update", "--no-first-run",
                 f"--user-data-dir={profile}", "--window-size=1300,1000", found.group(1)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        out_text, err = proc.communicate(timeout=300)
        lines = [ln for ln in out_text.splitlines() if ln.startswith("{")]
        result = json.loads(lines[-1]) if lines else {"reason": err.strip()[-200:]}
        result["exit_code"] = proc.returncode
        return result
    finally:
        if browser is not None:
            os.killpg(browser.pid, 9)
            browser.wait()
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(profile, ignore_errors=True)


def _summary(name: str, runs: list[dict]) -> str:
    timing = [r.get("loop_timing") or {} for r in runs]
    shares = [100 * t.get("missed", 0) / t["cycles"] for t in timing if t.get("cycles")]
    worst = [t.get("worst_late_s") or 0.0 for t in timing]
    bus = [t.get("bus_p99_s") or 0.0 for t in timing]
    lost = sum(1 for r in runs if "did not answer" in str(r.get("reason", "")) or r["exit_code"] == 3)
    return (f"{name:>16}: deadlines missed {statistics.median(shares):.2f} % median, {min(shares):.2f} % best, "
            f"{max(shares):.2f} % worst; worst lateness {1e3 * max(worst):.1f} ms; bus p99 "
            f"{1e3 * statistics.median(bus):.2f} ms median; bus lost in {lost} of {len(runs)}; "
            f"exit codes {[r['exit_code'] for r in runs]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write-table", action="store_true", help="record the figures in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    plain, live = [], []
    for i in range(args.repeats):
        plain.append(_trial(False))
        live.append(_trial(True))
        print(f"repeat {i + 1}/{args.repeats} done", file=sys.stderr, flush=True)
    rows = {"live.plain": ("an emulated-rig trial (lab_real.yaml --emulate), plain", _summary("plain", plain)),
            "live.chromium": ("the same trial with its live view open in headless Chromium, drawing",
                              _summary("live + Chromium", live))}
    for _, line in rows.values():
        print(line)
    print(f"the loop's priority: {(plain[0].get('loop_timing') or {}).get('priority')}; "
          f"load average over the run: {os.getloadavg()[1]:.1f} on {os.cpu_count()} cores")
    if args.write_table:
        record("benchmarks/live_overhead.py", {k: (what, line.split(": ", 1)[1]) for k, (what, line) in rows.items()},
               f"{args.repeats} interleaved repeats")


if __name__ == "__main__":
    started = time.monotonic()
    main()
    print(f"({time.monotonic() - started:.0f} s)")
