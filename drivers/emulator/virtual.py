"""The emulated servo bus and ultrasonic sensor on a virtual clock, served as ``virtual://`` lines.

The same emulated devices as on a pty (the same instructions, control tables, firmware, faults
and physics), with the transport and the time source swapped: no serving thread and no pty. Each
is a device of a :class:`~drivers.clock.VirtualClock` and its work happens at exact instants:

* the bus: a physics step ends every ``physics_dt``; an instruction reaches the servos once its
  bytes have crossed the wire at the host's baud (after whatever was on the wire before it); its
  status packets follow after each servo's Return Delay Time and their own transfer time, one
  after the other, and reach the host's buffer at the instant their last byte arrives;
* the sensor: a reading every ``1 / rate_hz``, its line arriving ``len × 10 / baud`` later.

Nothing here reads the wall clock, and every random draw comes from the devices' seeded
generators, so a trial on these lines is the same bit for bit on any machine, however loaded.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Callable, Mapping

from drivers.clock import VirtualClock
from drivers.emulator.bus import DynamixelBusEmulator
from drivers.emulator.plant import Plant
from drivers.emulator.servo import ServoModel
from drivers.emulator.ultrasonic import UltrasonicEmulator
from drivers.virtual import VirtualLine, register, unregister

__all__ = ["VirtualBusEmulator", "VirtualUltrasonic"]

#: A packet's bytes cross the wire at 10 bits each (8N1).
_BITS_PER_BYTE = 10.0


class _OnClock:
    """Serving on a virtual clock: the line registered under its name and the device attached to
    the clock while it serves (the part of :class:`~drivers.emulator.service.PtyService` it replaces)."""

    clock: VirtualClock
    line: VirtualLine
    _closed: bool

    def start(self):
        if self._closed:
            raise RuntimeError(f"this emulated line {self.line.name!r} was stopped; create a new one")
        register(self.line)
        self.clock.attach(self)
        return self

    def stop(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.clock.detach(self)
        unregister(self.line)

    def _fds(self) -> tuple[int, ...]:
        return ()


class VirtualBusEmulator(_OnClock, DynamixelBusEmulator):
    """:class:`~drivers.emulator.bus.DynamixelBusEmulator` on ``clock``, served as ``virtual://NAME``.

    The wire-time model is always on (on a virtual clock, the wire is what takes time), and the
    physics never rests: it steps every ``physics_dt`` of the clock's time.
    """

    def __init__(self, servos: Mapping[int, ServoModel], plant: Plant | None = None, *,
                 clock: VirtualClock, name: str, **kwargs) -> None:
        self.clock = clock
        self._name = name
        kwargs.update(realtime=False, wire_timing=True, rest_after_s=None)
        self._instructions: deque[tuple[float, bytes]] = deque()  # reaching the servos
        self._replies: deque[tuple[float, bytes]] = deque()  # reaching the host
        super().__init__(servos, plant, **kwargs)
        self._origin = clock.now()
        self._steps = 0  # physics steps run since the origin: the physics' time is exact
        self._t = self._origin  # the instant of the bus's last piece of work
        self._wire_free = self._origin

    def _open_transport(self) -> None:
        self.line = VirtualLine(self.clock, self._name, self._host_sent)
        self._port = self.line.url

    def _bus_now(self) -> float:
        return self._t

    def host_baud(self) -> int | None:
        return self.line.host_baud

    def _host_sent(self, data: bytes, t: float) -> None:
        """The host wrote ``data`` at ``t``: it reaches the servos once it has crossed the wire."""
        with self.lock:
            if self._unplugged or not data:
                return
            baud = self.line.host_baud or 1_000_000
            arrival = max(t, self._wire_free) + len(data) * _BITS_PER_BYTE / baud
            self._wire_free = arrival
            self._instructions.append((arrival, data))

    def _next_step_end(self) -> float:
        return self._origin + (self._steps + 1) * self.physics_dt

    def next_due(self) -> float:
        due = self._next_step_end()
        if self._instructions and self._instructions[0][0] < due:
            due = self._instructions[0][0]
        if self._replies and self._replies[0][0] < due:
            due = self._replies[0][0]
        return due

    def run_until(self, limit: float) -> float:
        with self.lock:
            dt = self.physics_dt
            while True:
                step = self._next_step_end()
                instruction = self._instructions[0][0] if self._instructions else math.inf
                reply = self._replies[0][0] if self._replies else math.inf
                if min(step, instruction, reply) > limit:
                    return self._t
                if step <= instruction and step <= reply:  # a step ending at that instant runs first
                    last = min(limit, instruction, reply)
                    n = max(1, math.floor((last - self._origin) / dt + 1e-9) - self._steps)
                    self._physics(n)
                    self._steps += n
                    self._t = self._origin + self._steps * dt
                elif reply <= instruction:
                    self._t, packet = self._replies.popleft()
                    self.line.deliver(packet, self._t)
                    self.stats.status_sent += 1
                    return self._t  # bytes at the host: the clock looks again
                else:
                    self._t, data = self._instructions.popleft()
                    self._arrive(data, self._t)

    def _arrive(self, data: bytes, t: float) -> None:
        """An instruction's bytes have reached the servos at ``t``: execute, and schedule the answers."""
        if self._parser.pending and t - self._last_rx > self.frame_timeout_s:
            self._parser.reset()  # inter-byte timeout: the partial frame is dropped
        self._last_rx = t
        self._host_baud = self.line.host_baud
        for event in self._parser.feed(data):
            try:
                self._handle(event)
            except Exception as exc:  # keep the bus alive; the error is kept for inspection
                self.errors.append(exc)
                self._outbox.clear()
                continue
            start = max(t, self._wire_free)
            for delay, _, packet in self._outbox:
                start += delay
                self._replies.append((start, packet))
            self._wire_free = start
            self._outbox.clear()


