"""Keep PyBullet's C-level banner off the terminal, so CLI output stays clean."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from typing import Iterator


@contextlib.contextmanager
def muted_output() -> Iterator[None]:
    """Send file descriptors 1 and 2 to /dev/null for the duration (C printf included)."""
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no stdout/stderr at all
        yield
        return
    libc = ctypes.CDLL(None)
    devnull = os.open(os.devnull, os.O_WRONLY)
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


def quiet_pybullet():
    """``import pybullet`` without its banner."""
    if "pybullet" not in sys.modules:
        with muted_output():
            import pybullet  # noqa: F401
    return sys.modules["pybullet"]
