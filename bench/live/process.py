"""The live view in a process of its own: the trial's interpreter never serves a browser.

A page's poll reads the journal, works out the interlock margins of its newest row and encodes
the rows: a few milliseconds of Python. In the trial's own process that work holds the
interpreter's lock while the control loop waits for it, and on a loaded two-core computer a
poll's few milliseconds became a missed deadline every half second. Here the server runs in a
child process at nice 10 (the loop, and the kernel's serial-port work at the default priority,
go first; the page falls behind), reading the same files the loop has already handed to the operating
system. The two talk through the child's standard streams, one word a line:

- the child's first line is JSON, ``{"url": …}`` (the address with its token);
- then ``page-open`` (a page loaded and polled) and ``stop`` (Stop was pressed), as they happen;
- the parent writes ``close`` (linger for open pages to fetch the verdict) or ``close-now``.

The child dies with its parent (Linux ``PR_SET_PDEATHSIG``), so a trial killed outright leaves
no server behind.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

from bench.config.models import load_trial_config
from bench.live.follow import RunFollower
from bench.live.server import LiveServer
from bench.trial.plan import prepare
from drivers.errors import ExitCode

__all__ = ["LiveProcess"]

#: The server's nice value: below the default, so the page falls behind, never the trial.
SERVER_NICE = 10
#: How long the parent waits for the child to announce its address (s): it imports the bench and
#: builds the margins' geometry first.
START_TIMEOUT_S = 60.0


class LiveProcess:
    """The live view of the runs under ``out``, served by a child process (see the module's note).

    ``config`` is the trial config whose interlock margins the page shows; ``on_stop`` is called
    (from a reader thread) when Stop is pressed in a page."""

    def __init__(self, out: Path, config: Path, on_stop: Callable[[], None]) -> None:
        self.on_stop = on_stop
        self.stop_requested = False
        self.page_open = threading.Event()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.live.process", "--out", str(out), "--config", str(config),
             "--parent", str(os.getpid())],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=None, text=True,
            start_new_session=True,  # a Ctrl-C meant for the trial reaches the trial, which closes us
            env=dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1"))
        first: list[str] = []
        reader = threading.Thread(target=lambda: first.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        try:
            hello = json.loads(first[0]) if first else None
        except ValueError:
            hello = None
        if not isinstance(hello, dict) or "url" not in hello:
            self.close(linger=False)
            raise RuntimeError("the live view did not start" + (f" within {START_TIMEOUT_S:.0f} s"
                                                                 if not first else ""))
        self.url: str = hello["url"]
        threading.Thread(target=self._follow, name="live-view-reader", daemon=True).start()

    def _follow(self) -> None:
        for line in self.proc.stdout:
            word = line.strip()
            if word == "page-open":
                self.page_open.set()
            elif word == "stop" and not self.stop_requested:
                self.stop_requested = True
                self.on_stop()

    def wait_for_page(self, timeout_s: float, check: Callable[[], None] = lambda: None) -> bool:
        """Wait until a page has loaded and polled, at most ``timeout_s``; True if one did.

        Opening a page is the browser's costliest moment (a renderer started, the script parsed,
        nine plots laid out): on a two-core bench computer it takes both cores for a second.
        Waiting for it before the trial moves keeps that second out of the control loop.
        ``check`` is called between waits (a Ctrl-C meanwhile stops the trial as usual)."""
        deadline = time.monotonic() + timeout_s
        while not self.page_open.is_set():
            check()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.page_open.wait(min(0.1, remaining))
        return True

    def close(self, linger: bool = True) -> None:
        """Stop the server; with ``linger``, first let open pages fetch the verdict."""
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("close\n" if linger else "close-now\n")
                self.proc.stdin.flush()
            except (OSError, ValueError):
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except (OSError, ValueError):
                pass

    def __enter__(self) -> "LiveProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        # A run stopped by Ctrl-C or the page's Stop has its record too: open pages get its verdict.
        self.close(linger=exc[0] is None or issubclass(exc[0], KeyboardInterrupt))


def _die_with_parent(parent: int) -> None:
    """Killed by the kernel the moment ``parent`` dies (Linux), or at once if it already has."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    if os.getppid() != parent:  # the trial died before prctl took effect: nothing to serve
        sys.exit(ExitCode.ORPHANED)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="the live view's server (started by trial/compare --live)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--parent", type=int, required=True)
    args = ap.parse_args(argv)
    _die_with_parent(args.parent)
    # Behind everything at the default priority, the kernel's serial-port workers included: a poll
    # answered late costs the page an update, never the loop a deadline.
    os.setpriority(os.PRIO_PROCESS, 0, max(SERVER_NICE, os.getpriority(os.PRIO_PROCESS, 0)))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the trial's Ctrl-C is the trial's; it closes us

    # The words go out on a private copy of stdout; fd 1 itself goes nowhere, so a library's
    # banner printed at the C level (PyBullet's) can never be taken for one.
    words = os.fdopen(os.dup(1), "w")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)
    say_lock = threading.Lock()

    def say(word: str) -> None:
        with say_lock:
            try:
                words.write(word + "\n")
                words.flush()
            except (OSError, ValueError):
                pass

    prep = prepare(load_trial_config(args.config))
    server = LiveServer(RunFollower(args.out, lambda: prep), on_stop=lambda: say("stop")).start()
    threading.Thread(target=lambda: (server.page_open.wait(), say("page-open")), daemon=True).start()
    say(json.dumps({"url": server.url}))
    linger = False
    for line in sys.stdin:
        if line.strip() in ("close", "close-now"):
            linger = line.strip() == "close"
            break
    server.close(linger=linger)


if __name__ == "__main__":
    main()
