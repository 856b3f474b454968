"""Host-side reader for a MaxBotix HR-MaxSonar ultrasonic range finder (``R####\\r`` lines).

The HRXL-MaxSonar-WR family free-runs at about 6 Hz (the default nominal rate)
and reports millimetres from 300 to 5000 (9999 on the 10 m models): a target
closer than 300 mm reads ``R0300`` (kept, counted as saturated) and no echo at
all reads the range's top code, ``R5000`` — counted as *no target* and never
fed to the filter, since it says nothing about where the train is.

The sensor free-runs, so a background thread drains the serial port and
keeps the latest readings (on an emulated line on a virtual clock there is no
thread: each call takes what has arrived by the clock's time, stamped with
when it arrived, so the readings are those a thread would have kept); :meth:`UltrasonicSensor.read` returns the median
of the last few in metres together with the age of the newest one, and
refuses (:class:`StaleReadingError`) once the stream has been silent longer
than ``stale_after_s``. Counters say how healthy the stream is: lines missed
against the expected rate, lines that did not parse, readings outside the
configured range.

On the needle robot the sensor looks along the train's axis from a fixed
standoff (``DEFAULT_STANDOFF_M``), so ``d2 = distance - standoff``; see
:mod:`drivers.emulator.ultrasonic`.
"""

from __future__ import annotations

import math
import os
import re
import select
import statistics
import threading
from collections import deque
from dataclasses import dataclass

import serial

from drivers import CommunicationError, BackendSetupError
from drivers.link import link_of, open_port
from drivers.errors import StaleReadingError

__all__ = [
    "DEFAULT_RATE_HZ",
    "DEFAULT_STANDOFF_M",
    "StaleReadingError",
    "UltrasonicCounters",
    "UltrasonicSensor",
]

DEFAULT_STANDOFF_M = 0.30
#: HRXL-MaxSonar-WR free-run rate (Hz).
DEFAULT_RATE_HZ = 6.0
#: Periods without a reading before the stream counts as stale (one missed line is not).
STALE_PERIODS = 3.0
_LINE = re.compile(rb"R(\d{4})")
_MAX_LINE = 16  # 'R####' plus slack: anything longer without a CR is garbage


def stale_after(rate_hz: float) -> float:
    """The default staleness timeout for a sensor reading at ``rate_hz`` (s)."""
    return STALE_PERIODS / rate_hz + 0.05


@dataclass
class UltrasonicCounters:
    """Stream health since the sensor was opened."""

    readings: int = 0  # lines accepted into the filter
    dropouts: int = 0  # lines missing against the expected rate
    parse_errors: int = 0  # lines that are not R####, and garbage skipped before an R
    out_of_range: int = 0  # well-formed readings outside range_m, discarded
    saturated: int = 0  # readings at the range's floor (target too close)
    no_target: int = 0  # the no-echo code (R5000 / R9999), discarded


