"""What ran is what the record says, and a trial is prepared once.

* Bus-level faults reach the emulated bus whoever runs the trial (a campaign, a comparison),
  because the backend builder attaches the bus's hooks, not the CLI: the emulator's own
  counters show the packets it dropped.
* Every record says whether the rig was simulated, emulated or real, and record.json holds
  the config, the calibration as applied, the servos and the versions beside the log's hash.
* The calibration file is read once per trial: changing it mid-run changes neither what the
  backend applied nor what the record holds; faults are parsed once, the plan and the
  interlocks built once.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import yaml

import bench.config.calibration as calibration_module
import bench.faults.spec as fault_spec_module
import bench.trial.plan as plan_module
from bench.campaign.run import create_campaign, run_campaign
from bench.campaign.store import CampaignStore
from bench.config.calibration import CalibrationFile, ServoCalibration, save_calibration
from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.rig.emulated import EmulatedRig
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from bench.trial.runs import list_runs
from drivers.clock import VirtualClock

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
SIM = REPO / "hil_configs" / "sim_target1_fast.yaml"
#: Status packets lost now and then: the driver's retries ride them out; whole bus, so ``auto``
#: puts it on the wire when there is one.
DROPS = [{"name": "dropped_status", "joints": "all", "prob": 0.03, "level": "auto"}]


def short_lab(tmp_path: Path, **changes) -> dict:
    """The lab config with a short plan (no retract, short settles), as plain data."""
    data = yaml.safe_load(LAB.read_text())
    data.update(plan={"velocity_scale": 1.0, "settle_s": 0.3, "retract": False}, **changes)
    return data


def write(tmp_path: Path, name: str, data: dict) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_campaign_on_an_emulated_rig_drops_status_packets_on_the_bus(tmp_path):
    cfg = load_trial_config(write(tmp_path, "lab", short_lab(tmp_path)))
    with EmulatedRig(cfg, clock=VirtualClock()) as rig:
        base = json.loads(rig.retarget(cfg).model_dump_json())
        spec = {"name": "bus-drops", "base": str(write(tmp_path, "base", base)), "seed": 3,
                "samples": 1, "repeats": 1, "faults": DROPS}
        d = create_campaign(write(tmp_path, "spec", spec), tmp_path / "campaign")
        before = rig.bus.stats.status_dropped
        run_campaign(d, workers=1)
        dropped = rig.bus.stats.status_dropped - before
    assert dropped > 0  # on the wire, not in a wrapper: the emulator itself dropped them
    with CampaignStore(d / "campaign.db") as store:
        (row,) = store.trials()
    assert row["status"] == "done", row.get("error")
    assert row["metrics"]["rig"] == "emulated"
    assert "- rig: emulated" in (d / "report.md").read_text()
    trial_dirs = [p for p in (d / "trials").rglob("record.json")]
    assert trial_dirs and json.loads(trial_dirs[0].read_text())["rig"] == "emulated"


def test_compare_emulate_drops_status_packets_on_the_bus_and_says_what_ran_where(tmp_path):
    """One emulated session: the bus faults act on the wire, the records say emulated, and the
    report says which window each section places the needle over, with the tip error by both."""
    from bench.compare.session import run_comparison

    data = short_lab(tmp_path, faults=DROPS)
    # the sim sides take the drops in a wrapper, which flags the joint stale; the rig's driver
    # retries a dropped packet, so nothing is stale there
    data["safety"] = {**data.get("safety", {}), "stale_data": False}
    path = write(tmp_path, "lab", data)
    res = run_comparison(load_trial_config(path), tmp_path / "out", repeats=1, emulate=True,
                         sim_model="datasheet")
    assert res.rig_stats.get("status_dropped", 0) > 0  # the emulator's counter, in its own process
    rec = json.loads((res.real_runs[0] / "record.json").read_text())
    assert rec["rig"] == "emulated" and rec["backend"] == "dynamixel"
    assert res.comparison.subject.rig == "emulated" and res.comparison.reference.rig == "sim"
    assert res.comparison.summary()["rig"] == "emulated"
    assert [r.rig for r in list_runs(res.real_runs[0].parent)] == ["emulated"]
    # the needle's two placements, each named on the page, and the tip error by both
    rig_tip = np.array(res.comparison.subject.outcomes[0].tip_mm)
    sim_tip = np.array(res.comparison.reference.outcomes[0].tip_mm)
    assert res.prediction.trial_tip_error_mm == [float(np.linalg.norm(rig_tip - sim_tip))]
    page = (res.out_dir / "report.md").read_text()
    assert "median reading over the last 0.1 s of the insertion's settle" in page
    assert "over all its stillness" in page and "placed as the repeat tables place it" in page
    assert "emulated" in page and "not the real rig" in page


def test_calibration_is_read_once_and_the_record_holds_what_was_applied(tmp_path, monkeypatch):
    reads = []
    real_load = calibration_module.load_calibration
    monkeypatch.setattr(calibration_module, "load_calibration", lambda p: reads.append(p) or real_load(p))
    parses = []
    real_parse = fault_spec_module.parse_fault
    monkeypatch.setattr(fault_spec_module, "parse_fault", lambda *a, **k: parses.append(a) or real_parse(*a, **k))
    plans, interlocks = [], []
    real_plan, real_interlocks = plan_module.plan, plan_module.interlocks_for
    monkeypatch.setattr(plan_module, "plan", lambda *a: plans.append(a) or real_plan(*a))
    monkeypatch.setattr(plan_module, "interlocks_for", lambda *a: interlocks.append(a) or real_interlocks(*a))

    applied, changed = 0.01, 0.05
    cal_path = save_calibration(CalibrationFile(
        config_name="lab-target1", created="2026-01-01T00:00:00+00:00",
        servos={"theta5": ServoCalibration(offset=applied, change=applied)}), tmp_path / "cal.yaml")
    data = short_lab(tmp_path, calibration=str(cal_path), faults=[{"name": "noise", "joints": ["theta3"]}])
    cfg = load_trial_config(write(tmp_path, "lab", data))

    def rewrite_calibration(phase: str) -> None:  # the file changes while the trial runs
        if phase == "approach":
            save_calibration(CalibrationFile(
                config_name="lab-target1", created="2026-01-02T00:00:00+00:00",
                servos={"theta5": ServoCalibration(offset=changed, change=changed)}), cal_path)

    stacks = []
    with EmulatedRig(cfg, clock=VirtualClock()) as rig:
        prep = prepare(rig.retarget(cfg))
        res = run_trial(prep, tmp_path / "runs", TrialHooks(
            report=False, phase=rewrite_calibration, wrap=lambda act: stacks.append(act) or act))
    assert res.completed, res.reason
    assert len(reads) == 1  # at config load; the trial used that reading
    assert len(parses) == 1 and len(plans) == 1 and len(interlocks) == 1
    backend = stacks[0].unwrapped
    (theta5,) = [s for s in backend.settings.servos if s.joint == "theta5"]
    assert theta5.offset == applied
    rec = json.loads((res.run_dir / "record.json").read_text())
    assert rec["calibration"]["content"]["servos"]["theta5"]["offset"] == applied
    assert yaml.safe_load(cal_path.read_text())["servos"]["theta5"]["offset"] == changed
    assert rec["calibration"] == TrialLog.load(res.log_path).metadata["calibration"]


def test_record_json_holds_what_the_readme_says(tmp_path):
    res = run_trial(prepare(load_trial_config(SIM)), tmp_path, TrialHooks(report=False, note="n"))
    rec = json.loads((res.run_dir / "record.json").read_text())
    meta = TrialLog.load(res.log_path).metadata
    for key in ("config", "calibration", "versions", "rig", "backend", "seed", "start_time", "note"):
        assert rec[key] == meta[key], key
    assert rec["rig"] == "sim" and rec["calibration"] is None and rec["note"] == "n"
    assert rec["versions"]["numpy"] == np.__version__
    assert set(rec) >= {"log", "sha256", "bytes", "servos"}
    assert [r.rig for r in list_runs(tmp_path)] == ["sim"]


def test_a_backend_built_on_an_emulated_port_gets_its_hooks_and_a_real_port_none(tmp_path):
    from bench.rig.backends import make_dynamixel_backend
    from bench.rig.serving import rig_kind

    cfg = load_trial_config(write(tmp_path, "lab", short_lab(tmp_path)))
    assert rig_kind(cfg) == "real"
    with EmulatedRig(cfg, clock=VirtualClock()) as rig:
        there = rig.retarget(cfg)
        assert rig_kind(there) == "emulated"
        prep = prepare(there)
        act = make_dynamixel_backend(prep.config, prep.robot)
        try:
            assert act.fault_hooks is rig.hooks
            act.fault_hooks.drop_prob = 0.25  # the hooks set that rig's bus faults
            assert rig.bus.faults.drop_prob == 0.25
        finally:
            act.close()
    assert rig_kind(there) == "real"  # the rig is gone: that port is no emulator's any more


def test_an_emulate_rehearsal_says_emulated_in_runs_report_and_log(tmp_path):
    import subprocess
    import sys

    hilbench = str(Path(sys.executable).with_name("hilbench"))
    path = write(tmp_path, "lab", short_lab(tmp_path))
    out = tmp_path / "runs"
    done = subprocess.run([hilbench, "trial", str(path), "--emulate", "--clock", "virtual", "--json", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode in (0, 1), done.stderr
    run = Path(json.loads(done.stdout)["run_dir"])
    assert TrialLog.load(run / "trial.npz").metadata["rig"] == "emulated"
    assert json.loads((run / "record.json").read_text())["rig"] == "emulated"
    assert "backend: dynamixel (emulated)" in (run / "report.md").read_text()
    listed = subprocess.run([hilbench, "runs", "--out", str(out), "--json"], capture_output=True,
                            text=True, timeout=60)
    assert [r["rig"] for r in json.loads(listed.stdout)["runs"]] == ["emulated"]
    table = subprocess.run([hilbench, "runs", "--out", str(out)], capture_output=True, text=True,
                           timeout=60, env={**os.environ, "COLUMNS": "200"})
    assert "dynamixel (emulated)" in table.stdout


def test_a_trial_against_hilbench_emulate_in_another_terminal_is_recorded_emulated(tmp_path):
    """The emulator serving from another process: this one does not know its port, the bus says."""
    import subprocess
    import sys

    hilbench = str(Path(sys.executable).with_name("hilbench"))
    proc = subprocess.Popen([hilbench, "emulate", str(LAB), "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        ports = json.loads(proc.stdout.readline())
        data = short_lab(tmp_path)
        data["backend"].update(port=ports["dynamixel_port"])
        data["backend"]["ultrasonic"].update(port=ports["ultrasonic_port"])
        data.pop("emulator", None)
        path = write(tmp_path, "lab-there", data)
        out = tmp_path / "runs"
        done = subprocess.run([hilbench, "trial", str(path), "--json", "--out", str(out)],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode in (0, 1), done.stderr
        run = Path(json.loads(done.stdout)["run_dir"])
        rec = json.loads((run / "record.json").read_text())
        assert rec["rig"] == "emulated" and all(s["emulated"] for s in rec["servos"])
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_real_servos_refusal_of_the_identity_read_says_real():
    """A real servo answers a READ past its table with an error and no data: never emulated."""
    from bench.rig.serving import bus_rig_kind
    from drivers.dynamixel.identity import EMULATED_REPLY, is_emulated_reply

    assert is_emulated_reply(0, EMULATED_REPLY)
    assert not is_emulated_reply(0x07, b"")  # Access Error, as X firmware answers
    assert not is_emulated_reply(0x04, EMULATED_REPLY)  # any error bit: not the emulator's answer
    assert not is_emulated_reply(0, b"\x00\x00\x00\x00")
    assert bus_rig_kind("real", [{"emulated": False}] * 9) == "real"
    assert bus_rig_kind("real", [{"emulated": True}] * 8 + [{"emulated": False}]) == "real"
    assert bus_rig_kind("real", [{"emulated": True}] * 9) == "emulated"
