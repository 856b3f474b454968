"""The clock a driver and its devices keep time by: the wall clock at a rig, a virtual one in a rehearsal.

Everything that waits or stamps a time on the servo path (the trial loop's period, the driver's
timeouts and retries, the sensor's ages, the emulated firmware, physics and wire) reads one
:class:`Clock`. At the rig it is :data:`WALL` (the monotonic clock; waits sleep). An emulated rig
may run on a :class:`VirtualClock` instead: time then advances only when the work of an instant is
done, device by device in time order, so a trial's log is the same bit for bit on any machine,
and as fast as the CPU allows.

The virtual clock is a small discrete-event scheduler. A device (:class:`Scheduled`) says when
its next piece of work falls due (a physics step, a status packet reaching the host, a sensor's
line); :meth:`VirtualClock.advance` runs those in order of their instants, the earliest first
(ties in the order the devices were attached), until the instant asked for, or until a condition
the caller waits on holds (bytes have arrived).
"""

from __future__ import annotations

import math
import time
from typing import Callable, Optional, Protocol, runtime_checkable

__all__ = ["Clock", "Scheduled", "VirtualClock", "WALL", "WallClock"]


@runtime_checkable
class Clock(Protocol):
    """Seconds on a monotonic scale, and waiting on it."""

    #: True for a clock that advances only when its devices' work is done (no wall time passes).
    virtual: bool

    def now(self) -> float: ...

    def sleep_until(self, t: float) -> None: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """The monotonic clock; waits sleep in the kernel and spin through the last millisecond
    (a sleep may overshoot by the timer slack, and a control cycle's deadline is sharper)."""

    virtual = False

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        remaining = t - time.monotonic()
        if remaining > 0.002:
            time.sleep(remaining - 0.001)
        while time.monotonic() < t:
            pass

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def __repr__(self) -> str:
        return "WallClock()"


#: The one wall clock: what a real port, and the real-time rehearsal, keep time by.
WALL = WallClock()


class Scheduled(Protocol):
    """A device on a virtual clock: its next piece of work, and running it."""

    def next_due(self) -> float:
        """The instant (s) its next piece of work falls due; ``math.inf`` for none."""
        ...

    def run_until(self, t: float) -> float:
        """Run its work due at or before ``t`` in time order, each piece at its own instant, and
        return the instant of the last piece run. It returns early, right after a piece the host
        or another device can see (bytes reaching a port), so the clock can look again."""
        ...


class VirtualClock:
    """Time that moves only when the attached devices' work up to it is done.

    ``advance(t)`` runs every device's work due by ``t`` in time order; ``sleep_until`` is that;
    ``advance(t, until=cond)`` stops at the first instant after which ``cond()`` holds (bytes on a
    host's port) and says whether it did. The clock never runs backwards, and its readings are the
    instants of the work it ran: no wall time enters them.
    """

    virtual = True

    def __init__(self, start: float = 0.0) -> None:
        if not math.isfinite(start):
            raise ValueError(f"a virtual clock starts at a finite time, got {start}")
        self._now = float(start)
        self._devices: list[Scheduled] = []
        #: Instants run, for the record: how many pieces of work the devices did.
        self.events = 0

    def attach(self, device: Scheduled) -> None:
        """``device`` runs on this clock from now on (in attach order where two fall due at once)."""
        if device not in self._devices:
            self._devices.append(device)

    def detach(self, device: Scheduled) -> None:
        if device in self._devices:
            self._devices.remove(device)

    def now(self) -> float:
        return self._now

    def advance(self, t: float, until: Optional[Callable[[], bool]] = None) -> bool:
        """Run the work due by ``t`` (or, with ``until``, up to the first instant it holds after);
        True when ``until`` held (always False without it). Time ends at ``t``, or at that instant."""
        if until is not None and until():
            return True
        devices = self._devices
        while True:
            first, due, second = None, math.inf, math.inf
            for device in devices:
                d = device.next_due()
                if d < due:
                    first, due, second = device, d, due
                elif d < second:
                    second = d
            if first is None or due > t:
                break
            # no other device has work before ``second``: this one runs its own up to it
            reached = first.run_until(min(t, second))
            if reached > self._now:
                self._now = reached
            self.events += 1
            if until is not None and until():
                return True
        if t > self._now and math.isfinite(t):  # an open-ended wait with nothing due ends now
            self._now = t
        return False

    def sleep_until(self, t: float) -> None:
        self.advance(t)

    def sleep(self, seconds: float) -> None:
        self.advance(self._now + max(0.0, seconds))

    def __repr__(self) -> str:
        return f"VirtualClock(now={self._now:.6f}, devices={len(self._devices)})"
