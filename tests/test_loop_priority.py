"""A paced loop runs ahead of a browser and other jobs where the OS allows, says what it got, and
leaves a longer-lived process as it found it; a simulator's loop never crowds the machine."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from bench.config.models import load_trial_config
from bench.rig.emulated import EmulatorProcess
from drivers.timing import LOOP_NICE, LOOP_RT_PRIORITY, LoopPriority, raise_priority

REPO = Path(__file__).resolve().parent.parent
LAB = REPO / "hil_configs" / "lab_real.yaml"
root_only = pytest.mark.skipif(os.geteuid() != 0, reason="raising a priority needs root or CAP_SYS_NICE")
#: What a paced loop gets as root: its nice value and SCHED_FIFO above every ordinary task.
GOT = f"nice {LOOP_NICE}, SCHED_FIFO {LOOP_RT_PRIORITY}"


def _nice(tid: int = 0) -> int:
    return os.getpriority(os.PRIO_PROCESS, tid)


@root_only
def test_every_thread_is_raised_for_the_block_and_put_back_after():
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    before = _nice()
    try:
        with LoopPriority() as got:
            assert got.got == GOT
            assert _nice() == LOOP_NICE and _nice(other.native_id) == LOOP_NICE
            assert os.sched_getscheduler(other.native_id) == os.SCHED_FIFO
            assert os.sched_getparam(other.native_id).sched_priority == LOOP_RT_PRIORITY
            born = []  # a thread started inside inherits it
            t = threading.Thread(target=lambda: born.append((_nice(), os.sched_getscheduler(0))))
            t.start()
            t.join()
            assert born == [(LOOP_NICE, os.SCHED_FIFO)]
        assert _nice() == before and _nice(other.native_id) == before
        assert os.sched_getscheduler(0) == os.sched_getscheduler(other.native_id) == os.SCHED_OTHER
    finally:
        stop.set()
        other.join()


def test_a_user_not_allowed_to_raise_it_is_told_why_and_keeps_its_priority(monkeypatch):
    """Without CAP_SYS_NICE or an RLIMIT_NICE allowance Linux answers EPERM; the loop runs on at
    the priority it had, and the record says why."""
    def refused(*args):
        raise PermissionError(1, "Operation not permitted")

    before = _nice()
    monkeypatch.setattr(os, "setpriority", refused)
    got = raise_priority()
    assert got.startswith(f"nice {before} (raising it to {LOOP_NICE} was refused")
    assert "CAP_SYS_NICE" in got and _nice() == before


@root_only
def test_already_higher_is_kept():
    with LoopPriority(nice=-12):
        # never lowered by asking for less
        assert raise_priority(LOOP_NICE) == f"nice -12, SCHED_FIFO {LOOP_RT_PRIORITY}"


@root_only
def test_a_real_time_policy_refused_leaves_the_nice_value_alone(monkeypatch):
    """Where the OS grants a nice value but no real-time policy (a user with an RLIMIT_NICE
    allowance and no rtprio), the loop runs at its nice value and the record says just that."""
    def refused(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refused)
    with LoopPriority() as got:
        assert got.got == f"nice {LOOP_NICE}" and os.sched_getscheduler(0) == os.SCHED_OTHER


@root_only
def test_the_emulated_rig_serves_at_the_loops_priority_and_a_trial_records_what_it_got(tmp_path):
    """`hilbench emulate` (here as a trial's child) raises itself; a paced trial records its priority
    in the log, its report and --json; a sim trial leaves its own alone."""
    from bench.trial.plan import prepare
    from bench.trial.run import run_trial

    with EmulatorProcess(LAB) as rig:
        deadline = time.monotonic() + 10
        while _nice(rig.proc.pid) != LOOP_NICE and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _nice(rig.proc.pid) == LOOP_NICE
        before = _nice()
        res = run_trial(prepare(rig.retarget(load_trial_config(LAB))), tmp_path / "runs")
        assert _nice() == before  # the test's process is as it was
    assert res.timing.priority == GOT
    assert res.timing.as_dict()["priority"] == GOT
    assert f"at {GOT}" in res.timing.summary_line()
    assert f"The loop ran at {GOT}." in (res.run_dir / "report.md").read_text()

    sim = run_trial(prepare(load_trial_config(REPO / "hil_configs" / "sim_target1.yaml")), tmp_path / "sim")
    assert sim.timing.priority is None and _nice() == before


def test_a_paced_loop_is_never_held_up_by_a_full_collection_and_leaves_the_collector_as_it_found_it(tmp_path):
    """A full collection walks every object the process holds (~0.1 s with PyBullet and the scene
    loaded: nine missed deadlines at 100 Hz). During a paced loop what existed before it is frozen
    out of the collector's reach; after, the process's collector is as it was. (The emulated rig on
    the virtual clock: the same runner and driver as in real time, in this process.)"""
    import gc

    from bench.rig.emulated import VirtualRig, retarget
    from bench.trial.plan import prepare
    from bench.trial.run import TrialHooks, run_trial

    cfg = load_trial_config(LAB)
    seen: list[int] = []
    with VirtualRig(cfg) as rig:
        prep = prepare(retarget(cfg, rig.ports))
        assert gc.get_freeze_count() == 0
        res = run_trial(prep, tmp_path, TrialHooks(report=False, progress=lambda f: seen.append(gc.get_freeze_count())))
    assert res.completed
    assert seen and min(seen) > 10_000  # the modules, the scene and the backend: set aside for the loop
    assert gc.get_freeze_count() == 0
