"""DYNAMIXEL Protocol 2.0 framing: CRC, byte stuffing, packet building and parsing.

Pure functions and one incremental parser, no I/O, so the host driver and the
servo-bus emulator frame bytes with the same code and the same rules.

Wire format (ROBOTIS e-manual, "Protocol 2.0")::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | [ERR] | PARAM... | CRC_L CRC_H

``LEN`` counts INST, ERR (status packets only), the parameters *after*
stuffing, and the two CRC bytes. Stuffing: inside the region from the
instruction byte to the last parameter, every ``FF FF FD`` is followed by an
extra ``FD`` so that a header can never appear inside a packet. The CRC is
CRC-16/BUYPASS (polynomial 0x8005, initial value 0, no reflection) over
everything from the first header byte to the last stuffed parameter.

Fast Sync Read / Fast Bulk Read status packets are the exception: the
devices append their blocks to one packet whose length was fixed by the first
device, so that packet is not stuffed and carries a running CRC after every
block (see :func:`build_fast_status`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Callable, Iterable, Sequence, Union

__all__ = [
    "ALERT_BIT",
    "BROADCAST_ID",
    "CRC_TABLE",
    "CrcError",
    "FastStatusBlock",
    "HARDWARE_ERROR_BITS",
    "HEADER",
    "Instruction",
    "MAX_ID",
    "MalformedPacket",
    "Packet",
    "PacketParser",
    "ParseResult",
    "StatusError",
    "StuffingError",
    "build_fast_status",
    "build_instruction",
    "build_status",
    "crc16",
    "decode_hardware_error",
    "describe_status_error",
    "reply_mismatch",
    "reply_params_expected",
    "parse_fast_status",
    "stuff",
    "unstuff",
]

HEADER = b"\xff\xff\xfd\x00"
_TRIPLE = b"\xff\xff\xfd"
_STUFF = 0xFD
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
#: Largest LEN field the parser accepts (the SDK's RXPACKET_MAX_LEN is 1024).
DEFAULT_MAX_LENGTH = 1024
ALERT_BIT = 0x80


class Instruction(IntEnum):
    """Instruction byte values (e-manual, Protocol 2.0 "Instruction")."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class StatusError(IntEnum):
    """Error numbers in bits 0-6 of a status packet's ERR byte."""

    NONE = 0x00
    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07


#: Hardware Error Status (address 70 on X-series) bit -> name.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "input_voltage",
    2: "overheating",
    3: "motor_encoder",
    4: "electrical_shock",
    5: "overload",
}


def decode_hardware_error(value: int) -> list[str]:
    """Names of the faults set in a Hardware Error Status byte, lowest bit first."""
    if not 0 <= value <= 0xFF:
        raise ValueError(f"hardware error status must be one byte, got {value}")
    names = [name for bit, name in sorted(HARDWARE_ERROR_BITS.items()) if value & (1 << bit)]
    unknown = value & ~sum(1 << bit for bit in HARDWARE_ERROR_BITS)
    names.extend(f"bit{bit}" for bit in range(8) if unknown & (1 << bit))
    return names


def describe_status_error(error: int) -> str:
    """Human-readable ERR byte, e.g. ``'DATA_LIMIT+ALERT'`` (empty string for 0)."""
    number = error & 0x7F
    parts = []
    if number:
        try:
            parts.append(StatusError(number).name)
        except ValueError:
            parts.append(f"UNKNOWN_{number:#04x}")
    if error & ALERT_BIT:
        parts.append("ALERT")
    return "+".join(parts)


# -- CRC ----------------------------------------------------------------------


def _make_crc_table(polynomial: int = 0x8005) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ polynomial) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE: tuple[int, ...] = _make_crc_table()


try:  # CRC-16/UMTS (BUYPASS) is the ROBOTIS CRC; fastcrc computes it in native code.
    from fastcrc.crc16 import umts as _native_crc16
except ImportError:  # pragma: no cover - fastcrc is a dependency; the table is the fallback
    _native_crc16 = None


def crc16(data: bytes | bytearray | Sequence[int], crc: int = 0) -> int:
    """ROBOTIS CRC-16 of ``data``, continuing from ``crc`` (0 starts a packet)."""
    if _native_crc16 is not None and isinstance(data, (bytes, bytearray)):
        return _native_crc16(bytes(data), crc)
    table = CRC_TABLE
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


#: :func:`crc16` of ``bytes`` without the type dispatch, for the control cycle's hot path.
crc16_bytes: Callable[[bytes, int], int] = _native_crc16 if _native_crc16 is not None else crc16


# -- stuffing -----------------------------------------------------------------


