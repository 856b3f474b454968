"""`hilbench compare`'s console summary: X/Y/Z with their unit, the mean signed and the largest |…|."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def test_the_console_names_axes_units_and_what_max_means(tmp_path):
    runs = []
    for _ in range(2):  # the same plan twice (two runs of different plans are refused)
        done = subprocess.run([HILBENCH, "trial", str(SIM), "--out", str(tmp_path / "runs"), "--json"],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        runs.append(json.loads(done.stdout)["run_dir"])
    shown = subprocess.run([HILBENCH, "compare", *runs, "--out", str(tmp_path / "cmp")],
                           capture_output=True, text=True, timeout=300, env=os.environ | {"COLUMNS": "200"})
    as_json = subprocess.run([HILBENCH, "compare", *runs, "--out", str(tmp_path / "cmp"), "--json"],
                             capture_output=True, text=True, timeout=300)
    assert shown.returncode == 0 and as_json.returncode == 0, shown.stderr + as_json.stderr
    tip = json.loads(as_json.stdout)["tip_deviation_mm"]
    lines = shown.stdout.splitlines()
    mean = next(ln for ln in lines if ln.startswith("tip deviation, mean (mm): "))
    assert mean.split(": ")[1] == "  ".join(f"{a} {round(v, 3) + 0.0:+.3f}" for a, v in zip("XYZ", tip["mean"]))
    worst = next(ln for ln in lines if ln.startswith("tip deviation, max |…| (mm): "))
    assert worst.split(": ")[1] == "  ".join(f"{a} {round(v, 3) + 0.0:.3f}" for a, v in zip("XYZ", tip["max"]))
    assert "[" not in shown.stdout.split("report:")[0]  # no raw Python list anywhere in the summary
    assert "-0.000" not in shown.stdout
