"""The emulated rig on the virtual clock against real time: how much faster its trial runs.

Runs ``hilbench trial CONFIG --emulate --clock virtual --json`` ``--runs`` times (default 5,
``hil_configs/lab_real.yaml``: Target 1, the interlocks on, as a user runs it) and reports the
trial loop's speed against real time (``loop_timing.sim_s / loop_timing.wall_s``: the trial time
covered per second of the loop's wall-clock time), the median of the runs beside the best, and
the whole command's wall time (start-up, the rig's set-up and the report included). It checks on
the way that every run's arrays are the first run's, bit for bit. The same config in real time
(``--emulate`` alone) runs beside it once, for its loop's wall time.

    python benchmarks/virtual_clock.py [--runs 5] [--config hil_configs/lab_real.yaml] [--write-table]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from figures import record  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def trial(config: Path, out: Path, virtual: bool) -> tuple[dict, float]:
    cmd = [HILBENCH, "trial", str(config), "--emulate", "--json", "--out", str(out)]
    if virtual:
        cmd += ["--clock", "virtual"]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    took = time.perf_counter() - t0
    if res.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} exited {res.returncode}: {res.stderr.strip()}")
    return json.loads(res.stdout), took


def arrays(run_dir: str) -> dict[str, np.ndarray]:
    with np.load(Path(run_dir) / "trial.npz") as z:
        return {k: z[k] for k in z.files if k != "meta"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=REPO / "hil_configs" / "lab_real.yaml")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--write-table", action="store_true", help="write the figures into docs/figures.json")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        speeds, commands, first = [], [], None
        for k in range(args.runs):
            out, took = trial(args.config, Path(tmp) / f"v{k}", virtual=True)
            t = out["loop_timing"]
            speeds.append(t["sim_s"] / t["wall_s"])
            commands.append(took)
            logged = arrays(out["run_dir"])
            if first is None:
                first = logged
            same = first.keys() == logged.keys() and all(np.array_equal(first[a], logged[a], equal_nan=True)
                                                          for a in first)
            print(f"run {k + 1}: {t['sim_s']:.2f} s of trial in {t['wall_s']:.2f} s of loop "
                  f"({speeds[-1]:.1f}× real time), the command {took:.1f} s; arrays as run 1: {same}")
            if not same:
                sys.exit("the virtual clock gave a different log: not reproducible")
        real, real_took = trial(args.config, Path(tmp) / "real", virtual=False)
    rt = real["loop_timing"]
    speed = f"×{statistics.median(speeds):.1f} median, ×{max(speeds):.1f} best"
    line = (f"{speed} real time ({first and len(first['time'])} cycles of {rt['sim_s']:.1f} s of trial, "
            f"{args.runs} runs, every log the same bit for bit); the command "
            f"{statistics.median(commands):.1f} s median; in real time the loop {rt['wall_s']:.1f} s, "
            f"the command {real_took:.1f} s")
    print(line)
    if args.write_table:
        name = args.config.name
        record("benchmarks/virtual_clock.py", {
            "emulated.virtual_clock": (f"`trial {name} --emulate --clock virtual`: the trial loop's speed "
                                       f"against real time (loop_timing.sim_s / wall_s; target ≥ 5)", line)})


if __name__ == "__main__":
    main()
