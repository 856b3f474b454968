"""Tampered campaign directories: `campaign report` refuses each in one line with exit 2, before
writing anything, naming the campaign (or the trial's run) and what is wrong."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import sqlite3
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from bench.campaign.run import create_campaign, run_campaign
from bench.cli.app import app

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("campaign")
    spec = tmp / "spec.yaml"
    spec.write_text(yaml.safe_dump({"name": "tampered", "base": str(FAST), "seed": 1, "samples": 2,
                                    "repeats": 1, "faults": [{"name": "deadband", "joints": "all",
                                                              "tol_deg": {"grid": [0.1, 0.29]}}]}))
    d = create_campaign(spec, tmp / "c")
    summary = run_campaign(d, workers=1, report=False)
    assert summary.completed == summary.planned == 4
    return d


def _sql(statement: str) -> Callable[[Path], str]:
    def tamper(d: Path) -> str:
        db = sqlite3.connect(d / "campaign.db")
        db.executescript(f"PRAGMA ignore_check_constraints = ON; {statement};")
        db.close()
        return str(d)
    return tamper


def _garbage_db(d: Path) -> str:
    for p in d.glob("campaign.db*"):
        p.unlink()
    (d / "campaign.db").write_bytes(b"not a database at all" * 100)
    return str(d)


def _nan_in_a_trial_log(d: Path) -> str:
    run = d / "trials" / sorted(p.name for p in (d / "trials").iterdir() if p.name != ".staging")[0]
    with np.load(run / "trial.npz") as z:
        a = {k: z[k] for k in z.files}
    a["q"] = a["q"].copy()
    a["q"][2, 2] = np.nan
    buf = io.BytesIO()
    np.savez_compressed(buf, **a)
    data = buf.getvalue()
    (run / "trial.npz").write_bytes(data)
    (run / "record.json").write_text(json.dumps({"log": "trial.npz", "sha256": hashlib.sha256(data).hexdigest(),
                                                 "bytes": len(data)}))
    return str(run)


CASES = [
    ("not-sqlite", _garbage_db, "not a campaign database"),
    ("no-trials-columns", _sql("ALTER TABLE trials DROP COLUMN tip_dx_mm"), "tip_dx_mm"),
    ("log-path-traversal", _sql("UPDATE trials SET log_path = '../../../../etc/passwd' WHERE id = 0"),
     "would leave the campaign"),
    ("log-path-absolute", _sql("UPDATE trials SET log_path = '/etc/trial.npz' WHERE id = 1"),
     "would leave the campaign"),
    ("metric-text", _sql("UPDATE trials SET angle_dev_deg = 'abc' WHERE id = 0"), "not a finite number"),
    ("metric-inf", _sql("UPDATE trials SET tip_dx_mm = 9e999 WHERE id = 0"), "not a finite number"),
    ("unknown-status", _sql("UPDATE trials SET status = 'weird' WHERE id = 0"), "status"),
    ("params-not-json", _sql("UPDATE trials SET params = '{x' WHERE id = 0"), "not JSON"),
    ("meta-not-json", _sql("UPDATE campaign SET value = '[' WHERE key = 'acceptance'"), "not JSON"),
    ("acceptance-negative", _sql("UPDATE campaign SET value = '{\"position_mm\": -1}' WHERE key = 'acceptance'"),
     "position_mm"),
    ("nan-in-a-trial-log", _nan_in_a_trial_log, "nan"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_campaign_report_refuses_a_tampered_campaign_in_one_line(campaign, tmp_path, case):
    _, tamper, words = case
    d = tmp_path / "c"
    shutil.copytree(campaign, d)
    named = tamper(d)
    res = CliRunner().invoke(app, ["campaign", "report", str(d)])
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, (res.exit_code, res.stderr, res.exception)
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith("error: ") and named in lines[0] and words.lower() in lines[0].lower(), lines[0]
    assert not (d / "report.md").exists() and not (d / "report.html").exists()


@pytest.mark.parametrize("content", ["garbage", "other-tables"])
@pytest.mark.parametrize("command", ["status", "export", "report", "resume"])
def test_every_campaign_command_refuses_a_database_that_holds_no_campaign(tmp_path, command, content):
    d = tmp_path / "c"
    d.mkdir()
    if content == "garbage":
        (d / "campaign.db").write_bytes(b"\x00garbage" * 64)
    else:
        db = sqlite3.connect(d / "campaign.db")
        db.execute("CREATE TABLE notes (text)")
        db.commit()
        db.close()
    extra = ["--out", str(tmp_path / "x.csv")] if command == "export" else []
    res = CliRunner().invoke(app, ["campaign", command, str(d), *extra])
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1, (res.exit_code, res.stderr, res.exception)
    assert "not a campaign database" in lines[0] and str(d) in lines[0]
    db = sqlite3.connect(d / "campaign.db") if content != "garbage" else None
    if db is not None:  # nothing was made up in it
        assert {r[0] for r in db.execute("SELECT name FROM sqlite_master")} == {"notes"}
        db.close()
