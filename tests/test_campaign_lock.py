"""One writer per campaign directory: a second run or resume refuses while the first lives, and
takes over after a kill -9 of the first; checked with real processes.

The holder is stopped (SIGSTOP) while the other process tries: it lives and holds the lock for
as long as that takes, on a loaded machine too, so a few trials are enough to test it."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator, Sequence

import pytest
import yaml

from bench.campaign.lock import LOCK_NAME, CampaignBusy, CampaignLock
from bench.campaign.run import create_campaign, run_campaign
from bench.campaign.store import CampaignStore

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"
HILBENCH = str(Path(sys.executable).with_name("hilbench"))


def _campaign(tmp_path: Path, samples: int) -> Path:
    spec = {"name": "locked", "base": str(FAST), "seed": 3, "samples": samples, "repeats": 1,
            "faults": [{"name": "deadband", "joints": "all", "tol_deg": 0.29}]}
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return create_campaign(path, tmp_path / "c")


def _rows(d: Path) -> list[dict]:
    with CampaignStore(d / "campaign.db") as store:
        return store.trials()


def _resume(d: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([HILBENCH, "campaign", "resume", str(d), "--workers", "1", "--no-report",
                             "--json", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait(cond, timeout: float = 90.0) -> None:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError("timed out")


def _consistent(d: Path) -> list[dict]:
    """Every trial done once, with its one log directory, and nothing else under trials/."""
    rows = _rows(d)
    assert all(r["status"] == "done" for r in rows), [r["status"] for r in rows]
    dirs = sorted(p.name for p in (d / "trials").iterdir() if p.name != ".staging")
    assert dirs == sorted(r["name"] for r in rows)
    assert not any((d / "trials" / ".staging").glob("*"))
    return rows


def _holder(d: Path, procs: Sequence[subprocess.Popen]) -> subprocess.Popen:
    """The one of ``procs`` that took the campaign's lock, once its pid is in the lock file."""
    by_pid = {p.pid: p for p in procs}

    def named() -> subprocess.Popen | None:
        try:
            words = (d / LOCK_NAME).read_text().split()
        except OSError:
            return None
        return by_pid.get(int(words[0])) if words and words[0].isdigit() else None

    _wait(lambda: named() is not None or any(p.poll() is not None for p in procs))
    holder = named()
    assert holder is not None, [(p.pid, p.poll()) for p in procs]
    return holder


@contextlib.contextmanager
def _stopped(proc: subprocess.Popen) -> Iterator[None]:
    """``proc`` stopped for the block (SIGSTOP; SIGCONT after): it lives and keeps the lock, and
    finishes nothing meanwhile, however long the other process takes to get to the lock."""
    proc.send_signal(signal.SIGSTOP)
    try:
        yield
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGCONT)


def test_the_lock_refuses_another_process_naming_it_nests_in_its_holder_and_leaves_no_pid(tmp_path):
    d = _campaign(tmp_path, samples=2)
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from bench.campaign.lock import "
                               "CampaignLock; CampaignLock(sys.argv[1]).acquire(); print('held', flush=True); "
                               "time.sleep(60)", str(d)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(CampaignBusy, match=rf"being run by process {holder.pid}"):
            CampaignLock(d).acquire()
        with pytest.raises(CampaignBusy, match="one writer"):
            run_campaign(d, workers=1, report=False)
        assert all(r["status"] == "pending" and r["attempts"] == 0 for r in _rows(d))  # untouched
    finally:
        holder.kill()
        holder.wait()
    with CampaignLock(d):  # the holder's death freed it; the holder of it may take it again
        assert (d / LOCK_NAME).read_text().split()[0] == str(os.getpid())
        with CampaignLock(d):
            pass
        assert (d / LOCK_NAME).read_text().split()[0] == str(os.getpid())  # still held
    assert (d / LOCK_NAME).read_text() == ""  # released: no stale pid left behind


def test_two_resumes_at_once_run_each_trial_once(tmp_path):
    d = _campaign(tmp_path, samples=4)
    a, b = _resume(d), _resume(d)
    try:
        winner = _holder(d, (a, b))
        loser = b if winner is a else a
        with _stopped(winner):  # the winner holds the lock, unfinished, until the loser has tried it
            refused = loser.communicate(timeout=120)[1]
        assert loser.returncode == 2, refused
        _, err = winner.communicate(timeout=300)
        assert winner.returncode == 0, err
    finally:
        for p in (a, b):
            if p.poll() is None:
                p.kill()
                p.wait()
    lines = refused.strip().splitlines()  # the holder's pid may not be written yet: "is being run by"
    assert len(lines) == 1 and "is being run by" in lines[0] and "Traceback" not in refused
    rows = _consistent(d)
    assert all(r["attempts"] == 1 for r in rows)  # not one trial ran twice


def test_a_second_resume_refuses_while_the_first_lives_and_takes_over_after_kill_9(tmp_path):
    d = _campaign(tmp_path, samples=4)
    first = _resume(d)
    try:
        _wait(lambda: sum(r["status"] == "done" for r in _rows(d)) >= 1)
        with _stopped(first):  # alive, holding the lock, while the second tries
            second = subprocess.run([HILBENCH, "campaign", "resume", str(d), "--json"], capture_output=True,
                                    text=True, timeout=120)
            assert first.poll() is None, "the first resume ended before the second tried: nothing tested"
            assert second.returncode == 2, second.stderr
            (line,) = second.stderr.strip().splitlines()
            assert f"being run by process {first.pid}" in line and str(d) in line
            assert second.stdout == ""
            first.send_signal(signal.SIGKILL)
            first.wait(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    before = {r["id"]: r for r in _rows(d)}
    done_before = {i for i, r in before.items() if r["status"] == "done"}
    assert 1 <= len(done_before) < 4
    # the kernel dropped the dead holder's lock: the next resume takes over and finishes
    again = subprocess.run([HILBENCH, "campaign", "resume", str(d), "--workers", "1", "--no-report", "--json"],
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout)["completed"] == 4
    for r in _consistent(d):
        if r["id"] in done_before:
            assert r["attempts"] == 1 and r["finished_at"] == before[r["id"]]["finished_at"]
