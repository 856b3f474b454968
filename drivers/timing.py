"""Fine waits on Linux: timer slack, and sleeping to a deadline without oversleeping.

Linux lets a sleeping thread's wake-up slip by its *timer slack* (50 µs by
default) so that wake-ups can be merged. A bus whose bytes take 2.5 µs each
at 4 Mbps cannot afford that: the emulator's serving thread, which times the
wire, asks for 1 ns.
"""

from __future__ import annotations

import ctypes
import os
import select
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


def drain_until_quiet(fd: int, quiet_s: float, max_s: float) -> int:
    """Discard what arrives on ``fd`` until it has been silent for ``quiet_s``; bytes discarded.

    After a failed transaction a servo's late answer may still be on its way;
    taken as the answer to the next request it would be a plausible, wrong
    value. Waiting for a quiet line (at most ``max_s``, so a babbling peer
    cannot hold the host) lets the next request start in step.
    """
    end = time.monotonic() + max_s
    dropped = 0
    while True:
        remaining = end - time.monotonic()
        if remaining <= 0:
            return dropped
        try:
            ready = select.select([fd], [], [], min(quiet_s, remaining))[0]
        except (OSError, ValueError):
            return dropped
        if not ready:
            return dropped
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:
            continue
        except OSError:
            return dropped
        if not chunk:
            return dropped
        dropped += len(chunk)
