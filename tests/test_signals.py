"""SIGINT, SIGTERM and SIGHUP at any moment of `hilbench trial` end it the same way: safe stop,
log and record on disk (rebuildable), one line on stderr, exit 128 + N, no surviving child;
SIGKILL leaves a journal that `hilbench report` recovers."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.core.log import TrialLog, journal_row_width

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
SIM = REPO / "hil_configs" / "sim_target1.yaml"
LAB = REPO / "hil_configs" / "lab_real.yaml"


def _start(config: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([HILBENCH, "trial", str(config), "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(predicate, timeout: float = 60.0, what: str = "",
              proc: subprocess.Popen | None = None) -> None:
    t_end = time.monotonic() + timeout
    while not predicate():
        if proc is not None and proc.poll() is not None:
            _, err = proc.communicate()
            raise AssertionError(f"the trial ended (exit {proc.returncode}) before {what}: {err}")
        if time.monotonic() > t_end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


def _run_dir(out: Path) -> Path | None:
    dirs = list(out.iterdir()) if out.is_dir() else []
    return dirs[0] if dirs else None


def _slow_sim(tmp_path: Path) -> Path:
    """Target 1 on the sim at a tenth of the speed: a run of a few seconds."""
    import yaml

    data = yaml.safe_load(SIM.read_text())
    data["plan"]["velocity_scale"] = 0.05
    path = tmp_path / "slow_sim.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _journal_rows(out: Path) -> int:
    d = _run_dir(out)
    j = d / "trial.journal" if d else None
    if not (j and j.is_file()):
        return 0
    return j.stat().st_size // (8 * _row_width(d))


def _row_width(run: Path) -> int:
    """The journal's row width as its metadata gives it (timing in a paced trial, the train's
    encoder on a rig); before the metadata is there, the narrowest."""
    try:
        meta = json.loads((run / "trial.journal.json").read_text())
    except (OSError, ValueError):
        return journal_row_width(9, False, False)
    return journal_row_width(len(meta["joint_names"]), meta.get("timing") is True, bool(meta.get("encoder_joint")))


def _emulated_lab(tmp_path: Path) -> Path:
    """lab_real.yaml without the servos' integral gains, so torque goes on without seconds of the
    rig's real time spent waiting for integrators to settle, and with its plant stepped at 250 Hz, a
    quarter of the emulator's work. The trial's loop then runs within a second of the rig's start,
    on the same driver, bus and safe stop in real time: what a signal meets."""
    import yaml

    data = yaml.safe_load(LAB.read_text())
    for servo in data["backend"]["servos"].values():
        servo.pop("position_i", None)
    data["emulator"]["physics_hz"] = 250
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _rebuild_report(run: Path) -> None:
    """`hilbench report RUN --json` through the command itself, in this process: the record on disk
    rebuilds the report. What is under test is the interrupted trial's process; a fresh process for
    the report would only add a second of imports."""
    from typer.testing import CliRunner

    from bench.cli.app import app

    rebuilt = CliRunner().invoke(app, ["report", str(run), "--json"])
    assert rebuilt.exit_code == 0 and rebuilt.exception is None, (rebuilt.output, rebuilt.exception)


def _finish(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


def _assert_interrupted(rc: int, err: str, sig: int, out: Path) -> TrialLog:
    name = signal.Signals(sig).name
    assert rc == 128 + sig, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err
    assert lines[-1].startswith(f"interrupted by {name}: trial stopped"), err
    run = _run_dir(out)
    assert f"log saved in {run}" in lines[-1]
    result = json.loads((run / "result.json").read_text())
    assert result["completed"] is False and result["reason"] == f"interrupted by {name}"
    _rebuild_report(run)
    assert (run / "report.html").is_file()
    log = TrialLog.load(run / "trial.npz")
    assert [e.message for e in log.events if e.kind == "abort"] == [f"interrupted by {name}"]
    assert not (run / "trial.journal").exists()  # the record replaced the journal
    return log


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_during_set_up_and_mid_run_on_the_sim(tmp_path, sig):
    """Mid-run with --json, which carries the reason whenever a run did not pass, a signal
    included: stdout gets that line, stderr the same one line as without it."""
    # during the set-up: as soon as the run directory exists (backend, interlocks, imports)
    out = tmp_path / "setup"
    proc = _start(SIM, out)
    _wait_for(lambda: _run_dir(out) is not None, what="the run directory")
    rc, err = _finish(proc, sig)
    _assert_interrupted(rc, err, sig, out)
    # mid-run: once the journal holds samples (a slow plan: the sim runs Target 1 in a
    # fraction of a second, less than the journal's flush interval)
    out = tmp_path / "run"
    proc = _start(_slow_sim(tmp_path), out, "--json")
    _wait_for(lambda: _journal_rows(out) > 10, what="samples in the journal",
              proc=proc)
    proc.send_signal(sig)
    stdout, err = proc.communicate(timeout=60)
    log = _assert_interrupted(proc.returncode, err, sig, out)
    assert len(log) > 10
    assert [e.message for e in log.events if e.kind == "safe-stop"] == ["holding the measured position"]
    assert "holding the measured position" in err
    line = json.loads(stdout.strip().splitlines()[-1])
    assert line["passed"] is False and line["completed"] is False
    assert line["reason"] == f"interrupted by {signal.Signals(sig).name}" and line["exit_code"] == 128 + sig
    assert line["run_dir"] == str(_run_dir(out)) and line["safe_stop"] == "holding the measured position"


def _catches_sigterm(pid: int) -> bool:
    """Whether ``pid`` has its own SIGTERM handler: hilbench's are in place (Python's start-up,
    before the first line of hilbench runs, catches SIGINT alone)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = next(int(x.split()[1], 16) for x in status.splitlines() if x.startswith("SigCgt:"))
    return bool(mask >> (signal.SIGTERM - 1) & 1)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_while_the_command_loads_gives_one_line_and_128_plus_n(tmp_path, sig):
    """From the command's first line on — its modules still importing, typer, rich and numpy
    not yet loaded — a stop signal ends it with one line and 128 + N, and writes nothing.

    Each delay counts from the spawn, but never from before the handlers are in place: the
    interpreter's own start-up before that (tens of ms, more on a loaded machine) is Python's."""
    name = signal.Signals(sig).name
    for delay in (0.0, 0.05, 0.15):
        out = tmp_path / f"out-{delay}"
        proc = _start(SIM, out)
        t0 = time.monotonic()
        _wait_for(lambda: _catches_sigterm(proc.pid), timeout=20, what="hilbench's handlers", proc=proc)
        time.sleep(max(0.0, delay - (time.monotonic() - t0)))
        rc, err = _finish(proc, sig)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert rc == 128 + sig, (delay, err)
        assert "Traceback" not in err and len(lines) == 1, (delay, err)
        assert lines[0].startswith(f"interrupted by {name}: "), (delay, err)
        if _run_dir(out) is None:
            assert "nothing had moved" in lines[0], (delay, err)
        else:  # on a quick machine the trial got going: then it is a trial's own stop
            assert "trial stopped" in lines[0], (delay, err)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_inside_an_import_is_raised_once_the_import_is_done(tmp_path, monkeypatch, sig):
    """Raised inside an import, a stop signal reaches the loader of a C extension, which turns it
    into an ImportError with its traceback (numpy's did, 0.15 s into a trial's start beside two CPU
    hogs: exit 1, not 143). A signal that lands in an import is sent again once the import is done,
    and raised there: the module loads whole and the stop comes right after it."""
    from bench.core.interrupts import SignalGuard, TrialInterrupted

    name = f"module_signalled_while_loading_{sig}"
    (tmp_path / f"{name}.py").write_text(
        "import os, time\n"
        f"os.kill(os.getpid(), {int(sig)})\n"
        "t = time.monotonic()\n"
        "while time.monotonic() - t < 0.05:  # the handler runs here, inside the import\n"
        "    pass\n"
        "LOADED = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    loaded = None
    try:
        with SignalGuard() as guard, pytest.raises(TrialInterrupted) as stopped:
            importlib.import_module(name)
            loaded = time.monotonic()
            time.sleep(2.0)  # the signal comes again within milliseconds
        after = time.monotonic() - loaded if loaded is not None else None
        assert getattr(sys.modules.get(name), "LOADED", False), "the import was cut short"
        assert after is not None and after < 0.5, after
        assert stopped.value.signum == sig and guard.signum == sig
    finally:
        sys.modules.pop(name, None)


@pytest.mark.parametrize("where", ["in the muted stretch", "between the two calls putting it back"])
def test_a_stop_signal_while_the_output_is_muted_is_raised_once_it_is_back(monkeypatch, where):
    """PyBullet's banner is kept off the terminal by pointing fds 1 and 2 at /dev/null (the
    backend's set-up). A stop signal raised there, between the two calls that put them back,
    left stderr on /dev/null: the trial exited 130 with its one line lost. It is held instead,
    and raised the moment both are back."""
    from bench.core.interrupts import SignalGuard, TrialInterrupted
    from drivers.quiet import muted_output

    real_dup2, calls = os.dup2, []

    def dup2(fd: int, fd2: int, *args) -> int:
        out = real_dup2(fd, fd2, *args)
        calls.append(fd2)
        if where.startswith("between") and len(calls) == 3:  # fd 1 is back, fd 2 not yet
            os.kill(os.getpid(), signal.SIGINT)
        return out

    before = [os.fstat(fd) for fd in (1, 2)]
    saved = [os.dup(1), os.dup(2)]
    monkeypatch.setattr(os, "dup2", dup2)
    try:
        with SignalGuard() as guard, pytest.raises(TrialInterrupted):
            with muted_output():
                if where.startswith("in"):
                    os.kill(os.getpid(), signal.SIGINT)
        after = [os.fstat(fd) for fd in (1, 2)]
    finally:  # whatever happened, the session's own output goes on
        for fd, copy in zip((1, 2), saved):
            real_dup2(copy, fd)
            os.close(copy)
    assert guard.signum == signal.SIGINT
    assert [(s.st_dev, s.st_ino) for s in after] == [(s.st_dev, s.st_ino) for s in before]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_tool_without_a_safe_stop_of_its_own_also_ends_in_one_line(tmp_path, sig):
    """`hilbench emulate` serves until stopped; SIGHUP (not one it waits for) still ends it in
    one line and 128 + N."""
    proc = subprocess.Popen([HILBENCH, "emulate", str(LAB), "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert "dynamixel_port" in proc.stdout.readline()  # serving
    rc, err = _finish(proc, sig)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if sig == signal.SIGTERM:  # the emulator's own stop: it reports its counters and exits 0
        assert rc == 0 and "Traceback" not in err, err
    else:
        assert rc == 128 + sig and len(lines) == 1, err
        assert lines[0] == f"interrupted by {signal.Signals(sig).name}: hilbench emulate stopped; nothing had moved"


def test_signal_while_the_report_is_drawn(tmp_path, monkeypatch):
    """The record is complete before the report: a signal then still leaves a rebuildable run."""
    from typer.testing import CliRunner

    import bench.trial.run
    from bench.cli.app import app

    def drawing(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)  # the handler raises here
        raise AssertionError("the signal did not stop the report")

    monkeypatch.setattr(bench.trial.run, "write_trial_report", drawing)
    res = CliRunner().invoke(app, ["trial", str(REPO / "hil_configs" / "sim_target1_fast.yaml"),
                                   "--out", str(tmp_path)])
    assert res.exit_code == 143, res.output
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # handlers restored
    run = _run_dir(tmp_path)
    assert json.loads((run / "result.json").read_text())["completed"] is True  # the trial itself did
    assert "interrupted by SIGTERM" in res.output and f"log saved in {run}" in res.output
    monkeypatch.undo()
    _rebuild_report(run)


def _emulators_of(config: Path) -> list[int]:
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"emulate" in cmd and str(config).encode() in cmd:
                pids.append(int(d.name))
    return pids


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals and /proc")
def test_sigterm_on_the_emulated_rig_turns_torque_off_and_leaves_no_child(tmp_path):
    config = _emulated_lab(tmp_path)
    out = tmp_path / "out"
    proc = _start(config, out, "--emulate")
    _wait_for(lambda: _journal_rows(out) > 20, timeout=120, what="samples in the journal",
              proc=proc)
    assert _emulators_of(config)
    rc, err = _finish(proc, signal.SIGTERM)
    log = _assert_interrupted(rc, err, signal.SIGTERM, out)
    assert [e.message for e in log.events if e.kind == "safe-stop"] == [
        "torque off, confirmed by reading Torque Enable back from all 9 servos"]
    _wait_for(lambda: not _emulators_of(config), timeout=10, what="the emulator to exit")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl and /proc")
def test_an_orphaned_emulator_dies_at_once_however_stuck_it_is(tmp_path):
    """The kernel ends the emulated rig when the process that started it dies, even one that
    could not run a line of its own stop (frozen here by SIGSTOP): a busy machine delaying
    its threads cannot keep it alive."""
    config = tmp_path / "lab.yaml"
    shutil.copy(LAB, config)
    starter = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from bench.rig.emulated import EmulatorProcess; "
         "print(EmulatorProcess(Path(sys.argv[1])).proc.pid, flush=True); time.sleep(600)",
         str(config)], stdout=subprocess.PIPE, text=True)
    try:
        emulator = int(starter.stdout.readline())
        os.kill(emulator, signal.SIGSTOP)
        starter.kill()
        starter.communicate(timeout=30)
        _wait_for(lambda: not _emulators_of(config), timeout=10, what="the orphaned emulator to die")
    finally:
        starter.kill()
        for pid in _emulators_of(config):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl and /proc")
def test_sigkill_leaves_a_journal_that_report_recovers_and_no_child(tmp_path):
    config = _emulated_lab(tmp_path)
    out = tmp_path / "out"
    proc = _start(config, out, "--emulate")
    _wait_for(lambda: _journal_rows(out) > 100, timeout=120, what="samples in the journal",
              proc=proc)
    rows_before = _journal_rows(out)
    proc.kill()
    proc.communicate(timeout=30)
    _wait_for(lambda: not _emulators_of(config), timeout=10, what="the emulator to die with it")
    run = _run_dir(out)
    assert not (run / "record.json").exists()
    _rebuild_report(run)
    log = TrialLog.load(run / "trial.npz")
    assert len(log) >= rows_before  # at most the last flush interval is lost
    assert any(e.kind == "abort" and "killed" in e.message for e in log.events)
    assert json.loads((run / "result.json").read_text())["completed"] is False
