"""Emulated serial lines on a virtual clock, opened by URL (``virtual://NAME``) like any port.

A :class:`VirtualLine` is both ends of one line: the emulated device (a servo bus, a sensor)
holds one end and registers the line under its name while it serves; the driver opens
``virtual://NAME`` through pyserial (:func:`drivers.link.open_port`), which finds the handler in
:mod:`drivers.virtual.protocol_virtual`. What the host writes reaches the device at the clock's
instant; what the device sends reaches the host's buffer when the device's own work on the clock
says it has crossed the wire. No thread and no file descriptor is involved: a waiting host
advances the clock.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Callable, Optional

from drivers.clock import VirtualClock

__all__ = ["VirtualLine", "line_named", "register", "unregister"]

_LOCK = threading.Lock()
_LINES: dict[str, "VirtualLine"] = {}


class VirtualLine:
    """One serial line between a host and an emulated device, on ``clock``.

    ``receive(data, t)``: the device's end, told of the host's bytes as they are written at
    clock time ``t``. The device puts its answers on the line with :meth:`deliver` when they
    have arrived. ``host_baud``: the speed the host set (None until it opens the port).
    """

    def __init__(self, clock: VirtualClock, name: str,
                 receive: Callable[[bytes, float], None]) -> None:
        self.clock = clock
        self.name = name
        self.receive = receive
        self.host_baud: Optional[int] = None
        #: The host's end while a host has the port open (None: bytes sent now are lost).
        self.host: Optional[object] = None
        #: Bytes that reached the host and wait to be read, each chunk with its arrival time.
        self.to_host: deque[tuple[float, bytes]] = deque()
        #: Bytes delivered while no host had the port open, which nothing read (as on a real line).
        self.lost_bytes = 0

    @property
    def url(self) -> str:
        return f"virtual://{self.name}"

    def deliver(self, data: bytes, at: float | None = None) -> None:
        """The device's bytes have crossed the wire at ``at``: the device's own instant, which the
        clock only reads once the device's work returns (default: the clock's instant, for bytes put
        on the line from outside a device's work)."""
        if not data:
            return
        if self.host is None:
            self.lost_bytes += len(data)
            return
        self.to_host.append((self.clock.now() if at is None else at, bytes(data)))

    def pending(self) -> int:
        return sum(len(chunk) for _, chunk in self.to_host)


def register(line: VirtualLine) -> None:
    """Serve ``line`` under its name (a second line of that name is refused)."""
    with _LOCK:
        if line.name in _LINES and _LINES[line.name] is not line:
            raise ValueError(f"an emulated line named {line.name!r} is already served")
        _LINES[line.name] = line


def unregister(line: VirtualLine) -> None:
    with _LOCK:
        if _LINES.get(line.name) is line:
            del _LINES[line.name]


def line_named(name: str) -> Optional[VirtualLine]:
    with _LOCK:
        return _LINES.get(name)
