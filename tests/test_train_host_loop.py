"""The train's host loop on the emulated rig (the Dynamixel backend over the emulator's ptys) steers
by what the bench saw: a status the bench lost is stale to the loop, which then holds; the driver's
own reading stays its own, whatever a fault makes of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.config.models import load_trial_config
from bench.faults.comms import DroppedStatus
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_dynamixel_backend
from bench.rig.emulated import EmulatedRig
from drivers.clock import VirtualClock

LAB = Path(__file__).resolve().parent.parent / "hil_configs" / "lab_real.yaml"
PERIOD = 0.02  # s, a lab loop's period
CYCLES = 25


@pytest.fixture(scope="module")
def rig():
    cfg = load_trial_config(LAB)
    with EmulatedRig(cfg, clock=VirtualClock()) as r:
        yield r.retarget(cfg)


def _steer(cfg, prob: float):
    """Command the train 0.02 rad off where it reads, for CYCLES periods, through DroppedStatus on it.

    Returns what the host loop was told each cycle (``valid``), its correction at the end, the
    readings the bench got and the driver's own reading after each."""
    backend = make_dynamixel_backend(cfg, get_robot(cfg.robot))
    train = list(backend.joint_names).index("train")
    seen: list[bool] = []
    loop = backend._train_loop
    steer = loop.goal

    def watched(q, sensed, now, valid=True):  # the loop itself runs unchanged; we note what it is told
        seen.append(valid)
        return steer(q, sensed, now, valid)

    loop.goal = watched
    act = DroppedStatus(backend, np.array([train]), prob, np.random.default_rng(0))
    readings, own = [], []
    with act:
        first = act.read()  # the wrapper's first reading passes: there is nothing older to hold
        act.enable()
        goal = first.position.copy()
        goal[train] = np.clip(goal[train] + 0.02, act.limits.lower[train], act.limits.upper[train])
        t = act.now()
        for _ in range(CYCLES):
            st = act.read()
            readings.append(st)
            own.append(backend._last)
            act.command(goal, np.zeros_like(goal))
            t += PERIOD
            act.wait_until(t)
        correction = loop.correction
    return seen, correction, readings, own, train


def test_a_dropped_train_status_is_stale_to_the_host_loop_which_holds(rig):
    seen, correction, readings, own, train = _steer(rig, prob=1.0)
    assert all("stale:train" in st.flags for st in readings)
    assert len(seen) == CYCLES and not any(seen)  # the loop was told, every cycle, not to trust it
    assert correction == 0.0  # and so it held: no correction built on a value the bench saw as stale
    for st, mine in zip(readings, own):  # the driver's reading is its own: fresh, unflagged, unedited
        assert mine is not st and "stale:train" not in mine.flags
        assert not mine.position.flags.writeable


def test_without_drops_the_same_commands_move_the_host_loop(rig):
    """The control: the loop is told its readings are valid and corrects towards the goal."""
    seen, correction, readings, own, train = _steer(rig, prob=0.0)
    assert not any("stale:train" in st.flags for st in readings)
    assert len(seen) == CYCLES and all(seen)
    assert correction > 1e-4  # 0.5/s · ~0.02 rad · 0.5 s ≈ 5e-3 rad, less as the train closes in
    assert all(mine is st for st, mine in zip(readings, own))  # nothing dropped: the same reading
