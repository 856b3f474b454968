"""A campaign whose base is a servo bus, with ``emulate: true``: every trial on its own emulated rig
on the virtual clock, the real driver's path, in parallel workers, the same results each time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _spec(tmp: Path, **changes) -> Path:
    spec = {"name": "emulated-bias", "base": str(REPO / "hil_configs" / "lab_real.yaml"), "seed": 7,
            "emulate": True, "overrides": {"cameras": None},
            "faults": [{"name": "bias", "joints": ["theta5"], "bias_deg": {"grid": [0.0, 1.5]}}]} | changes
    path = tmp / "spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def _run(spec: Path, out: Path) -> list[dict]:
    done = subprocess.run([HILBENCH, "campaign", "run", str(spec), "--out", str(out), "--workers", "2",
                           "--no-report", "--json"], capture_output=True, text=True, timeout=600)
    assert done.returncode in (0, 1), done.stderr
    summary = json.loads(done.stdout)
    assert summary["completed"] == summary["planned"] == 2 and summary["errors"] == 0, summary
    exported = subprocess.run([HILBENCH, "campaign", "export", str(out), "--out", str(out / "t.csv"), "--json"],
                              capture_output=True, text=True, timeout=120)
    assert exported.returncode == 0, exported.stderr
    import csv
    with open(out / "t.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_an_emulated_campaign_runs_each_trial_on_its_rig_on_the_virtual_clock_the_same_twice(tmp_path):
    from bench.core.log import TrialLog

    spec = _spec(tmp_path)
    first, second = _run(spec, tmp_path / "a"), _run(spec, tmp_path / "b")
    kept = ("bias[theta5].bias_deg", "completed", "passed", "robustness", "tip_dx_mm", "tip_dy_mm", "tip_dz_mm",
            "angle_dev_deg", "truth")
    rows = lambda rs: [{k: r[k] for k in kept} for r in rs]  # noqa: E731
    assert rows(first) == rows(second)  # two workers, two runs: the same numbers to the digit
    assert [r["bias[theta5].bias_deg"] for r in first] == ["0.0", "1.5"]
    # the bias reached the rig's readings: the encoders place the tip elsewhere
    assert first[0]["tip_dy_mm"] != first[1]["tip_dy_mm"]
    for r in first:  # each on its emulated rig, through the real driver, on the virtual clock
        meta = TrialLog.load(tmp_path / "a" / r["log_path"]).metadata
        assert meta["loop_clock"] == "virtual" and meta["rig"] == "emulated"


def test_emulate_on_a_simulator_base_is_refused_in_one_line(tmp_path):
    spec = _spec(tmp_path, base=str(REPO / "hil_configs" / "sim_target1_fast.yaml"), overrides={})
    done = subprocess.run([HILBENCH, "campaign", "run", str(spec), "--out", str(tmp_path / "c")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "emulate:" in lines[0] and "pybullet" in lines[0]
