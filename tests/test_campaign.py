"""Campaigns: deterministic trials, a store that survives kill -9 and Ctrl-C, the same
numbers on local processes and on a Dask cluster, the CLI's JSON, the report."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
import yaml

from bench.campaign.execute import InlinePool
from bench.campaign.report import deviation_table
from bench.campaign.run import (
    CampaignError,
    create_campaign,
    export_csv,
    make_pool,
    rerun_trial,
    run_campaign,
)
from bench.campaign.spec import CampaignSpecError, load_campaign_spec, plan_trials
from bench.campaign.store import METRIC_COLUMNS, CampaignStore
from bench.config.models import AcceptanceConfig
from bench.core.log import TrialLog
from bench.kinematics.arc_train import TABLE3_MEASURED, table3_deviations

if TYPE_CHECKING:
    from typer.testing import Result

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
RESULT_KEYS = ("status", "completed", "passed", *METRIC_COLUMNS)


def write_spec(tmp_path: Path, name: str = "small", **changes) -> Path:
    spec = {"name": name, "base": str(FAST), "seed": 5, "samples": 2, "repeats": 2,
            "faults": [{"name": "deadband", "joints": "all", "tol_deg": 0.29},
                       {"name": "torque_limit", "joints": ["theta5"], "scale": {"grid": [1.0, 0.3]}}]}
    spec.update(changes)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def results(db: Path) -> dict[int, tuple]:
    with CampaignStore(db) as store:
        return {r["id"]: tuple(r[k] for k in RESULT_KEYS) for r in store.trials()}


def rows(db: Path) -> list[dict]:
    with CampaignStore(db) as store:
        return store.trials()


def wait_for_done(db: Path, n: int, timeout: float = 120.0) -> None:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if db.is_file():
            try:
                with sqlite3.connect(db, timeout=5) as c:
                    if c.execute("SELECT COUNT(*) FROM trials WHERE status = 'done'").fetchone()[0] >= n:
                        return
            except sqlite3.OperationalError:
                pass
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} trials done after {timeout} s")


def hilbench_here(*args: str) -> "Result":
    """``hilbench ARGS`` run in this process, its trials on this process's forkserver. The
    campaigns that are killed or interrupted run as processes of their own."""
    from cli_in_process import invoke

    return invoke(*args)


def check_consistent(campaign_dir: Path) -> list[dict]:
    """Every done trial has exactly its one log directory; nothing else is in trials/."""
    rs = rows(campaign_dir / "campaign.db")
    done = {r["name"]: r for r in rs if r["status"] == "done"}
    dirs = sorted(p.name for p in (campaign_dir / "trials").iterdir() if p.name != ".staging") \
        if (campaign_dir / "trials").exists() else []
    assert dirs == sorted(done), (dirs, sorted(done))
    for name, r in done.items():
        assert r["log_path"] == f"trials/{name}/trial.npz"
        log = TrialLog.load(campaign_dir / r["log_path"])
        assert log.metadata["seed"] == r["seed"] and log.metadata["config"]["name"] == name
        outcome = r["metrics"]["outcome"]  # None when an interlock stopped it before the insertion
        tip = [r["tip_dx_mm"], r["tip_dy_mm"], r["tip_dz_mm"]]
        assert (outcome["tip_deviation_mm"] == tip) if outcome else tip == [None] * 3 and not r["passed"]
    return rs


# ---------------------------------------------------------------------------
# Specs and plans
# ---------------------------------------------------------------------------


def test_plan_is_deterministic_and_extends_without_reshuffling(tmp_path):
    spec = load_campaign_spec(write_spec(tmp_path, faults=[
        {"name": "deadband"},
        {"name": "torque_limit", "joints": ["theta5"], "scale": {"grid": [1.0, 0.5, 0.3]}},
        {"name": "noise", "std_deg": {"uniform": [0.0, 0.2]}}]))
    a, b = plan_trials(spec), plan_trials(spec)
    assert len(a) == 3 * 2 * 2 and [t.seed for t in a] == [t.seed for t in b]
    assert [t.params for t in a] == [t.params for t in b]
    assert len({t.seed for t in a}) == len(a)
    assert {t.params["torque_limit[theta5].scale"] for t in a} == {1.0, 0.5, 0.3}
    draws = [t.params["noise.std_deg"] for t in a]
    assert all(0.0 <= d <= 0.2 for d in draws) and len(set(draws)) == 3 * 2  # one per grid point × sample
    assert a[0].params == a[1].params and a[0].seed != a[1].seed  # repeats: same faults, own seed
    assert a[0].config["faults"][1] == {"name": "torque_limit", "joints": ["theta5"], "scale": 1.0}
    assert a[0].config["seed"] == a[0].seed and a[0].config["name"] == "small-00000"
    # overrides merge into the base config; the spec's acceptance replaces the base's
    tuned = plan_trials(spec.model_copy(update={"overrides": {"plan": {"settle_s": 0.4}},
                                                "acceptance": AcceptanceConfig(position_mm=3.0, angle_deg=0.5)}))
    assert tuned[0].config["plan"]["settle_s"] == 0.4 and tuned[0].config["plan"]["retract"] is False
    assert tuned[0].config["acceptance"] == {"position_mm": 3.0, "angle_deg": 0.5, "by": "encoders"}
    # more repeats and samples: the trials already planned keep their seeds and parameters
    bigger = plan_trials(spec.model_copy(update={"repeats": 3, "samples": 3}))
    key = {(t.grid_index, t.sample_index, t.repeat_index): (t.seed, t.params) for t in bigger}
    for t in a:
        assert key[(t.grid_index, t.sample_index, t.repeat_index)] == (t.seed, t.params)


@pytest.mark.parametrize("changes, words", [
    ({"samples": 0}, "samples: Input should be greater than or equal to 1"),
    ({"repeat": 2}, "repeat: unknown field"),
    ({"base": "nowhere.yaml"}, "base: trial config not found: nowhere.yaml"),
    ({"faults": [{"name": "deadbnd"}]}, "faults.0: unknown fault 'deadbnd'; valid faults: backlash"),
    ({"faults": [{"name": "deadband", "tol_deg": {"unifrom": [0, 1]}}]},
     "faults.0.tol_deg: unknown distribution 'unifrom'; valid: grid, uniform, loguniform, normal"),
    ({"faults": [{"name": "torque_limit", "joints": ["theta5"], "scale": {"grid": [0.5, 2.0]}}]},
     "faults.0 (torque_limit): scale must be <= 1, got 2.0"),
])
def test_bad_specs_fail_with_the_field_path(tmp_path, changes, words):
    path = write_spec(tmp_path, **changes)
    with pytest.raises(CampaignSpecError) as e:
        load_campaign_spec(path)
    assert words in str(e.value) and str(path) in str(e.value)


def test_cli_refuses_a_bad_spec_in_one_line(tmp_path):
    path = write_spec(tmp_path, faults=[{"name": "deadband", "tol": 1}])
    out = subprocess.run([HILBENCH, "campaign", str(path), "--out", str(tmp_path / "c"), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "unknown parameter 'tol'" in lines[0] and "tol_deg" in lines[0]
    assert not (tmp_path / "c").exists() and out.stdout == ""


def test_the_shipped_campaigns_plan(tmp_path):
    mc = load_campaign_spec(REPO / "hil_configs" / "campaigns" / "tolerance_sweep.yaml")
    trials = plan_trials(mc)
    assert len(trials) >= 200 and len({t.seed for t in trials}) == len(trials)
    assert all(t.faults == [{"name": "deadband", "joints": "all", "tol_deg": 0.29}] for t in trials)
    torque = plan_trials(load_campaign_spec(REPO / "hil_configs" / "campaigns" / "torque_limit.yaml"))
    labels = set(torque[0].params)
    assert any("train" in k for k in labels) and any("theta5" in k for k in labels)


def test_table3_of_seed_000_as_deviations():
    dev = table3_deviations()
    assert dev["x"] == pytest.approx([1.33, 1.34, 1.42, 1.26, 1.23])
    assert dev["y"] == pytest.approx([-0.70, -0.27, 0.74, -0.36, -0.40])
    assert dev["z"] == pytest.approx([-0.91, 0.71, -1.01, 0.90, -0.41])
    assert dev["insertion"] == pytest.approx([-0.22, 0.13, 0.33, -0.18, 0.06])
    assert dev["angle"] == pytest.approx([0.22, -0.50, -0.88, 0.13, -0.36])
    assert all(len(v) == 5 for v in TABLE3_MEASURED.values())
    fake = [{c: v for c, v in zip(METRIC_COLUMNS, row)} for row in ([1.0] * 8, [3.0] * 8, [-2.0] * 8)]
    table = {t["axis"]: t for t in deviation_table(fake)}
    assert table["entry Y"]["mean"] == pytest.approx(2 / 3) and table["entry Y"]["max_abs"] == 3.0
    assert table["entry Y"]["std"] == pytest.approx(np.std([1, 3, -2], ddof=1))
    assert table["entry X"]["paper_mean"] == pytest.approx(1.316)
    assert table["angle"]["paper_max_abs"] == pytest.approx(0.88)
    assert np.isnan(table["tip X"]["paper_mean"])  # the paper has no tip position


def test_the_real_backend_runs_one_trial_at_a_time():
    notes: list[str] = []
    pool = make_pool("dynamixel", 10, workers=4, scheduler=None, notes=notes)
    assert isinstance(pool, InlinePool) and pool.workers == 1
    assert notes and "one servo bus" in notes[0] and "workers=1" in notes[0]


# ---------------------------------------------------------------------------
# Running, storing, re-running
# ---------------------------------------------------------------------------


#: The shared campaign: write_spec's with one draw, so each torque scale runs twice (4 trials). Its
#: tests are about bookkeeping, the report and the same numbers on a Dask cluster, which 4 trials
#: show as well as 8.
LOCAL = {"samples": 1}


@pytest.fixture(scope="module")
def local_campaign(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("local")
    d = create_campaign(write_spec(tmp, **LOCAL), tmp / "campaign")
    summary = run_campaign(d, workers=2)
    return d, summary


def test_local_campaign_runs_every_trial_once_and_reports(local_campaign, tmp_path):
    d, s = local_campaign
    assert (s.planned, s.completed, s.errors, s.pending, s.ran) == (4, 4, 0, 0, 4)
    rs = check_consistent(d)
    assert all(r["status"] == "done" and r["attempts"] == 1 and r["truth"] == "sim" for r in rs)
    by_scale = {1.0: [], 0.3: []}
    for r in rs:
        by_scale[r["params"]["torque_limit[theta5].scale"]].append(bool(r["passed"]))
    assert all(by_scale[1.0]) and not any(by_scale[0.3])  # theta5 stalls below its gravity load
    assert len(by_scale[1.0]) == len(by_scale[0.3]) == 2 and s.passed == 2
    # trials run without figures (the log, record and result); the campaign report then
    # writes the worst ones' own reports, which its table links
    files = {p.name for p in (d / "trials" / "small-00000").iterdir()}
    assert {"trial.npz", "record.json", "result.json"} <= files
    with pytest.raises(CampaignError, match="already holds a campaign; continue it with"):
        create_campaign(write_spec(tmp_path), d)
    # CSV export: one row per trial, the axis as its own column
    csv_path = export_csv(d, tmp_path / "t.csv")
    lines = csv_path.read_text().splitlines()
    assert len(lines) == 5 and "torque_limit[theta5].scale" in lines[0].split(",")
    import csv as csv_module
    import datetime as dt

    for row in csv_module.DictReader(lines):  # wall-clock instants in ISO 8601 UTC
        started = dt.datetime.fromisoformat(row["started_at"])
        finished = dt.datetime.fromisoformat(row["finished_at"])
        assert started.utcoffset() == dt.timedelta(0) and started <= finished
        assert abs((dt.datetime.now(dt.timezone.utc) - started).total_seconds()) < 3600
    # the report: pass rates, the distribution beside Table 3, the worst trials with their logs
    md = (d / "report.md").read_text()
    assert "## Deviation against seed 000 Table 3" in md and "## Worst trials" in md
    assert "| 1.316 | 0.074 | 1.420 |" in md  # Table 3's X beside the campaign's
    assert "| torque_limit[theta5].scale | trials | passed |" in md
    assert "(trials/small-0000" in md
    html = (d / "report.html").read_text()
    assert html.count("data:image/png;base64") >= 2 and "<a href='trials/small-0000" in html
    import re

    links = re.findall(r"\]\((trials/[^)]+)\)", md.split("## Worst trials")[1])
    assert len(links) == 4 and all(link.endswith("/report.html") and (d / link).is_file() for link in links)


def test_rerunning_one_trial_alone_gives_identical_metrics(local_campaign, tmp_path):
    d, _ = local_campaign
    stored = rows(d / "campaign.db")
    passing = next(r["id"] for r in stored if r["passed"])
    failing = next(r["id"] for r in stored if not r["passed"] and r["tip_dx_mm"] is not None)  # tip measured
    for trial_id in (passing, failing):
        again = rerun_trial(d, trial_id, out=tmp_path / f"re{trial_id}")
        assert again["identical"], again
        assert again["stored"]["tip_dx_mm"] is not None
        assert (Path(again["run_dir"]) / "report.html").is_file()


def test_same_campaign_same_numbers_on_a_dask_cluster(local_campaign, tmp_path):
    distributed = pytest.importorskip("distributed")
    d_local, _ = local_campaign
    d = create_campaign(write_spec(tmp_path, **LOCAL), tmp_path / "dask")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=50) as cluster:
        s = run_campaign(d, scheduler=cluster.scheduler_address, report=False)
    assert (s.planned, s.completed, s.errors) == (4, 4, 0)
    assert results(d / "campaign.db") == results(d_local / "campaign.db")
    check_consistent(d)


def test_a_report_tables_other_campaigns_beside_its_own(local_campaign, tmp_path):
    """`campaign report DIR --beside OTHER`: each axis's bias ± scatter, campaign by campaign,
    with Table 3's; the numbers are the campaigns' own."""
    import numpy as np

    d, _ = local_campaign
    other = create_campaign(write_spec(tmp_path, samples=2, repeats=1), tmp_path / "other")
    run_campaign(other, workers=2, report=False)  # its numbers are tabled; its own report is not read
    out = hilbench_here("campaign", "report", str(d), "--beside", str(other), "--json")
    assert out.exit_code == 0, (out.stderr, out.exception)
    md = (d / "report.md").read_text()
    section = md.split("## Beside other campaigns")[1]
    header = [ln for ln in section.splitlines() if ln.startswith("| |")][0]
    assert "this campaign" in header and "Table 3" in header
    mine = [r["entry_dx_mm"] for r in rows(d / "campaign.db")
            if r["status"] == "done" and r["entry_dx_mm"] is not None]
    theirs = [r["entry_dx_mm"] for r in rows(other / "campaign.db")
              if r["status"] == "done" and r["entry_dx_mm"] is not None]
    line = [ln for ln in section.splitlines() if ln.startswith("| entry X")][0]
    assert f"{np.mean(mine):.2f} ± {np.std(mine, ddof=1):.2f}" in line
    assert f"{np.mean(theirs):.2f} ± {np.std(theirs, ddof=1):.2f}" in line
    assert "1.32 ± 0.07" in line  # Table 3's X
    bad = hilbench_here("campaign", "report", str(d), "--beside", str(tmp_path / "none"))
    assert bad.exit_code == 2 and "no campaign in" in bad.stderr, (bad.stderr, bad.exception)


def test_json_output_shape(tmp_path):
    spec = write_spec(tmp_path, samples=1, repeats=1)
    out = hilbench_here("campaign", "run", str(spec), "--out", str(tmp_path / "c"), "--workers", "2",
                        "--json", "--no-report")
    assert out.exit_code == 0, (out.stderr, out.exception)
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1
    res = json.loads(lines[0])
    assert list(res) == ["db", "planned", "completed", "passed", "errors", "reason"]
    assert res == {"db": str(tmp_path / "c" / "campaign.db"), "planned": 2, "completed": 2,
                   "passed": 1, "errors": 0, "reason": ""}
    # resume of a finished campaign runs nothing and says the same
    again = hilbench_here("campaign", "resume", str(tmp_path / "c"), "--json")
    assert again.exit_code == 0 and json.loads(again.stdout) == res, (again.stderr, again.exception)


def test_kill_9_then_resume_runs_each_trial_exactly_once(tmp_path):
    spec = write_spec(tmp_path, samples=2)  # 8 trials
    d = tmp_path / "c"
    proc = subprocess.Popen([HILBENCH, "campaign", "run", str(spec), "--out", str(d), "--workers", "2",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for_done(d / "campaign.db", 3)
        proc.kill()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    before = {r["id"]: r for r in rows(d / "campaign.db")}
    done_before = {i: r for i, r in before.items() if r["status"] == "done"}
    assert 3 <= len(done_before) < 8
    inodes = {r["name"]: (d / r["log_path"]).stat().st_ino for r in done_before.values()}
    staged = sorted((d / "trials" / ".staging").rglob("trial.npz"))
    time.sleep(1.5)  # the workers died with their parent: no trial in flight goes on to finish
    assert sorted((d / "trials" / ".staging").rglob("trial.npz")) == staged
    out = hilbench_here("campaign", "resume", str(d), "--workers", "2", "--json", "--no-report")
    assert out.exit_code == 0, (out.stderr, out.exception)
    assert json.loads(out.stdout)["completed"] == 8
    after = check_consistent(d)
    assert len(after) == 8 and all(r["status"] == "done" for r in after)
    for r in after:
        if r["id"] in done_before:  # not run again
            old = done_before[r["id"]]
            assert (r["attempts"], r["finished_at"], r["worker"]) == (1, old["finished_at"], old["worker"])
            assert (d / r["log_path"]).stat().st_ino == inodes[r["name"]]
        else:  # run by the resume: once more if it was in flight when killed
            assert r["attempts"] == before[r["id"]]["attempts"] + 1
    assert not any((d / "trials" / ".staging").glob("*"))
    # a trial the kill interrupted gives, resumed, the numbers it gives alone
    interrupted = [r for r in after if r["attempts"] == 2] or [r for r in after if r["id"] not in done_before]
    assert rerun_trial(d, interrupted[0]["id"], out=tmp_path / "re", report=False)["identical"]


def test_ctrl_c_leaves_a_consistent_database(tmp_path):
    spec = write_spec(tmp_path, samples=4)
    d = tmp_path / "c"
    proc = subprocess.Popen([HILBENCH, "campaign", "run", str(spec), "--out", str(d), "--workers", "2",
                             "--json", "--no-report"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        wait_for_done(d / "campaign.db", 2)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    res = json.loads(stdout)
    assert res["reason"].startswith("interrupted; ") and f"hilbench campaign resume {d}" in res["reason"]
    assert stderr.strip().splitlines()[-1] == f"campaign incomplete: {res['reason']}"
    rs = check_consistent(d)
    status = [r["status"] for r in rs]
    assert set(status) <= {"done", "pending"} and "pending" in status
    assert res["completed"] == status.count("done") and res["planned"] == 16
    assert all(r["attempts"] == (1 if r["status"] == "done" else 0) for r in rs)
    assert all(r["finished_at"] is None and r["tip_dx_mm"] is None for r in rs if r["status"] == "pending")
