"""The CLI's everyday basics: --version, help without placeholders, `runs`, labelled progress,
--gui without a display."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_in_process import invoke as _invoke
from bench.config.models import load_trial_config
from bench.core.log import TrialLog
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
SIM = REPO / "hil_configs" / "sim_target1.yaml"


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``hilbench ARGS`` in its own process: the installed command, start-up and exit code included."""
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=120,
                          env=env, cwd=REPO)


@pytest.fixture(autouse=True)
def _at_the_repository(monkeypatch):
    """Commands run in this process start where ``_cli`` starts them: at the repository's root."""
    monkeypatch.chdir(REPO)


def test_version_matches_the_installed_package():
    from importlib.metadata import version

    res = _cli("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"hilbench {version('needle-hil-bench')}"


def test_help_shows_no_type_placeholders_on_flags_and_names_arguments():
    res = _cli("trial", "--help")
    assert res.returncode == 0
    assert "<bool>" not in res.stdout and "{config}" not in res.stdout
    assert "CONFIG" in res.stdout and "--json" in res.stdout
    assert "--install-completion" in _cli("--help").stdout  # shell completion is on offer


def test_runs_lists_passed_stopped_and_killed_trials_with_their_verdicts(tmp_path):
    out = tmp_path / "runs"
    cfg = load_trial_config(SIM)
    phases: list[str] = []
    passed = run_trial(prepare(cfg), out, TrialHooks(phase=phases.append))
    # the progress display hears every phase in order, the plan's segments included
    assert phases == ["connecting", "planning", *passed_segments(passed.run_dir), "report"]
    stopped = run_trial(prepare(cfg.model_copy(update={"name": "stopped", "safety": cfg.safety.model_copy(
        update={"tracking_error_deg": 1e-6})})), out, TrialHooks(report=False))
    assert not stopped.completed
    killed = out / "20000101-000000-killed"  # what SIGKILL leaves: the journal only
    killed.mkdir()
    log = TrialLog(["a"], metadata={"config": {"name": "killed"}, "backend": "pybullet",
                                    "start_time": "2000-01-01T00:00:00+00:00"})
    log.journal_to(killed)
    log.append(0.0, 0, [0.0], [0.0], [0.0], [0.0], [0.0])
    log.flush()
    (out / "compare-x").mkdir()  # not a trial: left out

    res = _invoke("runs", "--out", str(out), "--json")
    assert res.exit_code == 0, res.stderr
    runs = json.loads(res.stdout)["runs"]
    assert [r["status"] for r in runs] == ["incomplete", "passed", "stopped"]
    assert [r["config"] for r in runs] == ["killed", cfg.name, "stopped"]
    assert runs[1]["tip_deviation_mm"] == round(float(np.linalg.norm(passed.outcome.tip_deviation_mm)), 3)
    assert runs[1]["report"].endswith("report.html") and runs[2]["report"] is None
    assert runs[2]["reason"] == stopped.reason and "interlock" in stopped.reason
    text = _invoke("runs", "--out", str(out), columns=80)
    assert text.exit_code == 0
    table = [ln for ln in text.stdout.splitlines() if ": " not in ln]  # reasons wrap as the terminal likes
    assert len(table) >= 7 and all(len(line) <= 80 for line in table)
    assert passed.run_dir.name in text.stdout  # a run's name is never broken mid-value
    assert f"{stopped.run_dir.name}: {stopped.reason}" in text.stdout
    missing = _invoke("runs", "--out", str(tmp_path / "none"))
    assert missing.exit_code == 2 and missing.stderr.strip() == f"error: --out {tmp_path / 'none'}: no such directory"
    (tmp_path / "empty").mkdir()
    empty = _invoke("runs", "--out", str(tmp_path / "empty"))
    assert empty.exit_code == 0 and "no trials, comparisons or campaigns" in empty.stdout


def passed_segments(run_dir: Path) -> list[str]:
    return TrialLog.load(run_dir / "trial.npz").segment_names


def test_gui_without_a_display_is_refused_with_one_line(tmp_path, monkeypatch):
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):  # read when the trial starts, not at start-up
        monkeypatch.delenv(name, raising=False)
    res = _invoke("trial", str(SIM), "--gui", "--out", str(tmp_path / "o"))
    assert res.exit_code == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--gui needs a display" in lines[0]
    assert not (tmp_path / "o").exists()


def test_trial_summary_fits_80_columns_without_splitting_a_value(tmp_path):
    res = _invoke("trial", str(SIM), "--out", str(tmp_path / "o"), columns=80)
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.splitlines()
    tip = next(ln for ln in lines if ln.startswith("tip deviation: "))
    assert len(tip) <= 80 and all(f" {axis} " in tip for axis in "XYZ") and tip.endswith(" mm")
    rest = next(ln for ln in lines if ln.startswith("depth "))
    assert len(rest) <= 80 and rest.endswith("°") and "angle " in rest and "-0.000" not in rest


NUMBER = r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"


def _numbers(text: str) -> list[str]:
    import re

    return re.findall(NUMBER, text)


@pytest.mark.parametrize("args", [
    ("robot", "arc-train"),
    ("robot", "zerobot"),
    ("ik", "arc-train", "--x-mm", "0", "--y-mm", "88.2", "--z-mm", "66", "--depth-mm", "30.1",
     "--angle-deg", "47"),
    ("check", str(SIM)),
    ("accuracy", "arc-train", "--samples", "500"),
], ids=lambda a: a[0] + "-" + a[1].split("/")[-1])
def test_summaries_fit_80_columns_and_never_split_a_value(args):
    """On an 80-column terminal every line fits, and every number printed on a wide terminal
    is printed whole (tables shrink their padding and wrap words, never digits)."""
    wide = _invoke(*args, columns=200)
    narrow = _invoke(*args, columns=80)
    assert wide.exit_code == narrow.exit_code == 0, narrow.stderr
    too_long = [ln for ln in narrow.stdout.splitlines() if len(ln) > 80]
    assert not too_long, too_long
    assert _numbers(narrow.stdout) == _numbers(wide.stdout)


def test_help_lists_every_command_with_a_whole_sentence():
    """`hilbench --help` shows each command's first line: a sentence that ends, never cut."""
    from bench.cli.app import app
    from typer.main import get_command

    group = get_command(app)
    for name, command in group.commands.items():
        first = (command.help or "").strip().split("\n\n")[0]
        assert "\n" not in first, (name, first)  # one line: the list shows no more of it
        assert first.endswith("."), (name, first)
    shown = _cli("--help", env={**os.environ, "COLUMNS": "200"}).stdout
    for name, command in group.commands.items():
        first = (command.help or "").strip().split("\n\n")[0]
        assert " ".join(first.split()) in " ".join(shown.replace("│", " ").split()), name


def test_check_ends_with_a_count_line_also_with_emulate():
    lab = Path(__file__).resolve().parent.parent / "hil_configs" / "lab_real.yaml"
    emulated = _invoke("check", str(lab), "--emulate")
    assert emulated.exit_code == 0, emulated.stderr
    assert " ".join(emulated.stdout.split()).endswith(
        "2 of 2 checks passed; the serial ports not checked (--emulate brings its own)"), emulated.stdout
    real = _invoke("check", str(lab))  # no adapter here: the ports fail, and the count says so
    assert real.exit_code == 2 and real.stdout.splitlines()[-1] == "2 of 3 checks passed"
