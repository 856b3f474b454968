"""DYNAMIXEL Protocol 2.0 parsing: an incremental parser that never trusts a byte, Fast Sync Read
status blocks, and matching a reply to the request it answers. No I/O: the host driver and the
emulator parse with the same code."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Union

from drivers.dynamixel.protocol import (
    _STUFF,
    _TRIPLE,
    DEFAULT_MAX_LENGTH,
    HEADER,
    FastStatusBlock,
    Instruction,
    StuffingError,
    crc16,
    unstuff,
)

__all__ = ["CrcError", "MalformedPacket", "Packet", "PacketParser", "ParseResult", "parse_fast_status", "reply_mismatch", "reply_params_expected"]


def parse_fast_status(packet: "Packet", data_lengths: Sequence[int]) -> list[FastStatusBlock]:
    """Split a Fast Sync/Bulk Read status :class:`Packet` into its device blocks.

    ``packet`` must come from a parser with ``stuffed=False``; the running
    CRC of every block is checked against the packet's raw bytes.
    """
    if packet.error is None:
        raise ValueError(f"not a status packet: {packet}")
    raw = packet.raw
    index = 8  # first block's ERR byte
    blocks = []
    for n, length in enumerate(data_lengths):
        end = index + 2 + length
        if end + 2 > len(raw):
            raise ValueError(
                f"fast status packet too short for block {n} ({length} data bytes): {raw.hex(' ')}"
            )
        crc = crc16(raw[:end])
        if raw[end] | (raw[end + 1] << 8) != crc:
            raise ValueError(f"running CRC of block {n} does not match in {raw.hex(' ')}")
        blocks.append(FastStatusBlock(raw[index + 1], raw[index], bytes(raw[index + 2 : end])))
        index = end + 2
    return blocks


# -- parsing ------------------------------------------------------------------


@dataclass(frozen=True)
class Packet:
    """A received packet, parameters already unstuffed.

    For a status packet (instruction 0x55) ``error`` is the ERR byte and
    ``params`` the bytes after it; for an instruction ``error`` is ``None``.
    ``raw`` holds the packet exactly as it was on the wire.
    """

    id: int
    instruction: int
    params: bytes = b""
    error: int | None = None
    raw: bytes = b""

    @property
    def is_status(self) -> bool:
        return self.instruction == Instruction.STATUS


@dataclass(frozen=True)
class CrcError:
    """A complete frame whose CRC did not match; ``id`` and ``instruction`` are as received."""

    id: int
    instruction: int
    raw: bytes
    expected: int
    received: int


@dataclass(frozen=True)
class MalformedPacket:
    """A frame with a good CRC that still cannot be a valid packet."""

    id: int
    raw: bytes
    reason: str


ParseResult = Union[Packet, CrcError, MalformedPacket]


class PacketParser:
    """Incremental Protocol 2.0 parser: :meth:`feed` bytes, get complete packets.

    It hunts for the header ``FF FF FD 00`` the way a servo does, reads LEN
    bytes, checks the CRC (a mismatch yields :class:`CrcError`) and unstuffs.

    ``resync_on_header=True`` (servo side): an unstuffed ``FF FF FD`` inside
    the stuffed region means a new frame starts there, so the current frame
    is abandoned (counted in :attr:`resyncs`) and the hunt restarts at that
    ``FF``. ``resync_on_header=False`` (host side, like the SDK): frames are
    read by length only. ``stuffed=False`` parses Fast Sync/Bulk Read status
    packets, whose bodies are not stuffed.
    """

    def __init__(
        self,
        *,
        stuffed: bool = True,
        resync_on_header: bool = True,
        max_length: int = DEFAULT_MAX_LENGTH,
    ) -> None:
        self.stuffed = stuffed
        self.resync_on_header = resync_on_header and stuffed
        self.max_length = max_length
        self._buf = bytearray()
        self._scanned = 0  # payload bytes already checked for a bare header
        #: bytes thrown away while hunting for a header
        self.discarded_bytes = 0
        #: frames abandoned because a header appeared inside them
        self.resyncs = 0

    @property
    def pending(self) -> int:
        """Bytes held for a frame not yet complete."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget any partial frame (a servo's inter-byte timeout)."""
        self.discarded_bytes += len(self._buf)
        self._buf.clear()
        self._scanned = 0

    def bytes_wanted(self) -> int:
        """How many more bytes can be read without reading past the current frame.

        A status packet is at least 11 bytes long, so before its length is
        known asking for up to 11 bytes never swallows the next packet.
        """
        buf = self._buf
        if len(buf) >= 7 and buf[:4] == HEADER:
            return max(1, 7 + (buf[5] | (buf[6] << 8)) - len(buf))
        return max(1, 11 - len(buf))

    def feed(self, data: bytes | bytearray | Sequence[int]) -> list[ParseResult]:
        """Add received bytes; return every packet (or error) they completed."""
        self._buf += bytes(data)
        results: list[ParseResult] = []
        while True:
            progressed, result = self._step()
            if result is not None:
                results.append(result)
            if not progressed:
                return results

    # One parsing step: (made progress, result or None).
    def _step(self) -> tuple[bool, ParseResult | None]:
        buf = self._buf
        start = buf.find(HEADER)
        if start < 0:
            keep = self._header_prefix_len()
            drop = len(buf) - keep
            if drop:
                self.discarded_bytes += drop
                del buf[:drop]
            self._scanned = 0
            return False, None
        if start:
            self.discarded_bytes += start
            del buf[:start]
            self._scanned = 0
        if len(buf) < 7:
            return False, None
        packet_id = buf[4]
        length = buf[5] | (buf[6] << 8)
        if packet_id in (0xFD, 0xFF) or length < 3 or length > self.max_length:
            self._skip(1)
            return True, None
        if self.resync_on_header:
            restart = self._find_bare_header(length)
            if restart is None:
                return False, None  # need the byte after a FF FF FD
            if restart > 0:
                self.resyncs += 1
                self._skip(restart)
                return True, None
        total = 7 + length
        if len(buf) < total:
            return False, None
        frame = bytes(buf[:total])
        del buf[:total]
        self._scanned = 0
        return True, self._decode(frame)

    def _header_prefix_len(self) -> int:
        buf = self._buf
        for keep in (3, 2, 1):
            if len(buf) >= keep and buf[-keep:] == HEADER[:keep]:
                return keep
        return 0

    def _skip(self, count: int) -> None:
        self.discarded_bytes += count
        del self._buf[:count]
        self._scanned = 0

    def _find_bare_header(self, length: int) -> int | None:
        """Offset of an unstuffed FF FF FD in the stuffed region, 0 if none (yet), None to wait."""
        buf = self._buf
        region_end = 7 + length - 2  # exclusive: the CRC is not stuffed
        available = min(len(buf), region_end)
        i = max(9, 7 + self._scanned)  # index of a candidate FD (needs two FF before it)
        while True:
            triple = buf.find(_TRIPLE, i - 2, available)
            if triple < 0:
                break
            i = triple + 2  # its FD
            if i + 1 >= len(buf):
                self._scanned = i - 7
                return None
            if buf[i + 1] != _STUFF:
                return triple
            i += 2  # skip the stuffing byte
        self._scanned = max(0, available - 7)
        return 0

    def _decode(self, frame: bytes) -> ParseResult:
        packet_id = frame[4]
        instruction = frame[7]
        received = frame[-2] | (frame[-1] << 8)
        expected = crc16(frame[:-2])
        if expected != received:
            return CrcError(packet_id, instruction, frame, expected, received)
        body = frame[7:-2]
        if self.stuffed:
            try:
                body = unstuff(body)
            except StuffingError as exc:
                return MalformedPacket(packet_id, frame, str(exc))
        if instruction == Instruction.STATUS:
            if len(body) < 2:
                return MalformedPacket(packet_id, frame, "status packet without an error byte")
            return Packet(packet_id, instruction, bytes(body[2:]), body[1], frame)
        return Packet(packet_id, instruction, bytes(body[1:]), None, frame)


