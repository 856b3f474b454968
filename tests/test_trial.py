"""Sim trials end to end: config -> plan -> run -> log -> report, and bad input refused first."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_in_process import invoke as _invoke
from bench.config.models import ConfigError, load_trial_config
from bench.core.log import TrialLog
from bench.core.result import TrialError
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "hil_configs" / "sim_target1.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def write_config(tmp_path: Path, **changes) -> Path:
    data = yaml.safe_load(SIM.read_text())
    for dotted, value in changes.items():
        node = data
        *path, last = dotted.split(".")
        for key in path:
            node = node[key]
        node[last] = value
    p = tmp_path / "trial.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.mark.parametrize("trajectory", ["lspb", "ruckig", "ruckig-online"])
def test_ideal_sim_trial_reaches_target_1(tmp_path, trajectory):
    cfg = load_trial_config(write_config(tmp_path, **{"plan.trajectory": trajectory}))
    res = run_trial(prepare(cfg), tmp_path / "runs")
    assert res.completed and res.passed
    o = res.outcome
    assert np.max(np.abs(o.tip_deviation_mm)) < 0.5
    assert np.max(np.abs(o.entry_deviation_mm)) < 0.5
    assert abs(o.depth_deviation_mm) < 0.5
    assert abs(o.angle_deviation_deg) < 0.1
    # the log holds the whole plan, saved with its metadata
    log = TrialLog.load(res.log_path)
    assert log.segment_names == ["approach", "insert", "retract"]
    assert log.metadata["config"]["plan"]["trajectory"] == trajectory
    assert "pybullet" in log.metadata["versions"]
    assert np.all(np.diff(log.time) > 0)
    # commanded profile starts at home and reaches the IK solution
    assert log.q_cmd[0] == pytest.approx(np.array(log.metadata["q_entry"]) * 0 + log.q[0], abs=1e-9)
    # the report shows the Table 3 row with these numbers
    md = (res.run_dir / "report.md").read_text()
    assert "PASSED" in md and "| input target | 0.000 | 88.200 | 66.000 | 30.100 | 47.000 |" in md
    row = f"| output (achieved) | {o.entry_mm[0]:.3f} | {o.entry_mm[1]:.3f} |"
    assert row in md
    html = (res.run_dir / "report.html").read_text()
    assert "data:image/png;base64" in html and "Table 3" in html
    assert (res.run_dir / "joints.png").stat().st_size > 20_000


def test_cli_trial_json(tmp_path):
    out = _invoke("trial", str(SIM), "--out", str(tmp_path), "--json")
    assert out.exit_code == 0, out.stderr
    res = json.loads(out.stdout)
    assert set(res) == {"run_dir", "tip_deviation_mm", "depth_deviation_mm", "angle_deviation_deg",
                        "passed", "completed", "reason", "safe_stop", "loop_timing", "camera", "judged_by",
                        "requirements", "placement_basis"}
    cam = res["camera"]  # the shipped config's two cameras: the tip as they saw it
    assert cam["problem"] == "" and cam["flag"] is False and res["judged_by"] == "encoders"
    assert cam["encoder_gap_mm"] < 0.5 and 0 < cam["uncertainty_mm"] < 2.0
    assert res["loop_timing"]["state"] == "not paced" and res["loop_timing"]["missed"] == 0
    assert res["passed"] is True and len(res["tip_deviation_mm"]) == 3
    assert res["completed"] is True and res["reason"] == "" and out.stderr.strip() == ""
    assert Path(res["run_dir"], "trial.npz").is_file()


@pytest.mark.parametrize("changes, words", [
    ({"plan.trajectroy": "lspb"}, "plan.trajectroy: unknown field"),
    ({"plan.trajectory": "cubic"}, "plan.trajectory"),
    ({"control_hz": -5}, "control_hz"),
    ({"urdf_dir": "/nonexistent/urdf"}, "URDF not found"),
    ({"target.z_mm": 666.0}, "out of the arm's reach"),
    ({"target.depth_mm": 250.0}, "insertion depth"),
    ({"backend.joints": {"theta9": {"effort": 1.0}}}, "theta9"),
])
def test_bad_configs_fail_before_anything_moves(tmp_path, changes, words):
    path = write_config(tmp_path, **changes)
    runs = tmp_path / "runs"
    out = _invoke("trial", str(path), "--out", str(runs), "--json")
    assert out.exit_code == 2
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], out.stderr
    assert not runs.exists()  # no run directory: nothing started


def test_library_errors_are_typed(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_trial_config(tmp_path / "missing.yaml")
    cfg = load_trial_config(write_config(tmp_path, **{"target.y_mm": 900.0}))
    with pytest.raises(TrialError, match="target"):
        prepare(cfg)


def test_report_rebuilt_from_the_record_equals_the_original(tmp_path):
    cfg = load_trial_config(SIM)
    res = run_trial(prepare(cfg), tmp_path, TrialHooks(note="rebuild check"))
    d = res.run_dir
    originals = {name: (d / name).read_bytes() for name in ("report.md", "report.html", "joints.png",
                                                            "result.json")}
    for name in originals:
        (d / name).unlink()
    # the installed command, in a process of its own: the report is rebuilt from the files alone
    out = subprocess.run([HILBENCH, "report", str(d), "--json"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    for name, content in originals.items():
        assert (d / name).read_bytes() == content, f"{name} differs after the rebuild"
    record = json.loads((d / "record.json").read_text())
    assert len(record["sha256"]) == 64
    log = TrialLog.load(res.log_path)
    assert log.metadata["note"] == "rebuild check" and log.metadata["seed"] == cfg.seed
    assert log.metadata["start_time"] and log.metadata["versions"]["needle-hil-bench"]


def test_a_trial_stopped_at_once_reports_what_stopped_it_and_draws_no_empty_plot(tmp_path):
    cfg = load_trial_config(SIM)
    cfg = cfg.model_copy(update={"name": "stopped", "safety": cfg.safety.model_copy(
        update={"tracking_error_deg": 0.001})})
    res = run_trial(prepare(cfg), tmp_path)
    assert not res.completed
    md = (res.run_dir / "report.md").read_text()
    stopped = md.split("## What stopped it")[1].split("##")[0]
    assert "s into the trial during the approach segment: **interlock**: tracking_error: theta" in stopped
    assert "then: holding the measured position" in stopped
    assert "nothing to plot" in md and "![joint profiles]" not in md
    assert not (res.run_dir / "joints.png").exists()
    html = (res.run_dir / "report.html").read_text()
    assert "<th style='text-align:left'>detail</th>" in html  # the events' text reads left to right
    assert "-0.0000" not in md


def test_report_refuses_a_modified_log(tmp_path):
    res = run_trial(prepare(load_trial_config(SIM)), tmp_path)
    with open(res.log_path, "ab") as f:
        f.write(b"tampered")
    out = _invoke("report", str(res.run_dir))
    assert out.exit_code == 2
    assert "checksum" in out.stderr


def test_a_bad_command_mid_trial_is_an_abort_event_and_a_kept_record(tmp_path):
    """A NaN that reaches the actuators (here from a broken wrapper) is an ActuatorError: the
    runner stops safely, logs it as the abort reason and keeps the record."""
    from bench.faults.base import FaultWrapper
    from drivers import CommandError

    class NaNAfterASecond(FaultWrapper):
        def command(self, position, velocity=None):  # skips the wrapper's own check on purpose
            if self.actuators.now() > 1.0:
                position = np.full_like(np.asarray(position, dtype=float), np.nan)
            self.actuators.command(position, velocity)

    res = run_trial(prepare(load_trial_config(SIM)), tmp_path, TrialHooks(wrap=NaNAfterASecond, report=False))
    assert not res.completed and not res.passed
    assert CommandError.__name__ in res.reason and "not finite" in res.reason
    log = TrialLog.load(res.log_path)
    aborts = [e for e in log.events if e.kind == "abort"]
    assert len(aborts) == 1 and 1.0 < aborts[0].time < 1.1
    assert json.loads((res.run_dir / "result.json").read_text())["completed"] is False
