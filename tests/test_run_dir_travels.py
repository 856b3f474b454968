"""A run directory travels: copied anywhere it rebuilds its report, lists, compares and exports;
and what its stored config names is never followed out of it, nor any file's content printed.

The crafted records below are re-signed (the log's SHA-256 and size in record.json made to
match), as a careful forger would, so each reaches the stored config and not only the checksum.
"""

from __future__ import annotations

import builtins
import hashlib
import io
import json
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from typer.testing import CliRunner

from bench.cli.app import app
from bench.config.models import load_trial_config
from bench.paths import REPO_ROOT
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

FAST = REPO_ROOT / "hil_configs" / "sim_target1_fast.yaml"
SECRET = "root:*:20228:0:99999:7:::"


@pytest.fixture(scope="module")
def good_run(tmp_path_factory) -> Path:
    res = run_trial(prepare(load_trial_config(FAST)), tmp_path_factory.mktemp("good"), TrialHooks(report=False))
    assert res.completed
    return res.run_dir


@pytest.fixture
def secret(tmp_path) -> Path:
    """A file outside every run directory that no reader may open: a shadow file's first line."""
    d = tmp_path / "elsewhere"
    d.mkdir()
    (d / "shadow").write_text(SECRET + "\ndaemon:*:20228:0:99999:7:::\n")
    (d / "arc_train.urdf").write_text("<robot name='not the package one'/>\n")
    return d


def _restore(run: Path, change: Callable[[dict], None]) -> None:
    """The log's stored config changed by ``change``, the record re-signed to match."""
    with np.load(run / "trial.npz") as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    change(meta["metadata"])
    arrays["meta"] = np.array(json.dumps(meta))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    data = buf.getvalue()
    (run / "trial.npz").write_bytes(data)
    record = json.loads((run / "record.json").read_text())
    record.update({k: meta["metadata"].get(k) for k in ("config", "calibration")},
                  sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))
    (run / "record.json").write_text(json.dumps(record))


def _as_rig(metadata: dict, **config: object) -> None:
    """The stored config made a rig's (the lab's dynamixel backend), with ``config`` over it."""
    rig = json.loads(load_trial_config(REPO_ROOT / "hil_configs" / "lab_real.yaml").model_dump_json())
    metadata["config"] = {**metadata["config"], "backend": rig["backend"], **config}
    metadata["backend"] = "dynamixel"
    metadata["calibration"] = None


def _crafted(secret: Path) -> dict[str, Callable[[dict], None]]:
    shadow = str(secret / "shadow")
    return {
        "calibration": lambda m: _as_rig(m, calibration=shadow),
        "urdf-dir": lambda m: m["config"].update(urdf_dir=str(secret)),
        "servo-model": lambda m: m["config"]["backend"].update(servo_model=shadow),
        "rig": lambda m: m["config"]["backend"].update(servo_model="datasheet", rig=shadow),
    }


@pytest.fixture
def opened(monkeypatch) -> list[str]:
    """Every path opened through ``open`` while the test runs (pathlib's reads go through it)."""
    seen: list[str] = []
    real = builtins.open

    def spy(file, *args, **kwargs):  # noqa: ANN001, ANN202 - open's own signature
        seen.append(str(file))
        return real(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", spy)
    monkeypatch.setattr(io, "open", spy)
    return seen


@pytest.mark.parametrize("case", ["calibration", "urdf-dir", "servo-model", "rig"])
def test_nothing_a_crafted_record_names_is_opened_nor_printed(good_run, secret, tmp_path, case, opened):
    run = tmp_path / "runs" / case
    shutil.copytree(good_run, run)
    _restore(run, _crafted(secret)[case])
    for args in (["report", str(run)], ["identify", str(run), "--out", str(tmp_path / "servos.yaml")],
                 ["export", str(run), "--mcap", str(tmp_path / "run.mcap")]):
        res = CliRunner().invoke(app, args)
        said = res.stdout + res.stderr
        assert res.exit_code in (0, 1, 2), (args, res.exit_code, res.exception)
        assert "Traceback" not in said and SECRET not in said and "daemon" not in said, said
        if res.exit_code == 2:
            assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not [p for p in opened if p.startswith(str(secret))], opened


def test_a_record_naming_its_own_urdf_dir_is_read_with_the_packages_urdfs(good_run, secret, tmp_path):
    """PyBullet opens a URDF in C, past any spy on ``open``: the loaded config says where it looks."""
    from bench.paths import URDF_DIR
    from bench.trial.record import load_checked

    run = tmp_path / "runs" / "urdf"
    shutil.copytree(good_run, run)
    _restore(run, _crafted(secret)["urdf-dir"])
    _, prep = load_checked(run)
    assert prep.config.robot_urdf == URDF_DIR / "arc_train.urdf"


def test_a_crafted_calibration_is_refused_naming_the_run(good_run, secret, tmp_path):
    run = tmp_path / "runs" / "calibrated"
    shutil.copytree(good_run, run)
    _restore(run, _crafted(secret)["calibration"])
    res = CliRunner().invoke(app, ["report", str(run)])
    assert res.exit_code == 2 and str(run) in res.stderr and "calibration" in res.stderr, res.stderr
    assert not (run / "report.md").exists()


def test_a_config_naming_a_file_that_is_no_config_never_prints_its_lines(secret, tmp_path):
    """The same file named by a config the user runs: refused, its lines not quoted."""
    cfg = tmp_path / "lab.yaml"
    cfg.write_text((REPO_ROOT / "hil_configs" / "lab_real.yaml").read_text()
                   + f"calibration: {secret / 'shadow'}\n")
    res = CliRunner().invoke(app, ["trial", str(cfg), "--emulate"])
    assert res.exit_code == 2, res.output
    assert "calibration" in res.stderr and SECRET not in res.output and "daemon" not in res.output, res.output


def test_a_run_directory_copied_elsewhere_rebuilds_lists_compares_and_exports(good_run, tmp_path, monkeypatch):
    away = tmp_path / "another-machine" / "runs"
    copy = away / good_run.name
    shutil.copytree(good_run, copy)
    twin = away / f"{good_run.name}-twin"
    shutil.copytree(good_run, twin)
    monkeypatch.chdir(tmp_path)  # neither the checkout nor where the run was made
    rebuilt = CliRunner().invoke(app, ["report", str(copy)])
    assert rebuilt.exit_code == 0, rebuilt.output
    assert (copy / "report.html").is_file() and (copy / "robot.png").is_file()
    listed = CliRunner().invoke(app, ["runs", "--out", str(away), "--json"])
    assert {r["status"] for r in json.loads(listed.stdout)["runs"]} == {"passed"}
    cmp = CliRunner().invoke(app, ["compare", str(copy), str(twin), "--out", str(tmp_path / "cmp")])
    assert cmp.exit_code in (0, 1) and (tmp_path / "cmp").exists(), cmp.output
    exported = CliRunner().invoke(app, ["export", str(copy), "--mcap", str(tmp_path / "run.mcap")])
    assert exported.exit_code == 0, exported.output
