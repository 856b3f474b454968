"""`hilbench runs` lists comparisons and campaigns beside trials: a kind each, its verdict, its
worst deviation and its report; a damaged one is listed broken in one line and the listing goes on."""

from __future__ import annotations

import io
import json
import shutil
import sqlite3
from pathlib import Path

import pytest
import yaml
from rich.console import Console
from typer.testing import CliRunner

import bench.cli.runs

from bench.campaign.run import create_campaign, run_campaign
from bench.cli.app import app
from bench.config.models import load_trial_config
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"


@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> Path:
    """A runs folder as the commands leave it: two trials, a compare of them, a campaign in
    ``campaigns/`` (where ``hilbench campaign`` puts one by default)."""
    out = tmp_path_factory.mktemp("runs")
    trials = [run_trial(prepare(load_trial_config(FAST)), out, TrialHooks(report=True)).run_dir for _ in range(2)]
    res = CliRunner().invoke(app, ["compare", str(trials[0]), str(trials[1]), "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    spec = out.parent / f"{out.name}-spec.yaml"
    spec.write_text(yaml.safe_dump({"name": "listed", "base": str(FAST), "seed": 1, "samples": 1, "repeats": 1,
                                    "faults": [{"name": "deadband", "joints": "all",
                                                "tol_deg": {"grid": [0.1, 4.0]}}]}))
    campaign = create_campaign(spec, out / "campaigns" / "20990101-000000-listed")
    assert run_campaign(campaign, workers=1).completed == 2
    return out


def _listed(out: Path) -> list[dict]:
    res = CliRunner().invoke(app, ["runs", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    return json.loads(res.stdout)["runs"]


def test_trials_compares_and_campaigns_are_listed_together_oldest_first(outputs):
    runs = _listed(outputs)
    assert sorted(r["kind"] for r in runs) == ["campaign", "compare", "trial", "trial"]
    assert [r["started"] for r in runs] == sorted(r["started"] for r in runs)  # to the second
    trials = [r for r in runs if r["kind"] == "trial"]
    (compare,) = [r for r in runs if r["kind"] == "compare"]
    (campaign,) = [r for r in runs if r["kind"] == "campaign"]
    assert compare["status"] == "passed" and compare["config"] == "sim-target1-fast"
    assert compare["backend"] == "pybullet vs pybullet" and compare["rig"] == "sim"
    # the compare's subject is the second trial: its deviation is that trial's
    assert compare["tip_deviation_mm"] == pytest.approx(trials[1]["tip_deviation_mm"], abs=1e-3)
    # a 4° deadband on every joint places the needle outside 5 mm / 1°: one of two trials fails
    assert campaign["status"] == "failed" and campaign["reason"].startswith("1 of 2 trials passed")
    assert campaign["run_dir"].endswith("campaigns/20990101-000000-listed") and campaign["config"] == "listed"
    assert campaign["tip_deviation_mm"] > 5 or abs(campaign["angle_deviation_deg"]) > 1
    for r in runs:  # each one links its own report
        assert r["report"] == str(Path(r["run_dir"]) / "report.html") and Path(r["report"]).is_file()


def test_the_table_has_a_kind_column_and_links_each_report(outputs, monkeypatch):
    res = CliRunner().invoke(app, ["runs", "--out", str(outputs)], env={"COLUMNS": "160"})
    assert res.exit_code == 0, res.stderr
    kinds = [line.split("│")[0].strip().split(",")[0] for line in res.stdout.splitlines() if "│" in line]
    assert sorted(k for k in kinds if k in ("campaign", "compare", "trial")) == ["campaign", "compare", "trial", "trial"]
    assert "4 runs (2 trial, 1 compare, 1 campaign)" in res.stdout
    assert "campaigns/20990101-000000-listed: 1 of 2 trials passed" in res.stdout
    terminal = Console(file=io.StringIO(), force_terminal=True, width=160)  # one that shows hyperlinks
    monkeypatch.setattr(bench.cli.runs, "console", terminal)
    bench.cli.runs.runs(out=outputs, as_json=False)
    shown = terminal.file.getvalue()
    for r in _listed(outputs):  # an OSC 8 hyperlink from each run's name to its report
        assert f"\x1b]8;id=" in shown and Path(r["report"]).resolve().as_uri() in shown


def _compare_dir(outputs: Path, out: Path) -> Path:
    src = next(d for d in outputs.iterdir() if "-compare-" in d.name)
    return Path(shutil.copytree(src, out / src.name))


def _summary(d: Path, text: str) -> None:
    (d / "summary.json").write_text(text)


def _nan_angle(d: Path) -> None:
    data = json.loads((d / "summary.json").read_text())
    data["subject"]["outcomes"][0]["angle_deviation_deg"] = float("nan")
    (d / "summary.json").write_text(json.dumps(data))


def _no_verdict(d: Path) -> None:
    data = json.loads((d / "summary.json").read_text())
    del data["summary"]["passed"]
    (d / "summary.json").write_text(json.dumps(data))


def _linked_summary(d: Path) -> None:
    (d / "summary.json").unlink()
    (d / "summary.json").symlink_to("/etc/hostname")


COMPARE_CASES = [
    ("not-json", lambda d: _summary(d, "{not json"), "not JSON"),
    ("a-list", lambda d: _summary(d, "[1, 2]"), "holds a list"),
    ("nan-angle", _nan_angle, "angle_deviation_deg"),
    ("no-verdict", _no_verdict, "passed"),
    ("linked", _linked_summary, "is a link"),
]


@pytest.mark.parametrize("name,tamper,words", COMPARE_CASES, ids=[c[0] for c in COMPARE_CASES])
def test_a_damaged_compare_is_listed_broken_in_one_line(outputs, tmp_path, name, tamper, words):
    d = _compare_dir(outputs, tmp_path)
    tamper(d)
    shutil.copytree(next(t for t in outputs.iterdir() if (t / "record.json").is_file()), tmp_path / "a-trial")
    (listed,) = [r for r in _listed(tmp_path) if r["kind"] == "compare"]
    assert listed["status"] == "broken" and words.lower() in listed["reason"].lower(), listed
    assert "\n" not in listed["reason"] and listed["report"] is None
    assert [r["status"] for r in _listed(tmp_path) if r["kind"] == "trial"] == ["passed"]
    text = CliRunner().invoke(app, ["runs", "--out", str(tmp_path)], env={"COLUMNS": "200"})
    assert text.exit_code == 0 and "Traceback" not in text.stdout
    assert sum(line.startswith(f"{d.name}: ") for line in text.stdout.splitlines()) == 1


def test_a_compare_stopped_before_its_report_is_incomplete(tmp_path):
    d = tmp_path / "20261126-101500-compare-lab-real"
    (d / "real").mkdir(parents=True)
    (listed,) = _listed(tmp_path)
    assert (listed["kind"], listed["status"], listed["config"]) == ("compare", "incomplete", "lab-real")
    assert "no summary.json" in listed["reason"] and listed["started"].endswith("+00:00")


def test_a_damaged_or_unfinished_campaign_is_listed_as_such(outputs, tmp_path):
    src = outputs / "campaigns" / "20990101-000000-listed"
    garbage = Path(shutil.copytree(src, tmp_path / "campaigns" / "garbage"))
    for p in garbage.glob("campaign.db*"):
        p.unlink()
    (garbage / "campaign.db").write_bytes(b"not a database at all" * 100)
    unfinished = Path(shutil.copytree(src, tmp_path / "unfinished"))  # a campaign given as --out DIR
    db = sqlite3.connect(unfinished / "campaign.db")
    db.execute("UPDATE trials SET status = 'pending' WHERE id = (SELECT MAX(id) FROM trials)")
    db.commit()
    db.close()
    runs = {Path(r["run_dir"]).name: r for r in _listed(tmp_path)}
    assert runs["garbage"]["kind"] == "campaign" and runs["garbage"]["status"] == "broken"
    assert "not a campaign database" in runs["garbage"]["reason"]
    assert runs["unfinished"]["status"] == "incomplete"
    assert f"campaign resume {unfinished}" in runs["unfinished"]["reason"]


def test_at_80_columns_every_run_name_is_whole_and_the_tip_is_labelled_a_distance(outputs):
    res = CliRunner().invoke(app, ["runs", "--out", str(outputs)], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.splitlines()
    for r in _listed(outputs):
        name = str(Path(r["run_dir"]).relative_to(outputs))
        assert any(name in line for line in lines), (name, res.stdout)  # on one line: copyable
    assert "tip dist. mm" in res.stdout and "tip dist.: how far the needle tip ended from its target" in res.stdout


def test_one_run_is_counted_as_one_run(outputs, tmp_path):
    one = next(d for d in outputs.iterdir() if (d / "record.json").is_file())
    shutil.copytree(one, tmp_path / one.name)
    res = CliRunner().invoke(app, ["runs", "--out", str(tmp_path)], env={"COLUMNS": "120"})
    assert res.exit_code == 0 and "1 run (1 trial)" in res.stdout and "1 runs" not in res.stdout, res.stdout


def test_runs_refuses_an_out_that_is_not_a_directory_in_one_line(tmp_path):
    (tmp_path / "file").write_text("x")
    for out, why in ((tmp_path / "missing", "no such directory"), (tmp_path / "file", "not a directory")):
        res = CliRunner().invoke(app, ["runs", "--out", str(out)])
        assert res.exit_code == 2 and res.stderr.strip() == f"error: --out {out}: {why}", res.stderr


def test_a_trial_with_cameras_lists_their_gap_to_the_encoders(tmp_path):
    """sim_target1.yaml ships two cameras: its trial is listed with the gap between their tip and the
    encoders' (not flagged on a clean sim trial), in the JSON and under the table."""
    cfg = load_trial_config(REPO / "hil_configs" / "sim_target1.yaml")
    res = run_trial(prepare(cfg), tmp_path, TrialHooks(report=False))
    gap = res.camera["encoder_gap_mm"]
    (listed,) = _listed(tmp_path)
    assert listed["cameras"] == f"tip {gap:.2f} mm from the encoders'"
    table = CliRunner().invoke(app, ["runs", "--out", str(tmp_path)], env={"COLUMNS": "160"})
    assert f": cameras: tip {gap:.2f} mm from the encoders'" in table.stdout
    result = json.loads((res.run_dir / "result.json").read_text())
    result["camera"]["flag"] = True
    (res.run_dir / "result.json").write_text(json.dumps(result))
    assert _listed(tmp_path)[0]["cameras"].endswith(", flagged")
