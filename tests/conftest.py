"""Shared fixtures: the arc-and-train model, a headless PyBullet world and a cold emulated rig;
and the order the test files start in."""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from typing import Iterator

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
# The commands print as into a pipe, whatever terminal started the suite: a width its tests
# ask for is the one they get (a console fixes COLUMNS, if exported, as it is created).
for _name in ("COLUMNS", "LINES"):
    os.environ.pop(_name, None)

#: Files whose ``alone`` tests are best started last: the one worker then waits for the other's
#: current test only (the shortest tests run last), not for a file of them.
ALONE_LAST = ("test_live.py",)

#: The longest test files (half a minute or more each), started first: the suite runs on three
#: workers, each file whole on one (README, the test command), and a long file started last
#: would leave one worker alone for its last minutes.
LONGEST_FIRST = ("test_servo_model.py", "test_compare.py", "test_identify.py", "test_identify_worn.py", "test_stop_unconfirmed.py",
                 "test_lab_tools.py", "test_signals.py", "test_cli_hostile_bus.py", "test_campaign.py")


def pytest_configure(config) -> None:
    config.addinivalue_line(
        "markers", "alone: measures the control loop's deadlines, so no other test runs beside it "
        "(the suite's other worker waits; see room())")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    last = len(rank) + 1
    items.sort(key=lambda item: last if item.path.name in ALONE_LAST else rank.get(item.path.name, len(rank)))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem):  # noqa: ARG001
    with room(item.config, alone=item.get_closest_marker("alone") is not None):
        yield


@contextlib.contextmanager
def room(config, alone: bool) -> Iterator[None]:
    """Under pytest-xdist, an ``alone`` test runs with no other test beside it; other tests share.

    Every test holds the room shared, from its setup to its teardown (a module's fixtures set up
    and torn down within one test's); an ``alone`` test holds it exclusively. The turnstile, held
    while a test waits for the room, lets an ``alone`` test in as soon as the test before it ends:
    the other worker's next test waits behind it rather than keeping the room busy for ever.
    """
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    shared = config._tmp_path_factory.getbasetemp().parent  # the run's: each worker's basetemp is under it
    with open(shared / "turnstile.lock", "a") as turnstile, open(shared / "room.lock", "a") as lock:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(lock, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(turnstile, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def pytest_terminal_summary(terminalreporter) -> None:
    """Under .ci/run, the run's time from a fresh clone: the figure the docs quote is this line."""
    import time

    started, installed = os.environ.get("CI_STARTED_AT"), os.environ.get("CI_INSTALLED_AT")
    if not (started and installed and started.isdigit() and installed.isdigit()):
        return
    now = time.time()
    checks = int(installed) - int(started)
    terminalreporter.write_line(
        f"ci time: {now - int(started):.0f} s in all (install {checks} s, tests {now - int(installed):.0f} s, "
        f"the wheel and docs checks beside them) on {os.cpu_count()} cores")


@pytest.fixture(scope="session")
def arc_train():
    from bench.kinematics.arc_train import ArcTrainRobot

    return ArcTrainRobot()


@pytest.fixture
def cold_rig():
    """The lab's emulated rig with its servos powering up torque off, and the config pointed at it."""
    from bench.config.models import load_trial_config  # the rig's fixtures only
    from bench.paths import REPO_ROOT
    from bench.rig.emulated import EmulatedRig

    cfg = load_trial_config(REPO_ROOT / "hil_configs" / "lab_real.yaml")
    cfg = cfg.model_copy(update={"emulator": cfg.emulator.model_copy(update={"start_torque_on": False})})
    with EmulatedRig(cfg) as r:  # real ptys: registers --watch reads it from another process
        yield r, r.retarget(cfg)


@pytest.fixture
def timed_journal(tmp_path):
    """A live view following ``tmp_path`` and a timed trial log journaling into a run there, with the
    sim config's joints: (follower, log). Rows appended and flushed are what the page is sent."""
    from bench.config.models import load_trial_config
    from bench.core.log import TrialLog
    from bench.live.follow import RunFollower
    from bench.paths import REPO_ROOT
    from bench.trial.plan import prepare

    prep = prepare(load_trial_config(REPO_ROOT / "hil_configs" / "sim_target1.yaml"))
    follower = RunFollower(tmp_path, lambda: prep)
    run = tmp_path / "20260101-000000-t"
    run.mkdir()
    log = TrialLog(list(prep.robot.joint_names), ["approach"], metadata={"control_period": 0.01})
    log.journal_to(run)
    log.start_timing()
    return follower, log


def assert_block_equals_cycles(one, block, q, qd, period: float, chunk: int):
    """Run the plan ``q``, ``qd`` on ``one`` cycle by cycle (read, command, wait) and on ``block`` in
    blocks of ``chunk`` cycles: every reading, field by field, and the clock are the same bit for bit.
    Returns the readings cycle by cycle (time, position, velocity, effort) and each cycle's end."""
    import numpy as np

    k = len(q)
    ends = np.add.accumulate(np.concatenate([[0.0], np.full(k, period)]))[1:]
    rows, t = [], one.now()
    for i in range(k):
        st = one.read()
        rows.append((st.time, st.position, st.velocity, st.effort))
        one.command(q[i], qd[i])
        t += period
        one.wait_until(t)
    got = [block.execute_block(q[a:a + chunk], qd[a:a + chunk], ends[a:a + chunk]) for a in range(0, k, chunk)]
    assert one.now() == block.now()
    for field, col in (("time", 0), ("position", 1), ("velocity", 2), ("effort", 3)):
        expected = np.array([r[col] for r in rows])
        assert np.array_equal(np.concatenate([getattr(g, field) for g in got]), expected), field
    return rows, ends


@pytest.fixture(scope="session")
def block_equals_cycles():
    """:func:`assert_block_equals_cycles`, for the backends' block-execution tests."""
    return assert_block_equals_cycles
