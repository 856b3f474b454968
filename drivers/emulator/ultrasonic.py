"""A MaxBotix HRLV-MaxSonar-EZ (MB1003/MB1013/MB1043 family) on a pseudo-terminal.

The real sensor free-runs and sends, at 9600 baud 8N1, one ASCII line per
reading: ``R`` + four digits of range in millimetres + carriage return, e.g.
``R0480\\r``. Its range is 300-5000 mm: a target closer than 300 mm reads
``R0300`` and no target reads ``R5000`` — the sensor clamps, it never sends
an out-of-range number. This emulator does the same from ``distance_fn``
(metres), with optional Gaussian noise, calibration error (``scale``,
``offset_m``) and dropouts (a line that is simply not sent).

Mounting on the needle-placement robot: the train's d2 travel (about
0.03-0.38 m) is below the sensor's 0.30 m minimum, so the sensor sits at a
fixed standoff behind the zero position and sees ``standoff + d2``
(:func:`standoff_distance`, default 0.30 m -> 0.33-0.68 m, inside the range
and in the sensor's accurate far field beyond 0.5 m for most of the travel).
"""

from __future__ import annotations

import os
import threading
import time
import tty
from typing import Callable

import numpy as np

from drivers.emulator.service import PtyService
from drivers.train_loop import sensor_millimetres
from drivers.ultrasonic import DEFAULT_STANDOFF_M

__all__ = ["DEFAULT_STANDOFF_M", "UltrasonicEmulator", "standoff_distance"]



def standoff_distance(
    d2_fn: Callable[[], float], standoff_m: float = DEFAULT_STANDOFF_M
) -> Callable[[], float]:
    """Distance the sensor sees (m) for a joint position function ``d2_fn`` (m)."""
    if standoff_m < 0:
        raise ValueError(f"standoff_m must be >= 0 m, got {standoff_m}")
    return lambda: standoff_m + float(d2_fn())


def format_reading(distance_m: float) -> bytes:
    """The line the sensor sends for a true distance, clamped like the sensor does."""
    return b"R%04d\r" % sensor_millimetres(distance_m)


class UltrasonicEmulator(PtyService):
    """Streams ``R####\\r`` lines at ``rate_hz`` on its own pty (:attr:`port`)."""

    def __init__(
        self,
        distance_fn: Callable[[], float],
        rate_hz: float = 20.0,
        noise_std_m: float = 0.0,
        dropout_prob: float = 0.0,
        seed: int = 0,
        offset_m: float = 0.0,
        scale: float = 1.0,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0 Hz, got {rate_hz}")
        if noise_std_m < 0:
            raise ValueError(f"noise_std_m must be >= 0 m, got {noise_std_m}")
        if not 0 <= dropout_prob <= 1:
            raise ValueError(f"dropout_prob must be in [0, 1], got {dropout_prob}")
        self.distance_fn = distance_fn
        self.rate_hz = float(rate_hz)
        self.noise_std_m = float(noise_std_m)
        self.dropout_prob = float(dropout_prob)
        self.offset_m = float(offset_m)
        self.scale = float(scale)
        self.rng = np.random.default_rng(seed)
        #: lines written / lines skipped as dropouts / bytes injected raw
        self.lines_sent = 0
        self.lines_dropped = 0
        self._paused = threading.Event()
        self._init_service()
        self._lock = threading.Lock()
        self._open_transport()

    def _open_transport(self) -> None:
        """The pty the host opens."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self._port = os.ttyname(self._slave)

    @property
    def port(self) -> str:
        return self._port

    thread_name = "ultrasonic-emulator"

    def pause(self) -> None:
        """Stop sending lines but keep the port open (a sensor that went quiet)."""
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def inject_raw(self, data: bytes) -> None:
        """Put arbitrary bytes on the line (line noise, a garbled reading)."""
        with self._lock:
            self._write(data)

    def measure(self) -> bytes:
        """One reading as the sensor would send it now."""
        distance = self.scale * float(self.distance_fn()) + self.offset_m
        if self.noise_std_m:
            distance += self.rng.normal(0.0, self.noise_std_m)
        return format_reading(distance)

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += period
            if not self._paused.is_set():
                line = self.measure()
                with self._lock:
                    if self.dropout_prob and self.rng.random() < self.dropout_prob:
                        self.lines_dropped += 1
                    elif self._write(line):
                        self.lines_sent += 1
            delay = next_t - time.monotonic()
            if delay < -period:  # fell far behind (suspended): do not burst
                next_t = time.monotonic()
                delay = 0.0
            self._stop.wait(max(0.0, delay))

    def _write(self, data: bytes) -> bool:
        try:
            return os.write(self._master, data) == len(data)
        except OSError:  # buffer full (nobody reading) or closed
            return False
