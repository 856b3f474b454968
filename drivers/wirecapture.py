"""A wire capture: every byte the host put on its ports and took from them, stamped with the
port's clock, in one text file a person can read and ``diff``.

One line a chunk, as it crossed: ``<time s> <role> <direction> <hex>``, the role the port's job
(``dynamixel``, ``ultrasonic``), ``>`` host to device and ``<`` device to host. On the virtual
clock the times are the line's own and the file is the same bit for bit on any machine; in real
time they are the monotonic clock's. What a capture cannot hold is what the host never saw:
bytes a flush of the input buffer dropped unread.

:func:`packets` splits a role's stream in one direction into Dynamixel Protocol 2.0 packets, so
two captures compare packet by packet whatever chunks the bytes arrived in.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO, Optional

__all__ = ["CAPTURE_HEADER", "CapturedLink", "WireCapture", "packets", "read_capture"]

#: The capture file's first line.
CAPTURE_HEADER = "# needle-hil-bench wire capture 1: time_s role direction(> to the device, < from it) hex"
_HEADER = b"\xff\xff\xfd\x00"


class WireCapture:
    """The file a command's ports write their bytes to (``with WireCapture(path) as capture:``)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._file: Optional[IO[str]] = None

    def __enter__(self) -> "WireCapture":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("w", encoding="ascii")
        self._file.write(CAPTURE_HEADER + "\n")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def record(self, t: float, role: str, direction: str, data: bytes) -> None:
        """One chunk that crossed at ``t`` (the port's clock, s)."""
        if self._file is not None and data:
            self._file.write(f"{t:.9f} {role} {direction} {bytes(data).hex()}\n")


class CapturedLink:
    """A :class:`~drivers.link.Link` whose every byte sent and taken is written to a capture."""

    def __init__(self, link, capture: WireCapture, role: str) -> None:
        self.link, self.capture, self.role = link, capture, role
        self.clock = link.clock

    def send(self, data: bytes) -> None:
        self.capture.record(self.clock.now(), self.role, ">", data)
        self.link.send(data)

    def take(self, size: int) -> bytes:
        data = self.link.take(size)
        self.capture.record(self.clock.now(), self.role, "<", data)
        return data

    def take_timed(self) -> list[tuple[float, bytes]]:
        chunks = self.link.take_timed()
        for t, chunk in chunks:
            self.capture.record(t, self.role, "<", chunk)
        return chunks

    def wait(self, deadline: float) -> bool:
        return self.link.wait(deadline)

    def waiting(self) -> bool:
        return self.link.waiting()


def read_capture(path: Path) -> list[tuple[float, str, str, bytes]]:
    """The chunks of a capture file: (time s, role, direction, bytes); a file that is not one is
    refused, naming its line."""
    lines = Path(path).read_text(encoding="ascii").splitlines()
    if not lines or lines[0] != CAPTURE_HEADER:
        raise ValueError(f"{path}: not a wire capture (its first line is not {CAPTURE_HEADER!r})")
    chunks = []
    for n, line in enumerate(lines[1:], start=2):
        try:
            t, role, direction, data = line.split(" ")
            chunks.append((float(t), role, direction, bytes.fromhex(data)))
        except ValueError:
            raise ValueError(f"{path}, line {n}: not 'time role direction hex': {line[:80]!r}") from None
    return chunks


def packets(chunks: list[tuple[float, str, str, bytes]], role: str, direction: str) -> list[bytes]:
    """The Protocol 2.0 packets in one role's stream in one direction, in order (bytes between
    packets, noise on the line, are skipped)."""
    stream = b"".join(c[3] for c in chunks if c[1] == role and c[2] == direction)
    found, i = [], 0
    while True:
        i = stream.find(_HEADER, i)
        if i < 0 or i + 7 > len(stream):
            return found
        end = i + 7 + int.from_bytes(stream[i + 5:i + 7], "little")
        if end > len(stream):
            return found
        found.append(stream[i:end])
        i = end