class StuffingError(ValueError):
    """A stuffed region holds ``FF FF FD`` not followed by the stuffing ``FD``."""


def stuff(body: bytes | bytearray | Sequence[int]) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` of ``body`` (instruction .. last parameter)."""
    data = bytes(body)
    if _TRIPLE not in data:
        return data
    out = bytearray()
    for i, byte in enumerate(data):
        out.append(byte)
        if byte == 0xFD and i >= 2 and data[i - 1] == 0xFF and data[i - 2] == 0xFF:
            out.append(_STUFF)
    return bytes(out)


def unstuff(body: bytes | bytearray | Sequence[int]) -> bytes:
    """Exact inverse of :func:`stuff`: drop the ``FD`` following each ``FF FF FD``.

    Raises :class:`StuffingError` when a ``FF FF FD`` is not followed by
    ``FD``: such bytes cannot have come from :func:`stuff`.
    """
    data = bytes(body)
    if _TRIPLE not in data:
        return data
    out = bytearray()
    expect_stuff = False
    for i, byte in enumerate(data):
        if expect_stuff:
            if byte != _STUFF:
                raise StuffingError(
                    f"unstuffed FF FF FD at offset {i - 3} (followed by {byte:#04x}) in {data.hex(' ')}"
                )
            expect_stuff = False
            continue
        out.append(byte)
        if byte == 0xFD and len(out) >= 3 and out[-2] == 0xFF and out[-3] == 0xFF:
            expect_stuff = True
    if expect_stuff:
        raise StuffingError(f"FF FF FD at the end without its stuffing FD in {data.hex(' ')}")
    return bytes(out)


# -- building -----------------------------------------------------------------


def _check_id(packet_id: int) -> None:
    if not (0 <= packet_id <= BROADCAST_ID) or packet_id == 0xFD:
        raise ValueError(f"packet ID must be 0..252 or 254 (broadcast), got {packet_id}")


def _frame(packet_id: int, body: bytes) -> bytes:
    length = len(body) + 2
    if length > 0xFFFF:
        raise ValueError(f"packet body of {len(body)} bytes does not fit the 16-bit LEN field")
    packet = HEADER + bytes((packet_id, length & 0xFF, length >> 8)) + body
    crc = crc16(packet)
    return packet + bytes((crc & 0xFF, crc >> 8))


def _as_bytes(params: bytes | bytearray | Iterable[int]) -> bytes:
    try:
        return bytes(params)
    except ValueError as exc:
        raise ValueError(f"parameters must be bytes 0..255, got {list(params)!r}") from exc


def build_instruction(
    packet_id: int, instruction: int, params: bytes | bytearray | Iterable[int] = b""
) -> bytes:
    """A complete, stuffed instruction packet with its CRC."""
    _check_id(packet_id)
    if not 0 <= instruction <= 0xFF:
        raise ValueError(f"instruction must be one byte, got {instruction}")
    return _frame(packet_id, stuff(bytes((instruction,)) + _as_bytes(params)))


def build_status(packet_id: int, error: int, params: bytes | bytearray | Iterable[int] = b"") -> bytes:
    """A complete, stuffed status packet (instruction 0x55) with its CRC."""
    _check_id(packet_id)
    if not 0 <= error <= 0xFF:
        raise ValueError(f"status error must be one byte, got {error}")
    return _frame(packet_id, stuff(bytes((Instruction.STATUS, error)) + _as_bytes(params)))


@dataclass(frozen=True)
class FastStatusBlock:
    """One device's block of a Fast Sync/Bulk Read status packet."""

    id: int
    error: int
    data: bytes


def build_fast_status(
    blocks: Sequence[FastStatusBlock], declared_blocks: Sequence[int] | None = None
) -> bytes:
    """The combined Fast Sync/Bulk Read status packet (ID 0xFE, not stuffed).

    Layout: header, ID FE, LEN, 0x55, then per device ``ERR ID DATA CRC``
    where each CRC is the running CRC of every byte sent so far, so the last
    block's CRC is the packet CRC. ``declared_blocks`` gives the data length
    of every device the master asked for: when some of them stay silent the
    LEN field still counts them, as the first device wrote it.
    """
    lengths = list(declared_blocks) if declared_blocks is not None else [len(b.data) for b in blocks]
    length = 1 + sum(4 + n for n in lengths)
    out = bytearray(HEADER + bytes((BROADCAST_ID, length & 0xFF, length >> 8, Instruction.STATUS)))
    for block in blocks:
        out += bytes((block.error, block.id)) + block.data
        crc = crc16(out)
        out += bytes((crc & 0xFF, crc >> 8))
    return bytes(out)


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
