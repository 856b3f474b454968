"""CI as a new user meets it: ``.ci/run`` in a fresh clone of this commit, timed, optionally beside
CPU hogs; prints the run's own ``ci time`` line, pytest's closing line and the slowest tests.

    python benchmarks/ci_time.py [--hogs 2] [--keep]

The hogs are busy loops at the default priority (what another job on the CI machine is): the
suite's timing-sensitive tests must pass beside them.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hogs", type=int, default=0, help="CPU hogs to run beside the suite")
    ap.add_argument("--keep", action="store_true", help="keep the clone (its path is printed)")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="ci-time-"))
    clone = work / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    commit = subprocess.run(["git", "-C", str(clone), "rev-parse", "--short", "HEAD"], check=True,
                            capture_output=True, text=True).stdout.strip()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.hogs)]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTEST"))}
    env["CI"] = "true"
    started = time.monotonic()
    try:
        run = subprocess.run(["bash", ".ci/run"], cwd=clone, env=env, stdin=subprocess.DEVNULL,
                             capture_output=True, text=True)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    took = time.monotonic() - started
    out = run.stdout + run.stderr
    (work / "ci.log").write_text(out)
    lines = out.splitlines()
    ci_line = next((ln for ln in lines if ln.startswith("ci time:")), "ci time: (not printed)")
    closing = next((ln for ln in reversed(lines) if re.search(r"\d+ (passed|failed)", ln)), "(no closing line)")
    slow = [ln for ln in lines if re.match(r"\s*\d+\.\d+s (call|setup|teardown)", ln)]
    print(f"commit {commit}, {args.hogs} CPU hog(s) beside it: exit {run.returncode} after {took:.0f} s")
    print(ci_line)
    print(closing.strip("= "))
    print("slowest:\n" + "\n".join(slow))
    if args.keep:
        print(f"clone and log kept in {work}")
    else:
        shutil.rmtree(work, ignore_errors=True)
    return run.returncode


if __name__ == "__main__":
    sys.exit(main())
