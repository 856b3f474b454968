"""Fine waits on Linux: timer slack, and sleeping to a deadline without oversleeping.

Linux lets a sleeping thread's wake-up slip by its *timer slack* (50 µs by
default) so that wake-ups can be merged. A bus whose bytes take 2.5 µs each
at 4 Mbps cannot afford that: the emulator's serving thread, which times the
wire, asks for 1 ns.
"""

from __future__ import annotations

import ctypes
import sys
import time

_PR_SET_TIMERSLACK = 29


def tighten_timer_slack() -> bool:
    """Ask Linux for 1 ns timer slack on the calling thread; True if granted.

    With the default 50 µs slack every short sleep, even ``sleep(0)``, may
    overshoot by up to 50 µs, which would lengthen each modelled transfer.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def sleep_until(deadline: float, spin_s: float) -> None:
    """Sleep to ``deadline`` (perf_counter s): coarse sleep, then yield for the last ``spin_s``."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        time.sleep(remaining - spin_s if remaining > spin_s else 0)
