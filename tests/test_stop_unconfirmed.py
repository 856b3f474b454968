"""A bus that dies mid-run: "torque off not confirmed" is the one thing the technician must see.

The emulated rig's cable is pulled (SIGUSR1 to `hilbench emulate`) while `hilbench trial`
or `hilbench compare` drives it. The safe stop cannot be read back from any servo; the
stderr line and the ``--json`` reason say so first, and the exit code is 3 (the stop was
not confirmed), apart from 1 (ran and failed).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.core.log import journal_row_width
from drivers.errors import ExitCode

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
LAB = REPO / "hil_configs" / "lab_real.yaml"

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals and /proc")


def _emulator_of(config: Path) -> int | None:
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"emulate" in cmd and str(config).encode() in cmd:
                return int(d.name)
    return None


def _journal_rows(out: Path) -> int:
    widths = {}
    for j in out.rglob("trial.journal"):
        try:
            meta = json.loads((j.parent / "trial.journal.json").read_text())
        except (OSError, ValueError):
            continue  # its metadata comes first; until then it holds no row
        widths[j] = journal_row_width(len(meta["joint_names"]), meta.get("timing") is True,
                                      bool(meta.get("encoder_joint")))
    return max((j.stat().st_size // (8 * w) for j, w in widths.items()), default=0)


def _pull_the_cable_mid_run(proc: subprocess.Popen, config: Path, out: Path) -> None:
    t_end = time.monotonic() + 180
    while _journal_rows(out) < 30:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < t_end, "the rig never started moving"
        time.sleep(0.02)
    pid = _emulator_of(config)
    assert pid is not None
    os.kill(pid, signal.SIGUSR1)  # the emulator's cable out: no servo hears or answers


def _unconfirmed(text: str) -> bool:
    return "torque off not confirmed" in text.lower()


def test_a_trial_whose_bus_dies_says_torque_off_not_confirmed_and_exits_3(tmp_path):
    config = tmp_path / "lab.yaml"
    shutil.copy(LAB, config)
    out = tmp_path / "out"
    proc = subprocess.Popen([HILBENCH, "trial", str(config), "--emulate", "--json", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _pull_the_cable_mid_run(proc, config, out)
    stdout, err = proc.communicate(timeout=120)
    assert "Traceback" not in err
    assert proc.returncode == ExitCode.STOP_UNCONFIRMED == 3, err
    said = [x for x in err.splitlines() if _unconfirmed(x)]
    assert len(said) == 1 and said[0].startswith("check the rig: torque off NOT confirmed"), err
    result = json.loads(stdout.strip().splitlines()[-1])
    assert result["passed"] is False and result["completed"] is False
    assert result["reason"].lower().startswith("torque off not confirmed"), result
    assert "CommunicationError" in result["reason"]  # and then why it stopped
    assert _unconfirmed(result["safe_stop"])
    on_disk = json.loads((Path(result["run_dir"]) / "result.json").read_text())
    assert _unconfirmed(on_disk["safe_stop"])  # the record keeps it beside its own reason
    assert _emulator_of(config) is None


def test_a_compare_whose_rig_dies_says_torque_off_not_confirmed_and_exits_3(tmp_path):
    config = tmp_path / "lab.yaml"
    shutil.copy(LAB, config)
    out = tmp_path / "out"
    proc = subprocess.Popen([HILBENCH, "compare", str(config), "--emulate", "--repeats", "1", "--retries", "0",
                             "--json", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _pull_the_cable_mid_run(proc, config, out)
    stdout, err = proc.communicate(timeout=300)
    assert "Traceback" not in err
    assert proc.returncode == ExitCode.STOP_UNCONFIRMED, err
    said = [x for x in err.splitlines() if _unconfirmed(x)]
    assert len(said) == 1 and said[0].startswith("check the rig: torque off not confirmed"), err
    result = json.loads(stdout.strip().splitlines()[-1])
    assert result["passed"] is False and result["reason"].lower().startswith("torque off not confirmed")
    assert _unconfirmed(result["safe_stop"])
