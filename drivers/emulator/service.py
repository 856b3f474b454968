"""The life cycle every emulated device shares: a thread serving a pseudo-terminal, started once,
stopped once (the port disappears), usable as a context manager."""

from __future__ import annotations

import os
import threading

__all__ = ["PtyService"]


class PtyService:
    """Base of the emulators: subclasses set ``_master``/``_slave`` and implement ``_run``."""

    #: The serving thread's name (shown by debuggers and ``ps -L``).
    thread_name = "emulator"
    _closed = False
    _thread: threading.Thread | None = None

    def _init_service(self) -> None:
        self._stop = threading.Event()
        self._thread = None
        self._closed = False

    def _run(self) -> None:
        raise NotImplementedError

    def _before_start(self) -> None:
        """Called in :meth:`start` just before the thread starts."""

    def _interrupt_wait(self) -> None:
        """Interrupt the serving thread's wait so it sees the stop at once."""

    def _fds(self) -> tuple[int, ...]:
        """The file descriptors to close when stopped."""
        return (self._master, self._slave)

    def start(self):
        if self._closed:
            raise RuntimeError(f"this {self.thread_name} was stopped; create a new one")
        if self._thread is None:
            self._before_start()
            self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty (the port disappears); idempotent."""
        if self._closed:
            return
        self._stop.set()
        self._interrupt_wait()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._closed = True
        for fd in self._fds():
            try:
                os.close(fd)
            except OSError:
                pass

    def close(self) -> None:
        self.stop()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