class UltrasonicSensor:
    """Background reader: ``with UltrasonicSensor(port) as s: distance, age = s.read()``.

    ``expected_rate_hz`` is the sensor's nominal rate, used to count missing
    lines (a gap of ``k`` periods means ``k - 1`` dropouts) and, unless
    ``stale_after_s`` is given, for staleness: :data:`STALE_PERIODS` periods
    without a reading. ``no_target_m`` is the code the sensor sends for no echo.
    """

    def __init__(
        self,
        port: str,
        baud: int = 9600,
        median_window: int = 5,
        stale_after_s: float | None = None,
        range_m: tuple[float, float] = (0.3, 5.0),
        expected_rate_hz: float = DEFAULT_RATE_HZ,
        no_target_m: float = 5.0,
    ) -> None:
        if not expected_rate_hz > 0:
            raise BackendSetupError(f"expected_rate_hz must be > 0 Hz, got {expected_rate_hz}")
        if stale_after_s is None:
            stale_after_s = stale_after(expected_rate_hz)
        if median_window < 1:
            raise BackendSetupError(f"median_window must be >= 1, got {median_window}")
        if stale_after_s <= 0:
            raise BackendSetupError(f"stale_after_s must be > 0 s, got {stale_after_s}")
        if not 0 <= range_m[0] < range_m[1]:
            raise BackendSetupError(f"range_m must be (low, high) with 0 <= low < high, got {range_m}")
        self.port = port
        self.no_target_m = float(no_target_m)
        self.stale_after_s = float(stale_after_s)
        self.range_m = (float(range_m[0]), float(range_m[1]))
        self.expected_rate_hz = float(expected_rate_hz)
        self._counters = UltrasonicCounters()
        self._window: deque[float] = deque(maxlen=median_window)
        self._last_line_time: float | None = None  # any well-formed line (rate bookkeeping)
        self._last_time: float | None = None  # newest reading accepted into the filter
        self._lock = threading.Lock()
        self._first_reading = threading.Event()
        self._stop = threading.Event()
        self._closed = False
        try:
            self._serial = open_port(port, baud)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise CommunicationError(f"cannot open ultrasonic sensor port {port!r}: {exc}") from exc
        self._serial.reset_input_buffer()
        self._link = link_of(self._serial, "ultrasonic")
        self.clock = self._link.clock
        self._pending = bytearray()
        self._synced = False  # the first bytes may be the tail of a line sent before we opened
        self._thread: threading.Thread | None = None
        self._wake_r = self._wake_w = -1
        if not self.clock.virtual:  # a virtual line is taken from at each call instead
            self._wake_r, self._wake_w = os.pipe()
            self._thread = threading.Thread(target=self._run, name=f"ultrasonic:{port}", daemon=True)
            self._thread.start()

    # -- public API -----------------------------------------------------------------
    def read(self, *, allow_stale: bool = False) -> tuple[float, float]:
        """(median distance in m, age of the newest reading in s).

        Raises :class:`StaleReadingError` when there is no reading yet or the
        newest is older than ``stale_after_s`` — unless ``allow_stale``, which
        returns the last value anyway (``nan`` if there never was one).
        """
        self._take_arrived()
        with self._lock:
            if not self._window:
                if allow_stale:
                    return float("nan"), float("inf")
                raise StaleReadingError(f"ultrasonic sensor on {self.port}: no reading received yet")
            distance = statistics.median(self._window)
            age = self.clock.now() - (self._last_time or 0.0)
        if age > self.stale_after_s and not allow_stale:
            raise StaleReadingError(
                f"ultrasonic sensor on {self.port}: newest reading is {age:.3f} s old "
                f"(stale after {self.stale_after_s:.3f} s)"
            )
        return distance, age

    def wait_for_reading(self, timeout_s: float | None = None) -> None:
        """Block until the first reading is in the filter, so a trial never starts blind.

        Waits up to ``timeout_s`` (default: the staleness timeout plus one period, room
        for the partial line dropped on opening); raises :class:`StaleReadingError` after.
        """
        if timeout_s is None:
            timeout_s = self.stale_after_s + 1.0 / self.expected_rate_hz
        if self._thread is None:  # a virtual line: the clock runs until a reading, or the timeout
            deadline = self.clock.now() + timeout_s
            while not self._first_reading.is_set() and self._link.wait(deadline):
                self._take_arrived()
            self._take_arrived()
        if not self._first_reading.wait(timeout_s if self._thread is not None else 0):
            raise StaleReadingError(
                f"ultrasonic sensor on {self.port}: no reading within {timeout_s:.2f} s of opening "
                f"it (expected {self.expected_rate_hz:g} Hz); is it connected and powered?")

    @property
    def counters(self) -> UltrasonicCounters:
        """Stream health since the sensor was opened (what has arrived so far counted)."""
        self._take_arrived()
        return self._counters

    @property
    def is_stale(self) -> bool:
        self._take_arrived()
        with self._lock:
            if self._last_time is None:
                return True
            return self.clock.now() - self._last_time > self.stale_after_s

    def close(self) -> None:
        """Stop the reader thread and close the port; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            try:
                os.write(self._wake_w, b"x")
            except OSError:
                pass
            self._thread.join(timeout=2.0)
            for fd in (self._wake_r, self._wake_w):
                os.close(fd)
        self._serial.close()

    def __enter__(self) -> "UltrasonicSensor":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading the line ----------------------------------------------------------------
    def _run(self) -> None:
        """The reader thread of a real port: sleeps in the kernel until bytes or the wake pipe."""
        fd = self._serial.fileno()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([fd, self._wake_r], [], [], 0.5)
            except (OSError, ValueError):
                return
            if self._wake_r in ready or fd not in ready:
                continue
            try:
                chunk = os.read(fd, 256)
            except BlockingIOError:
                continue
            except OSError:
                # The device went away (e.g. emulator stopped): readings go stale.
                self._stop.wait(0.05)
                continue
            if not chunk:
                self._stop.wait(0.05)
                continue
            self._feed(chunk, self.clock.now())

    def _take_arrived(self) -> None:
        """On a virtual line (no thread): feed what has arrived, each chunk at its arrival time."""
        if self._thread is None and not self._closed:
            for at, chunk in self._link.take_timed():
                self._feed(chunk, at)

    def _feed(self, chunk: bytes, now: float) -> None:
        """Bytes that arrived at ``now``: each complete line parsed and accepted."""
        pending = self._pending
        pending += chunk
        while b"\r" in pending:
            line, _, rest = bytes(pending).partition(b"\r")
            pending[:] = rest
            if not self._synced:
                self._synced = True
                if not line.startswith(b"R"):
                    continue
            self._accept(self._resync(line.strip()), now)
        if len(pending) > _MAX_LINE:  # no CR for far too long: keep only a last 'R...'
            start = pending.rfind(b"R")
            with self._lock:
                self._counters.parse_errors += 1
            del pending[: start if start > 0 else len(pending)]
            if len(pending) > _MAX_LINE:
                pending.clear()

    def _resync(self, line: bytes) -> bytes:
        """A line starts at its last 'R': garbage before it is counted once and dropped."""
        start = line.rfind(b"R")
        if start > 0:
            with self._lock:
                self._counters.parse_errors += 1
            return line[start:]
        return line

    def _accept(self, line: bytes, now: float) -> None:
        match = _LINE.fullmatch(line)
        with self._lock:
            if match is None:
                self._counters.parse_errors += 1
                return
            distance = int(match.group(1)) / 1000.0
            if self._last_line_time is not None:
                # A gap of k periods means k - 1 missing lines; the +0.25 keeps a
                # late line (gap ~1.5 periods) from counting as a dropout.
                periods = math.floor((now - self._last_line_time) * self.expected_rate_hz + 0.25)
                self._counters.dropouts += max(0, periods - 1)
            self._last_line_time = now
            if distance >= self.no_target_m:
                self._counters.no_target += 1
                return
            low, high = self.range_m
            if not low <= distance <= high:
                self._counters.out_of_range += 1
                return
            if distance == low:
                self._counters.saturated += 1
            self._counters.readings += 1
            self._window.append(distance)
            self._last_time = now
        self._first_reading.set()