class VirtualUltrasonic(_OnClock, UltrasonicEmulator):
    """:class:`~drivers.emulator.ultrasonic.UltrasonicEmulator` on ``clock``, served as ``virtual://NAME``:
    a reading every ``1 / rate_hz``, its line reaching the host after its transfer at ``baud``."""

    def __init__(self, distance_fn: Callable[[], float], *, clock: VirtualClock, name: str,
                 baud: int = 9600, **kwargs) -> None:
        self.clock = clock
        self._name = name
        self._byte_s = _BITS_PER_BYTE / baud
        self._lines: deque[tuple[float, bytes]] = deque()  # reaching the host
        super().__init__(distance_fn, **kwargs)
        self._origin = clock.now()
        self._readings = 0

    def _open_transport(self) -> None:
        self.line = VirtualLine(self.clock, self._name, lambda data, t: None)  # the sensor only talks
        self._port = self.line.url

    def _next_reading(self) -> float:
        return self._origin + (self._readings + 1) / self.rate_hz

    def next_due(self) -> float:
        due = self._next_reading()
        return self._lines[0][0] if self._lines and self._lines[0][0] < due else due

    def run_until(self, limit: float) -> float:
        reached = self.clock.now()
        while True:
            reading = self._next_reading()
            arrival = self._lines[0][0] if self._lines else math.inf
            if min(reading, arrival) > limit:
                return reached
            if arrival <= reading:
                reached, line = self._lines.popleft()
                self.line.deliver(line, reached)
                self.lines_sent += 1
                return reached
            self._readings += 1
            reached = reading
            if self._paused.is_set():
                continue
            line = self.measure()
            if self.dropout_prob and self.rng.random() < self.dropout_prob:
                self.lines_dropped += 1
                continue
            self._lines.append((reading + len(line) * self._byte_s, line))

    def inject_raw(self, data: bytes) -> None:
        """Put arbitrary bytes on the line now (line noise, a garbled reading)."""
        self.line.deliver(data)
