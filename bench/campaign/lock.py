"""One writer per campaign directory: a lock the kernel drops when its holder dies.

``campaign run`` and ``campaign resume`` hold ``campaign.lock`` (``flock``, exclusive) for as
long as they write the directory: two at once would run every missing trial twice, each
wiping the other's staging, and on a rig drive one servo bus from two processes. The file
holds the holder's pid, host and start time, for the refusal to name it. A holder killed
outright (``kill -9``, out of memory) loses the lock with its last file descriptor, so the
next ``resume`` takes over at once; nothing has to be cleaned up by hand.
"""

from __future__ import annotations

import datetime as dt
import fcntl
import os
import socket
from pathlib import Path
from typing import Optional

from drivers.errors import CampaignBusy

__all__ = ["LOCK_NAME", "CampaignBusy", "CampaignLock"]

LOCK_NAME = "campaign.lock"
#: Campaign directories this process holds, and how deep: a holder may call code that takes it again.
_HELD: dict[Path, int] = {}


class CampaignLock:
    """Exclusive hold on a campaign directory; a context manager (``acquire`` refuses at once
    when another process holds it; within the holding process it nests)."""

    def __init__(self, campaign_dir: Path | str) -> None:
        self.campaign_dir = Path(campaign_dir)
        self.path = self.campaign_dir / LOCK_NAME
        self._fd: Optional[int] = None
        self._nested = False

    def acquire(self) -> "CampaignLock":
        key = self.campaign_dir.resolve()
        if key in _HELD:  # this process holds it already (the command around the library call)
            _HELD[key] += 1
            self._nested = True
            return self
        flags = os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except OSError as e:
            raise CampaignBusy(f"{self.campaign_dir}: cannot open its lock {LOCK_NAME}: {e.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _read_holder(fd)
            os.close(fd)
            raise CampaignBusy(f"{self.campaign_dir} is being run by {holder}: a campaign directory "
                               f"has one writer; wait for it to end (or stop it), then resume") from None
        os.ftruncate(fd, 0)
        stamp = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
        os.pwrite(fd, f"{os.getpid()} {socket.gethostname()} {stamp}\n".encode(), 0)
        self._fd = fd
        _HELD[key] = 1
        return self

    def release(self) -> None:
        key = self.campaign_dir.resolve()
        if self._nested:
            self._nested = False
            _HELD[key] -= 1
            return
        if self._fd is None:
            return
        _HELD.pop(key, None)
        fd, self._fd = self._fd, None
        try:
            os.ftruncate(fd, 0)  # no stale pid left to read
        finally:
            os.close(fd)  # closing the last descriptor drops the flock

    def __enter__(self) -> "CampaignLock":
        held = self._fd is not None or self._nested
        return self if held else self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _read_holder(fd: int) -> str:
    """Who holds the lock, as its file says, with whether that process still lives here."""
    try:
        text = os.pread(fd, 256, 0).decode("utf-8", "replace").split()
    except OSError:
        text = []
    if not text or not text[0].isdigit():
        return "another process (it has not written its pid yet)"
    pid, host = int(text[0]), text[1] if len(text) > 1 else "?"
    since = f", since {text[2]}" if len(text) > 2 else ""
    if host != socket.gethostname():
        return f"process {pid} on {host}{since}"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return f"a child of process {pid}, which has ended{since}"
    except PermissionError:
        pass
    return f"process {pid}{since}"
