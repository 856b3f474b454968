"""How long CI takes: `.ci/run` in a fresh clone of this checkout, timed, its tests counted.

    python benchmarks/suite_time.py [--hogs 2] [--write-table]

Clones the checkout's HEAD into a temporary folder (a fresh clone, as CI has), runs its
`.ci/run` and prints the wall time, the pytest summary line, the run's own ``ci time`` line and
its 15 slowest tests (the failures and warnings, if any, and the whole output kept); ``--hogs N`` runs N busy
loops beside it (a shared machine), ``--serial`` the suite one file after another instead.
With ``--write-table`` the figure goes to docs/figures.json (docs/figures.md).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from figures import ROOT, record


def _hog() -> None:
    while True:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hogs", type=int, default=0, help="busy loops beside the suite")
    ap.add_argument("--serial", action="store_true", help="the suite one file after another, no workers")
    ap.add_argument("--write-table", action="store_true", help="record the figure in docs/figures.json (docs/figures.md)")
    args = ap.parse_args()
    hogs = [multiprocessing.Process(target=_hog, daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    try:
        with tempfile.TemporaryDirectory() as d:
            clone = Path(d) / "clone"
            subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
            if args.serial:
                cmd = ["bash", "-c", "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && "
                                     ".venv/bin/pytest -q -p no:cacheprovider"]
            else:
                cmd = [str(clone / ".ci" / "run")]
            t0 = time.perf_counter()
            env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTEST"))}
            done = subprocess.run(cmd, cwd=clone, capture_output=True, text=True, stdin=subprocess.DEVNULL,
                                  env=env | {"CI": "true"})
            wall = time.perf_counter() - t0
    finally:
        for h in hogs:
            h.terminate()
    out = done.stdout + done.stderr
    lines = out.splitlines()
    summary = next((ln for ln in reversed(lines) if re.search(r"\d+ (passed|failed)", ln)), "?").strip("= ")
    ci_line = next((ln for ln in lines if ln.startswith("ci time: ")), None)  # .ci/run's own figure
    slowest = [ln.strip() for ln in lines if re.match(r"\s*\d+\.\d+s (call|setup|teardown) ", ln)]
    minutes = f"{int(wall // 60)} min {int(wall % 60)} s"
    print(f"{' '.join(cmd[-1:])}: {minutes}, exit {done.returncode}; {summary}")
    if ci_line:
        print(ci_line)
    if slowest:
        print("slowest:\n  " + "\n  ".join(slowest))
    warned = re.search(r"\d+ warnings?\b", summary) is not None
    if done.returncode or warned:  # a warning is kept too: under load it may be a thread's exception
        failed = [ln for ln in lines if ln.startswith(("FAILED", "ERROR"))]
        print("\n".join(failed[:20]))
        if warned and "warnings summary" in out:
            print(out[out.index("warnings summary"):].split("\n-- Docs:")[0][:4000])
        kept = Path(tempfile.mkstemp(prefix="ci-output-", suffix=".txt")[1])
        kept.write_text(out)
        print(f"the run's whole output: {kept}")
    if args.write_table:
        key = "ci.serial" if args.serial else ("suite.hogs" if args.hogs else "ci.quiet")
        what = {"ci.serial": "the suite one file after another",
                "suite.hogs": f"`.ci/run` in a fresh clone beside {args.hogs} CPU hogs",
                "ci.quiet": "`.ci/run` in a fresh clone (the README's test command, three workers on two cores)"}[key]
        value = f"{minutes}; {summary}" + (f"; {ci_line.removeprefix('ci time: ')}" if ci_line else "")
        record("benchmarks/suite_time.py", {key: (what, value)}, f"exit {done.returncode}")
    sys.exit(0 if done.returncode == 0 else 1)


if __name__ == "__main__":
    main()
