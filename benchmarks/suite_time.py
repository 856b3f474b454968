"""How long CI takes: `.ci/run` in a fresh clone of this checkout, timed, its tests counted.

    python benchmarks/suite_time.py [--hogs 2] [--write-table]

Clones the checkout's HEAD into a temporary folder (a fresh clone, as CI has), runs its
`.ci/run` and prints the wall time and the pytest summary line; ``--hogs N`` runs N busy
loops beside it (a shared machine), ``--serial`` the suite one file after another instead.
With ``--write-table`` the figure goes to docs/figures.json (docs/figures.md).
"""

from __future__ import annotations

import argparse
import multiprocessing
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
            done = subprocess.run(cmd, cwd=clone, capture_output=True, text=True)
            wall = time.perf_counter() - t0
    finally:
        for h in hogs:
            h.terminate()
    summary = next((ln for ln in reversed(done.stdout.splitlines()) if re.search(r"\d+ (passed|failed)", ln)), "?")
    minutes = f"{int(wall // 60)} min {int(wall % 60)} s"
    print(f"{' '.join(cmd[-1:])}: {minutes}, exit {done.returncode}; {summary}")
    if args.write_table:
        key = "ci.serial" if args.serial else ("suite.hogs" if args.hogs else "ci.quiet")
        what = {"ci.serial": "the suite one file after another",
                "suite.hogs": f"the suite beside {args.hogs} CPU hogs",
                "ci.quiet": "`.ci/run` in a fresh clone (the README's test command, two workers)"}[key]
        record("benchmarks/suite_time.py", {key: (what, f"{minutes}; {summary.strip('= ')}")},
               f"exit {done.returncode}")
    sys.exit(0 if done.returncode == 0 else 1)


if __name__ == "__main__":
    main()
