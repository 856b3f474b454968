"""The bench as a lab installs it: a wheel carrying the URDFs and the shipped configs, a lab
folder written by ``hilbench init``, and a trial run from outside the checkout."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

from bench.paths import REPO_ROOT

SHIPPED = sorted(p.relative_to(REPO_ROOT).as_posix() for d in ("urdf", "hil_configs")
                 for p in (REPO_ROOT / d).rglob("*") if p.is_file() and p.suffix in (".urdf", ".obj", ".yaml"))


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel of this checkout, built as pip builds it (no dependencies fetched)."""
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO_ROOT)],
                   check=True, capture_output=True, timeout=240)
    (whl,) = out.glob("needle_hil_bench-*.whl")
    return whl


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """The wheel unpacked as an installer lays it out (its files only: no checkout beside them)."""
    site = tmp_path_factory.mktemp("site")
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    return site


def _hilbench(site: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site), "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-c", "from bench.cli.app import main; main()", *args],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=240)


def test_wheel_carries_every_urdf_and_shipped_config(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    assert SHIPPED and "urdf/arc_train.urdf" in SHIPPED and "hil_configs/stand/test_stand_xl330.yaml" in SHIPPED
    missing = [rel for rel in SHIPPED if f"bench/data/{rel}" not in names]
    assert not missing, f"not in the wheel: {missing}"
    code = [p.relative_to(REPO_ROOT).as_posix() for top in ("bench", "drivers", "trajectories")
            for p in (REPO_ROOT / top).rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    assert not [rel for rel in code if rel not in names]  # every module and asset, the live view's too


def test_installed_wheel_inits_a_lab_folder_and_runs_a_trial_outside_the_checkout(installed, tmp_path):
    probe = _hilbench(installed, tmp_path, "--version")
    assert probe.returncode == 0, probe.stderr
    where = subprocess.run([sys.executable, "-c", "import bench.paths as p; print(p.__file__); print(p.DATA_ROOT)"],
                           cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(installed)},
                           capture_output=True, text=True, check=True).stdout.split()
    assert Path(where[0]).is_relative_to(installed) and Path(where[1]) == installed / "bench" / "data"

    made = _hilbench(installed, tmp_path, "init", "lab")
    assert made.returncode == 0, made.stderr
    assert (tmp_path / "lab" / "sim_target1.yaml").is_file()
    ran = _hilbench(installed, tmp_path, "trial", "lab/sim_target1.yaml", "--out", "runs")
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "PASSED" in ran.stdout
    (run,) = (tmp_path / "runs").iterdir()
    assert (run / "report.html").is_file() and (run / "robot.png").is_file()

    travelled = tmp_path / "another-machine" / run.name  # the run alone, its config folder left behind
    shutil.copytree(run, travelled)
    for name in ("report.html", "report.md", "robot.png", "joints.png"):
        (travelled / name).unlink()
    shutil.rmtree(tmp_path / "lab")
    rebuilt = _hilbench(installed, travelled.parent, "report", run.name)
    assert rebuilt.returncode == 0, rebuilt.stdout + rebuilt.stderr
    assert (travelled / "report.html").is_file() and (travelled / "robot.png").is_file()


def test_init_writes_the_shipped_configs_and_refuses_a_folder_in_use(tmp_path, monkeypatch):
    from bench.cli.app import app
    from typer.testing import CliRunner

    monkeypatch.chdir(tmp_path)
    first = CliRunner().invoke(app, ["init", "lab"])
    assert first.exit_code == 0, first.output
    written = sorted(p.relative_to(tmp_path / "lab").as_posix() for p in (tmp_path / "lab").rglob("*.yaml"))
    assert written == [rel.removeprefix("hil_configs/") for rel in SHIPPED if rel.startswith("hil_configs/")]
    before = (tmp_path / "lab" / "lab_real.yaml").read_text()
    again = CliRunner().invoke(app, ["init", "lab"])
    assert again.exit_code == 2 and "not an empty folder" in again.output
    assert (tmp_path / "lab" / "lab_real.yaml").read_text() == before  # nothing written over
    assert [p.name for p in tmp_path.iterdir()] == ["lab"]  # and no half-written folder left beside it


def test_a_lab_folders_configs_use_the_lab_folders_files(tmp_path, monkeypatch):
    """sim_target1_identified names the rig and the servo model: the lab's edited copies are used."""
    from bench.config.models import load_trial_config
    from bench.config.shipped import write_lab_folder

    write_lab_folder(tmp_path / "lab")
    rig = tmp_path / "lab" / "lab_real.yaml"
    data = yaml.safe_load(rig.read_text())
    data["backend"]["servos"]["theta3"]["id"] = 42  # the lab's own wiring
    rig.write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path.parent)  # not where the folder is: paths resolve beside the config
    cfg = load_trial_config(tmp_path / "lab" / "sim_target1_identified.yaml")
    assert cfg.backend.servos["theta3"].id == 42
    assert cfg.resolve(Path(cfg.backend.servo_model)) == tmp_path / "lab" / "servo_models" / "emulated_worn_rig.yaml"
    assert cfg.robot_urdf.is_file()  # the URDFs are not copied: found in the package's data


def test_shipped_configs_load_from_any_directory(tmp_path, monkeypatch):
    from bench.config.models import load_trial_config
    from bench.paths import CONFIG_DIR

    monkeypatch.chdir(tmp_path)
    cfg = load_trial_config(CONFIG_DIR / "sim_target1_servo.yaml")
    assert cfg.backend.servos and cfg.robot_urdf.is_file()
