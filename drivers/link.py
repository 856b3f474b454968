"""A serial port's bytes as the drivers use them, whatever carries them.

A driver opens its port by name with :func:`open_port`, as pyserial opens any URL: a device path
(``/dev/ttyUSB0``) is a real port, ``virtual://NAME`` an emulated line of this process on a
virtual clock (:mod:`drivers.virtual`). Either way the driver gets a pyserial object and its
:class:`Link`: the same calls (send, take what arrived, wait until bytes arrive or a deadline,
let the line fall quiet) and the :class:`~drivers.clock.Clock` its deadlines are on. A real
port's link works on the file descriptor (the kernel's ``select``, no polling) and the wall
clock; a virtual line's waits advance its virtual clock. The packets, parsers, retries and
safe stops above are the same code for both.
"""

from __future__ import annotations

import contextlib
import os
import select
import time
from typing import Iterator, Optional, Protocol, runtime_checkable

import serial

from drivers.clock import WALL, Clock
from drivers.virtual import line_named
from drivers.wirecapture import CapturedLink, WireCapture

__all__ = ["FdLink", "Link", "VIRTUAL_SCHEME", "capturing", "drain_until_quiet", "is_virtual_port", "link_of",
           "open_port", "port_usable", "virtual_port_served"]

#: The URL scheme of an emulated line on a virtual clock (``virtual://NAME``).
VIRTUAL_SCHEME = "virtual://"
# pyserial finds the handler of ``virtual://`` as drivers.virtual.protocol_virtual
if "drivers.virtual" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("drivers.virtual")


@runtime_checkable
class Link(Protocol):
    """What a driver does with a port's bytes; deadlines on :attr:`clock`."""

    clock: Clock

    def send(self, data: bytes) -> None:
        """Put every byte on the line (raises ``OSError`` when the port is gone)."""
        ...

    def take(self, size: int) -> bytes:
        """Up to ``size`` bytes already arrived, without waiting (b"" for none; ``OSError`` when the
        device went away)."""
        ...

    def take_timed(self) -> list[tuple[float, bytes]]:
        """Everything already arrived, in chunks stamped with when each arrived (the clock's time)."""
        ...

    def wait(self, deadline: float) -> bool:
        """Wait until bytes have arrived (True) or ``deadline`` on the clock passed (False)."""
        ...

    def waiting(self) -> bool:
        """Whether bytes have arrived and wait to be taken."""
        ...


def is_virtual_port(port: str | None) -> bool:
    """Whether ``port`` names an emulated line on a virtual clock."""
    return isinstance(port, str) and port.startswith(VIRTUAL_SCHEME)


class FdLink:
    """A real port's link: its file descriptor, the kernel's ``select`` and the wall clock
    (``port``: an open pyserial port, or a file descriptor)."""

    clock: Clock = WALL

    def __init__(self, port: "serial.Serial | int") -> None:
        self.fd = port if isinstance(port, int) else port.fileno()

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 0.01)
                continue
            view = view[n:]

    def take(self, size: int) -> bytes:
        try:
            return os.read(self.fd, size)
        except BlockingIOError:  # nothing yet; a device that went away raises OSError
            return b""

    def take_timed(self) -> list[tuple[float, bytes]]:
        try:
            chunk = self.take(4096) if self.waiting() else b""
        except OSError:
            return []
        return [(time.monotonic(), chunk)] if chunk else []

    def wait(self, deadline: float) -> bool:
        remaining = deadline - time.monotonic()
        try:
            return bool(select.select([self.fd], [], [], max(0.0, remaining))[0])
        except InterruptedError:  # pragma: no cover - PEP 475 retries already
            return False

    def waiting(self) -> bool:
        try:
            return bool(select.select([self.fd], [], [], 0)[0])
        except (OSError, ValueError):
            return False


def virtual_port_served(port: str) -> bool:
    """Whether ``port`` is a ``virtual://`` line this process serves now."""
    if not is_virtual_port(port):
        return False
    return line_named(port[len(VIRTUAL_SCHEME):]) is not None


def port_usable(port: str) -> bool:
    """Whether ``port`` can be opened: a device that exists and this user may read and write, or a
    ``virtual://`` line this process serves."""
    if is_virtual_port(port):
        return virtual_port_served(port)
    return os.path.exists(port) and os.access(port, os.R_OK | os.W_OK)


#: The capture the ports opened meanwhile write to (:func:`capturing`), or None.
_capture: Optional[WireCapture] = None


@contextlib.contextmanager
def capturing(capture: Optional[WireCapture]) -> Iterator[None]:
    """Every port opened inside the block writes its bytes to ``capture`` (None: none does)."""
    global _capture
    before, _capture = _capture, capture
    try:
        yield
    finally:
        _capture = before


def link_of(ser, role: str) -> Link:
    """The link of an open pyserial port: the virtual line's own, or one on its descriptor; a
    port opened while :func:`capturing` writes its bytes to the capture as ``role``."""
    link = ser if isinstance(ser, Link) else FdLink(ser)
    return link if _capture is None else CapturedLink(link, _capture, role)


def open_port(port: str, baud: int) -> serial.SerialBase:
    """Open ``port`` (a device path or a ``virtual://`` URL) at ``baud``, non-blocking reads."""
    return serial.serial_for_url(port, baudrate=baud, timeout=0)


def drain_until_quiet(link: Link, quiet_s: float, max_s: float) -> int:
    """Discard what arrives until the line has been silent for ``quiet_s``; bytes discarded.

    After a failed transaction a servo's late answer may still be on its way; taken as the
    answer to the next request it would be a plausible, wrong value. Waiting for a quiet line
    (at most ``max_s``, so a babbling peer cannot hold the host) lets the next request start
    in step.
    """
    clock = link.clock
    end = clock.now() + max_s
    dropped = 0
    while True:
        now = clock.now()
        if now >= end:
            return dropped
        try:
            if not link.wait(min(now + quiet_s, end)):
                return dropped
            chunk = link.take(4096)
        except (OSError, ValueError):
            return dropped
        if not chunk:
            return dropped
        dropped += len(chunk)
