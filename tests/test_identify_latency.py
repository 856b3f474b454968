"""What identification takes from a log besides its readings: when each goal reached the servos
(the loop's latency, from the loop's timing) and which constant speeds the excitation held (what
friction it can tell). The end-to-end check, the true physics drawing the logged current of an
emulated rig at speed, is in tests/test_train_encoder.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.core.log import TrialLog
from bench.identify.coverage import speed_reasons, steady_speeds
from bench.identify.logs import LoggedRun, loop_latency
from bench.identify.simulate import merge_runs
from drivers.servo.model import FIRMWARE_PERIOD_S


def _timed_log(rows: int, read_s: float, bus_s: float) -> TrialLog:
    log = TrialLog(["theta3"], ["approach"])
    log.start_timing()
    for k in range(rows):
        start = 0.01 * k
        log.append(start + read_s, 0, [0], [0], [0], [0], [0])
        log.time_cycle(start, -0.005, bus_s)
    return log


def test_a_goal_lands_the_rest_of_its_bus_time_and_one_firmware_sample_after_its_reading():
    log = _timed_log(5, read_s=0.0004, bus_s=0.0009)
    t = log.time - log.time[0]
    sampled, applied = loop_latency(log, t)
    # the servos answered when the read went out; the goal followed the read on the bus
    np.testing.assert_allclose(sampled, t - 0.0004, atol=1e-12)
    np.testing.assert_allclose(applied, t + 0.0005 + FIRMWARE_PERIOD_S, atol=1e-12)
    assert np.all(applied - sampled == pytest.approx(0.0009 + FIRMWARE_PERIOD_S))


def test_a_log_without_the_loops_timing_is_read_at_its_rows_and_written_a_sample_later():
    log = TrialLog(["theta3"], ["approach"])
    for k in range(4):
        log.append(0.01 * k, 0, [0], [0], [0], [0], [0])
    t = log.time.copy()
    sampled, applied = loop_latency(log, t)
    np.testing.assert_array_equal(sampled, t)
    np.testing.assert_allclose(applied, t + FIRMWARE_PERIOD_S)


def test_untimed_rows_of_a_timed_log_take_the_median_latency():
    log = _timed_log(6, read_s=0.001, bus_s=0.003)
    log._timing["bus_s"][2] = np.nan  # a cycle whose timing was not recorded
    t = log.time - log.time[0]
    sampled, applied = loop_latency(log, t)
    assert applied[2] - t[2] == pytest.approx(0.002 + FIRMWARE_PERIOD_S)
    assert np.all(np.diff(applied) > 0)


def _goal_run(goal: np.ndarray, dt: float = 0.01, lag: tuple[float, float] | None = None) -> LoggedRun:
    n = len(goal)
    z = np.zeros((n, 1))
    t = np.arange(n) * dt
    sampled, applied = (None, None) if lag is None else (t - lag[0], t + lag[1])
    return LoggedRun(run_dir=Path("."), sha256="", time=t, goal=goal[:, None], q=z, qd=z, current=z,
                     inertia=z + 1, load=z, excited=np.ones(1, bool), sampled=sampled, applied=applied)


class _Setup:
    ratio = np.array([1.0])


def test_the_constant_speeds_an_excitation_held_are_found_and_a_brisk_chirp_holds_none():
    """(A slow sine does hold its peak speed long enough: its current there reads friction too.)"""
    dt = 0.01
    legs = [np.full(50, 0.1), np.zeros(20), np.full(40, -1.0), np.zeros(20), np.full(30, 0.5)]
    goal = np.concatenate([[0.0], np.cumsum(np.concatenate(legs)) * dt])
    speeds = steady_speeds(_Setup(), [_goal_run(goal)], 0)
    np.testing.assert_allclose(speeds, [0.1, 0.5, 1.0], rtol=0.02)
    t = np.arange(600) * dt
    chirp = 0.1 * np.sin(2 * np.pi * (1.0 * t + 0.15 * t ** 2))  # 1 to 2.8 Hz
    assert steady_speeds(_Setup(), [_goal_run(chirp)], 0).size == 0


def test_friction_values_the_speeds_cannot_tell_are_named_with_the_speeds_missing():
    told = {"stribeck_velocity_rads": 0.2}
    assert speed_reasons(told, np.array([0.1, 0.22, 0.52, 1.2])) == {}
    why = speed_reasons(told, np.array([0.085, 0.22]))
    assert set(why) == {"stribeck_velocity_rads", "coulomb_nm", "viscous_nms"}
    assert "no constant speed past twice it (0.2 rad/s)" in why["stribeck_velocity_rads"]
    assert "0.085, 0.22 rad/s" in why["coulomb_nm"]
    below = speed_reasons(told, np.array([0.3, 0.6, 1.5]))
    assert set(below) == {"stribeck_velocity_rads"} and "below it" in below["stribeck_velocity_rads"]
    # one constant speed past the fade tells Coulomb's level and the viscous slope only as a sum
    one = speed_reasons(told, np.array([0.1, 0.7]))
    assert set(one) == {"coulomb_nm", "viscous_nms"} and "told only with the viscous slope" in one["coulomb_nm"]
    assert "none" in speed_reasons(told, np.zeros(0))["viscous_nms"]


def test_merged_logs_keep_each_rows_latency():
    a, b = _goal_run(np.zeros(10), lag=(0.0004, 0.0015)), _goal_run(np.zeros(8))
    merged, _, slices = merge_runs([a, b])
    np.testing.assert_allclose(merged.applied[slices[0]] - merged.time[slices[0]], 0.0015)
    np.testing.assert_allclose(merged.applied[slices[1]] - merged.time[slices[1]], 0.0)
    np.testing.assert_allclose(merged.sampled[slices[0]] - merged.time[slices[0]], -0.0004)


def test_a_damaged_or_stalled_timing_puts_a_goal_off_by_a_bounded_time():
    log = _timed_log(5, read_s=0.0004, bus_s=0.0009)
    log._timing["bus_s"][2] = 1e9  # a hostile run directory's timing
    log._timing["loop_start"][3] = 1e9
    t = log.time - log.time[0]
    sampled, applied = loop_latency(log, t)
    assert np.all(applied - t <= 0.05 + FIRMWARE_PERIOD_S + 1e-12) and np.all(t - sampled <= 0.05)
