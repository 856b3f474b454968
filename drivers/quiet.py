"""Keep PyBullet's C-level banner off the terminal, so CLI output stays clean.

While the output is muted (file descriptors 1 and 2 on /dev/null) a stop signal must not raise:
an exception between the two ``dup2`` calls that put the output back, or at the entry of the
context manager's ``__exit__`` before it resumes the generator, leaves the process writing to
/dev/null, and the command's one line saying why it stopped is lost (exit 130, empty stderr).
So a handler that would raise asks :func:`hold_signal` first: a signal that lands in a muted
stretch is sent again the moment the output is back.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
from typing import Iterator

#: Muted stretches open now; while there is one, fds 1 and 2 go to /dev/null.
_depth = 0
#: Stop signals held during a muted stretch, to be sent again once the output is back.
_held: list[int] = []


def hold_signal(signum: int) -> bool:
    """True when the output is muted: ``signum`` is kept and sent again once it is back (the
    handler should return without acting); False when nothing is muted: act on it now."""
    if _depth == 0:
        return False
    _held.append(signum)
    return True


@contextlib.contextmanager
def muted_output() -> Iterator[None]:
    """Send file descriptors 1 and 2 to /dev/null for the duration (C printf included)."""
    global _depth
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no stdout/stderr at all
        yield
        return
    libc = ctypes.CDLL(None)
    devnull = os.open(os.devnull, os.O_WRONLY)
    _depth += 1  # before the output goes: from here a stop signal is held, not raised
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
        libc.fflush(None)
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)
        _depth -= 1
        _send_held()


def _send_held() -> None:
    """Send the stop signals held while muted again, now that the output is back."""
    if _depth or not _held:
        return
    pending = list(dict.fromkeys(_held))
    _held.clear()
    for signum in pending:
        signal.raise_signal(signum)


def quiet_pybullet():
    """``import pybullet`` without its banner."""
    if "pybullet" not in sys.modules:
        with muted_output():
            import pybullet  # noqa: F401
    return sys.modules["pybullet"]
