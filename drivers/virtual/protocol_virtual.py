"""pyserial's handler for ``virtual://NAME``: the host's end of a :class:`~drivers.virtual.VirtualLine`.

A ``serial.SerialBase`` as pyserial's own URL handlers are (``loop://``, ``socket://``), so code
that opens ports by URL opens it unchanged, and a :class:`~drivers.link.Link` besides: reads
with a timeout and the link's waits advance the line's virtual clock instead of sleeping.
"""

from __future__ import annotations

import math

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from drivers.virtual import VirtualLine, line_named

__all__ = ["Serial"]

_SCHEME = "virtual://"


class Serial(SerialBase):
    """The host's end of an emulated line on a virtual clock."""

    _line: VirtualLine | None = None

    def open(self) -> None:
        if self.is_open:
            raise SerialException("port already open")
        url = str(self.portstr or "")
        if not url.lower().startswith(_SCHEME):
            raise SerialException(f"not a virtual port URL: {url!r} (expected {_SCHEME}NAME)")
        name = url[len(_SCHEME):]
        line = line_named(name)
        if line is None:
            raise SerialException(
                f"no emulated line {name!r} in this process: a {_SCHEME} port is served by the "
                f"emulated rig of the same command (--emulate --clock virtual)")
        self._line = line
        self.is_open = True
        line.host = self
        line.to_host.clear()
        self._reconfigure_port()

    def close(self) -> None:
        line, self._line = self._line, None
        if self.is_open and line is not None and line.host is self:  # not a later opener's
            line.host = None
            line.to_host.clear()
        self.is_open = False

    def _reconfigure_port(self, force_update: bool = False) -> None:  # noqa: ARG002 - pyserial's
        if self._line is not None:
            self._line.host_baud = int(self._baudrate) if self._baudrate else None

    def fileno(self) -> int:
        raise SerialException(f"{self.portstr} is an emulated line: it has no file descriptor")

    # -- the Link ------------------------------------------------------------------------------
    @property
    def clock(self):
        return self._open_line().clock

    def _open_line(self) -> VirtualLine:
        if not self.is_open or self._line is None:
            raise PortNotOpenError()
        return self._line

    def send(self, data: bytes) -> None:
        line = self._open_line()
        line.receive(bytes(data), line.clock.now())

    def take(self, size: int) -> bytes:
        line = self._open_line()
        out = bytearray()
        queue = line.to_host
        while queue and len(out) < size:
            t, chunk = queue[0]
            room = size - len(out)
            if len(chunk) <= room:
                out += chunk
                queue.popleft()
            else:
                out += chunk[:room]
                queue[0] = (t, chunk[room:])
        return bytes(out)

    def take_timed(self) -> list[tuple[float, bytes]]:
        queue = self._open_line().to_host
        out = list(queue)
        queue.clear()
        return out

    def wait(self, deadline: float) -> bool:
        line = self._open_line()
        queue = line.to_host
        return line.clock.advance(deadline, until=lambda: bool(queue))

    def waiting(self) -> bool:
        return bool(self._open_line().to_host)

    # -- pyserial's calls ------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        return self._open_line().pending()

    def read(self, size: int = 1) -> bytes:
        line = self._open_line()
        if self._timeout is None:
            deadline = math.inf
        else:
            deadline = line.clock.now() + self._timeout
        if size > 0 and self._timeout != 0:
            line.clock.advance(deadline, until=lambda: line.pending() >= size)
        return self.take(size)

    def write(self, data) -> int:
        data = bytes(data)
        self.send(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._open_line().to_host.clear()

    def reset_output_buffer(self) -> None:
        self._open_line()

    def flush(self) -> None:
        self._open_line()
