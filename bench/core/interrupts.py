"""SIGINT, SIGTERM and SIGHUP end a trial the same way: safe stop, log saved, one line, 128+N.

A signal handler that only raised an exception would be lost wherever library
code swallows exceptions (an import that catches ``BaseException``) and would
cut a safe stop short if a second signal came during it. So the guard records
the first signal and raises :class:`TrialInterrupted` once; the runner and the
trial also poll :meth:`SignalGuard.check` at every phase boundary and control
block, so a swallowed exception is still acted on; later signals are counted,
never raised, so the safe stop and the saving of the log always finish. A signal that lands while
PyBullet's output is muted (:mod:`drivers.quiet`) is held and sent again once the output is back:
raised there, it could leave stdout and stderr on /dev/null and the one line would be lost. One
that lands while a module is importing is sent again the moment the import is done: raised
inside it, the loader of a C extension (numpy's) turns it into an ImportError with its
traceback, and the command would die of a broken import instead of saying it was stopped.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from contextlib import contextmanager
from types import FrameType
from typing import Iterator, Optional

from drivers.errors import signal_exit_code

#: The signals a trial treats as "stop now, safely": Ctrl-C, kill/timeout/systemd, a lost terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class TrialInterrupted(KeyboardInterrupt):
    """A stop signal arrived; ``signum`` says which (exit code 128 + signum)."""

    def __init__(self, signum: int, source: str | None = None) -> None:
        super().__init__(f"interrupted by {signal_name(signum)}" + (f" ({source})" if source else ""))
        self.signum = signum
        self.source = source

    @property
    def exit_code(self) -> int:
        return signal_exit_code(self.signum)


def _held_while_muted(signum: int) -> bool:
    """Whether ``signum`` landed while stdout and stderr were muted and is held till they are
    back (:func:`drivers.quiet.hold_signal`). Looked up, not imported: a process that never
    loaded the module never muted anything, and the entry point stays light."""
    quiet = sys.modules.get("drivers.quiet")
    return quiet is not None and quiet.hold_signal(signum)


#: How often (s) a stop signal that landed in an import looks whether the import is done, and
#: then whether the main thread has taken it (sent again if not: see :func:`_send_after_import`).
_IMPORT_POLL_S = 0.002
_TAKEN_WAIT_S = 0.02


def _importing(frame: Optional[FrameType]) -> bool:
    """Whether the code a signal interrupted runs inside an import (a frame of importlib's loader
    below it): a module's top level, or the Python a C extension's initialisation calls."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _send_after_import(guard: "SignalGuard") -> None:
    """Send the signal ``guard`` put off in an import to the main thread again once it is out of
    every import, and again until its handler has taken it (from a thread of its own: the main
    thread is busy importing).

    To the main thread itself: sent to the process, another thread may take it, and a main
    thread waiting (asleep, on a socket) would act on it only once that wait was over. And again:
    one that comes as the main thread is about to start a wait is noted by Python and acted on
    only once the wait is over (seconds, in a test that slept right after its import)."""
    main = threading.main_thread()

    def resend() -> None:
        while (signum := guard._after_import) is not None and guard._previous and main.is_alive():
            if _importing(sys._current_frames().get(main.ident)):
                time.sleep(_IMPORT_POLL_S)
                continue
            try:
                signal.pthread_kill(main.ident, signum)
            except (OSError, TypeError):  # the main thread has ended meanwhile
                return
            time.sleep(_TAKEN_WAIT_S)

    threading.Thread(target=resend, name="resend-after-import", daemon=True).start()


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


class SignalGuard:
    """Context manager: the stop signals become one :class:`TrialInterrupted` and a flag.

    Installs its handlers only in the main thread (elsewhere Python forbids
    it; the guard then does nothing but answer :meth:`check` with no signal),
    and restores the previous handlers on exit.
    """

    def __init__(self) -> None:
        self.signum: Optional[int] = None
        #: Who asked for the stop when it was not a signal from outside (the live view's Stop).
        self.source: Optional[str] = None
        self.repeats = 0
        self._previous: dict[int, object] = {}
        self._deferring = 0
        #: a stop signal that landed inside an import, until its handler takes it after the import
        self._after_import: Optional[int] = None

    def _handle(self, signum: int, frame: Optional[FrameType]) -> None:
        if self.signum is not None:
            self.repeats += 1  # never raise twice: the safe stop in progress must finish
            return
        if _held_while_muted(signum):
            return  # sent again the moment the output is back
        if not self._deferring and _importing(frame):
            if self._after_import is None:  # sent again once the import is done, and taken then
                self._after_import = signum
                _send_after_import(self)
            return
        self._after_import = None
        self.signum = signum
        if not self._deferring:
            raise TrialInterrupted(signum, self.source)

    @contextmanager
    def deferred(self) -> Iterator[None]:
        """A stretch no signal may cut short (the safe stop, writing the record): a signal
        arriving in it is only noted, for :meth:`check` to raise afterwards."""
        self._deferring += 1
        try:
            yield
        finally:
            self._deferring -= 1

    def settle(self) -> None:
        """From now on a signal is only noted, never raised: the process is ending and its
        last line must get out whole."""
        self._deferring += 1

    def _take_put_off(self) -> None:
        """A signal put off in an import counts from the first look out of every import: the
        thread that sends it again may be late on a loaded machine, and the trial must not run on
        past the signal's phase meanwhile (or end as if none had come)."""
        if (self.signum is None and self._after_import is not None
                and threading.current_thread() is threading.main_thread()
                and not _importing(sys._getframe())):
            self.signum, self._after_import = self._after_import, None

    def check(self) -> None:
        """Raise :class:`TrialInterrupted` if a stop signal has arrived (even if swallowed)."""
        self._take_put_off()
        if self.signum is not None:
            raise TrialInterrupted(self.signum, self.source)

    def request_stop(self, source: str) -> None:
        """The stop Ctrl-C gives, asked for from another thread of this process (a SIGINT to its
        main thread, so it takes the very same path and ends a wait the main thread is in),
        recorded as coming from ``source``."""
        if self.signum is None and self.source is None:
            self.source = source
        main = threading.main_thread().ident
        if main is not None:
            signal.pthread_kill(main, signal.SIGINT)

    @property
    def interrupted(self) -> bool:
        self._take_put_off()
        return self.signum is not None

    #: Guards entered while another was in place: a command's own over the entry point's. A
    #: command that moves anything enters its own first; none entered, nothing moved.
    nested_entered = 0
    _active = 0

    def __enter__(self) -> "SignalGuard":
        if SignalGuard._active:
            SignalGuard.nested_entered += 1
        SignalGuard._active += 1
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        SignalGuard._active -= 1
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        self._previous.clear()
        pending, self._after_import = self._after_import, None
        if pending is not None:  # put off in an import and not yet taken: the handler before ours has it
            signal.raise_signal(pending)


class _NoSignals:
    """The guard of a trial run with no signal handling (library use, worker threads)."""

    signum = None
    interrupted = False

    def check(self) -> None:
        return None

    @contextmanager
    def deferred(self) -> Iterator[None]:
        yield


NO_SIGNALS = _NoSignals()
