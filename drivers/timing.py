"""Fine waits on Linux: timer slack, and sleeping to a deadline without oversleeping.

Linux lets a sleeping thread's wake-up slip by its *timer slack* (50 µs by
default) so that wake-ups can be merged. A bus whose bytes take 2.5 µs each
at 4 Mbps cannot afford that: the threads that time the wire (the emulator's
server, the driver's control loop while it waits for a reply) ask for 1 ns.
"""

from __future__ import annotations

import ctypes
import sys
import threading
import time

_PR_SET_TIMERSLACK = 29
_tightened: set[int] = set()


def tighten_timer_slack() -> bool:
    """Ask Linux for 1 ns timer slack on the calling thread; True if granted.

    With the default 50 µs slack every short sleep, even ``sleep(0)`` or a
    ``select`` with a timeout, may overshoot by up to 50 µs. Asked once per
    thread; later calls return the first answer.
    """
    ident = threading.get_ident()
    if ident in _tightened:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        granted = ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False
    if granted:
        _tightened.add(ident)
    return granted


def sleep_until(deadline: float, spin_s: float) -> None:
    """Sleep to ``deadline`` (perf_counter s): coarse sleep, then yield for the last ``spin_s``."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        time.sleep(remaining - spin_s if remaining > spin_s else 0)