# -- matching a reply to its request ----------------------------------------


def reply_params_expected(instruction: int, params: bytes | bytearray | Sequence[int]) -> int:
    """How many parameters the status answering this (unicast) instruction must carry.

    PING: model number and firmware (exactly 3); READ: the length it asked
    for; every other unicast instruction: none.
    """
    if instruction == Instruction.PING:
        return 3
    if instruction == Instruction.READ:
        if len(params) < 4:
            raise ValueError(f"READ needs address and length (4 bytes), got {len(params)}")
        return params[2] | (params[3] << 8)
    return 0


def reply_mismatch(packet: Packet, sid: int, n_params: int) -> str | None:
    """Why ``packet`` cannot be servo ``sid``'s answer carrying ``n_params`` parameters.

    ``None`` when it can. A status packet carries neither the instruction nor
    a sequence number, so the ID, the status instruction and the exact
    parameter count are all a host can hold a reply to: a short reply would
    otherwise have its CRC bytes taken as data, and a late answer to another
    request would be taken as this one's.
    """
    if packet.instruction != Instruction.STATUS:
        return f"an instruction packet (0x{packet.instruction:02X}) where a status was due"
    if packet.id != sid:
        return f"a status from ID {packet.id} where ID {sid} was asked"
    if len(packet.params) != n_params:
        return (f"a status from ID {sid} with {len(packet.params)} parameter bytes where "
                f"{n_params} were asked")
    return None
