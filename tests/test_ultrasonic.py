"""The HR-MaxSonar emulator and the host-side UltrasonicSensor reader, over a pty."""

from __future__ import annotations

import threading
import time

import pytest

from drivers import CommunicationError
from drivers.clock import VirtualClock
from drivers.emulator.ultrasonic import UltrasonicEmulator, format_reading, standoff_distance
from drivers.emulator.virtual import VirtualUltrasonic
from drivers.ultrasonic import DEFAULT_STANDOFF_M, StaleReadingError, UltrasonicSensor

pytestmark = pytest.mark.timeout(30)


def wait_for(condition, timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def test_format_reading_clamps_like_the_sensor() -> None:
    assert format_reading(0.48) == b"R0480\r"
    assert format_reading(0.1) == b"R0300\r"  # closer than 300 mm reads 300
    assert format_reading(7.5) == b"R5000\r"  # nothing in range reads 5000
    assert format_reading(float("nan")) == b"R5000\r"


def test_d2_travel_maps_into_the_sensor_range() -> None:
    for d2 in (0.03, 0.2, 0.38):
        distance = standoff_distance(lambda d2=d2: d2)()
        assert 0.3 < distance < 5.0
        assert distance == pytest.approx(DEFAULT_STANDOFF_M + d2)


def test_reader_tracks_the_emulated_distance_within_noise() -> None:
    d2 = {"value": 0.12}
    with UltrasonicEmulator(standoff_distance(lambda: d2["value"]), rate_hz=50, noise_std_m=0.002, seed=3) as emu:
        with UltrasonicSensor(emu.port, median_window=5, expected_rate_hz=50) as sensor:
            assert wait_for(lambda: sensor.counters.readings >= 5)
            distance, age = sensor.read()
            assert distance == pytest.approx(0.42, abs=0.006)
            assert 0.0 <= age < 0.1
            d2["value"] = 0.30
            assert wait_for(lambda: abs(sensor.read()[0] - 0.60) < 0.006)
            assert sensor.counters.parse_errors == 0 and sensor.counters.out_of_range == 0


def test_reader_counts_dropouts_against_the_expected_rate() -> None:
    """On the virtual clock: a dropout is a gap in the lines' timing, which a loaded machine's late
    reader thread would stretch; on the clock each line arrives when the sensor sent it, so the count
    is exact."""
    clock = VirtualClock()
    emu = VirtualUltrasonic(lambda: 1.0, clock=clock, name="dropouts", rate_hz=50, dropout_prob=0.3,
                            seed=11).start()
    try:
        with UltrasonicSensor(emu.port, expected_rate_hz=50, stale_after_s=1.0) as sensor:
            sensor.wait_for_reading()  # the clock stops as the first line arrives: nothing lost since
            dropped_before, counted_before = emu.lines_dropped, sensor.counters.dropouts
            clock.sleep(2.0)
            # the window closes on a line that arrives, so every line lost before it is noticed
            emu.dropout_prob = 0.0
            seen = sensor.counters.readings
            assert clock.advance(clock.now() + 1.0, until=lambda: sensor.counters.readings > seen)
            dropped = emu.lines_dropped - dropped_before
            counted = sensor.counters.dropouts - counted_before
    finally:
        emu.stop()
    assert 20 <= dropped <= 40  # ~30 % of 100 lines
    assert counted == dropped


def test_reader_reports_staleness_when_the_emulator_stops() -> None:
    emu = UltrasonicEmulator(lambda: 0.5, rate_hz=40)
    emu.pause()
    emu.start()
    sensor = UltrasonicSensor(emu.port, stale_after_s=0.15, expected_rate_hz=40)
    try:
        with pytest.raises(StaleReadingError, match="no reading"):
            sensor.read()
        emu.resume()
        assert wait_for(lambda: not sensor.is_stale)
        emu.pause()
        assert wait_for(lambda: sensor.is_stale, timeout=1.0)
        with pytest.raises(StaleReadingError, match="old"):
            sensor.read()
        distance, age = sensor.read(allow_stale=True)
        assert distance == pytest.approx(0.5) and age > 0.15
        emu.resume()
        assert wait_for(lambda: not sensor.is_stale)
        emu.stop()  # the port disappears: stale again, and the reader survives it
        assert wait_for(lambda: sensor.is_stale, timeout=1.0)
        assert isinstance(StaleReadingError("x"), CommunicationError)
    finally:
        sensor.close()
        emu.stop()
    assert not sensor._thread.is_alive()


def test_wait_for_reading_returns_with_the_first_line_or_raises_after_its_timeout() -> None:
    emu = UltrasonicEmulator(lambda: 0.5, rate_hz=20)
    emu.pause()
    emu.start()
    try:
        with UltrasonicSensor(emu.port, expected_rate_hz=20) as sensor:
            t0 = time.monotonic()
            with pytest.raises(StaleReadingError, match=r"no reading within 0\.25 s"):
                sensor.wait_for_reading()  # stale after 3 periods + 50 ms, plus one period
            assert 0.24 < time.monotonic() - t0 < 1.0
            emu.resume()
            sensor.wait_for_reading()
            distance, age = sensor.read()
            assert distance == pytest.approx(0.5) and age < 0.2
    finally:
        emu.stop()


def test_reader_counts_parse_errors_and_out_of_range() -> None:
    with UltrasonicEmulator(lambda: 0.8, rate_hz=50) as emu:
        with UltrasonicSensor(emu.port, range_m=(0.3, 0.7), expected_rate_hz=50) as sensor:
            assert wait_for(lambda: sensor.counters.out_of_range >= 3)
            assert sensor.counters.readings == 0  # 0.8 m is outside this reader's range
            emu.inject_raw(b"R12x4\r")
            emu.inject_raw(b"\x00garbage\r")
            assert wait_for(lambda: sensor.counters.parse_errors >= 2)
        # The sensor saturates at its limits: 0.3 m is a valid, but saturated, reading.
    with UltrasonicEmulator(lambda: 0.05, rate_hz=50) as emu:
        with UltrasonicSensor(emu.port, expected_rate_hz=50) as sensor:
            assert wait_for(lambda: sensor.counters.saturated >= 2)
            assert sensor.read()[0] == pytest.approx(0.3)


def test_close_is_clean_and_idempotent() -> None:
    before = threading.active_count()
    with UltrasonicEmulator(lambda: 1.0) as emu:
        sensor = UltrasonicSensor(emu.port)
        sensor.close()
        sensor.close()
    assert wait_for(lambda: threading.active_count() <= before)
    with pytest.raises(CommunicationError, match="cannot open"):
        UltrasonicSensor("/dev/does-not-exist")


class _Pty:
    """A raw pseudo-terminal peer that writes exactly the bytes a test gives it."""

    def __init__(self) -> None:
        import os
        import tty

        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave

    def send(self, data: bytes) -> None:
        import os

        os.write(self.master, data)

    def close(self) -> None:
        import os

        os.close(self.master)
        os.close(self._slave)


def _lines(pty: _Pty, lines: list[bytes], rate_hz: float) -> None:
    for line in lines:
        pty.send(line)
        time.sleep(1.0 / rate_hz)


def test_no_target_codes_never_reach_the_filter() -> None:
    """Three R5000 in a window of five would put the train beyond its arc if taken as 5 m."""
    pty = _Pty()
    try:
        with UltrasonicSensor(pty.port, median_window=5, expected_rate_hz=50) as sensor:
            _lines(pty, [b"R0480\r", b"R0481\r", b"R5000\r", b"R5000\r", b"R5000\r", b"R0482\r"], 50)
            assert wait_for(lambda: sensor.counters.readings == 3 and sensor.counters.no_target == 3)
            distance, _ = sensor.read()
            assert distance == pytest.approx(0.481)
            assert sensor.counters.out_of_range == 0 and sensor.counters.saturated == 0
        with UltrasonicSensor(pty.port, expected_rate_hz=50, no_target_m=9.999,
                              range_m=(0.3, 9.999)) as wide:  # a 10 m model's code
            _lines(pty, [b"R6000\r", b"R9999\r"], 50)
            assert wait_for(lambda: wide.counters.readings == 1 and wide.counters.no_target == 1)
            assert wide.read()[0] == pytest.approx(6.0)
    finally:
        pty.close()


@pytest.mark.parametrize("rate_hz", [6.0, 10.0, 20.0])
def test_dropouts_are_counted_against_the_nominal_rate(rate_hz: float) -> None:
    """Twelve lines on time count no dropout; three silent periods, then a line on time, count three.
    On the virtual clock: a line's gap is the sensor's, never a late reader thread's."""
    clock = VirtualClock()
    emu = VirtualUltrasonic(lambda: 0.5, clock=clock, name=f"nominal-{rate_hz}", rate_hz=rate_hz).start()
    try:
        with UltrasonicSensor(emu.port, expected_rate_hz=rate_hz, stale_after_s=5.0) as sensor:
            sensor.wait_for_reading()
            assert clock.advance(clock.now() + 2.0, until=lambda: sensor.counters.readings == 12)
            assert sensor.counters.dropouts == 0
            emu.pause()  # three lines missing, then the next on time
            clock.sleep(3.0 / rate_hz)
            emu.resume()
            assert clock.advance(clock.now() + 2.0 / rate_hz, until=lambda: sensor.counters.readings == 13)
            assert sensor.counters.dropouts == 3
    finally:
        emu.stop()


def test_staleness_follows_the_nominal_rate() -> None:
    """At 6 Hz one missed line is not stale; three periods without a reading are (on the virtual
    clock, where the time between two reads is the one the test says)."""
    clock = VirtualClock()
    emu = VirtualUltrasonic(lambda: 0.5, clock=clock, name="stale-6hz", rate_hz=6.0).start()
    try:
        with UltrasonicSensor(emu.port, expected_rate_hz=6.0) as sensor:
            assert sensor.stale_after_s == pytest.approx(3 / 6 + 0.05)
            sensor.wait_for_reading()
            emu.pause()
            clock.sleep(2 / 6)  # one line missed
            assert sensor.read()[0] == pytest.approx(0.5)
            clock.sleep(0.3)
            with pytest.raises(StaleReadingError, match="stale after 0.550 s"):
                sensor.read()
    finally:
        emu.stop()


def test_garbage_without_cr_does_not_swallow_the_next_line() -> None:
    pty = _Pty()
    try:
        with UltrasonicSensor(pty.port, expected_rate_hz=50) as sensor:
            pty.send(b"R0400\r")
            assert wait_for(lambda: sensor.counters.readings == 1)
            pty.send(b"\x00\x17zz#R0421\r")  # noise, then a good line
            assert wait_for(lambda: sensor.counters.readings == 2)
            assert sensor.read()[0] == pytest.approx(0.4105)  # median of 0.400 and 0.421
            pty.send(b"x" * 100 + b"R0422\r")  # a burst longer than any line, then a good one
            assert wait_for(lambda: sensor.counters.readings == 3)
            pty.send(b"R04230000000000000000\r")  # an overlong line is dropped
            time.sleep(0.1)
            assert sensor.counters.readings == 3
            assert sensor.counters.parse_errors >= 3
    finally:
        pty.close()
