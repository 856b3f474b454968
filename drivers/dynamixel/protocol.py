"""DYNAMIXEL Protocol 2.0 framing: CRC, byte stuffing and packet building (parsing: :mod:`.parser`).

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
from typing import Callable, Iterable, Sequence

from drivers.errors import StuffingError

__all__ = [
    "ALERT_BIT",
    "BROADCAST_ID",
    "CRC_TABLE",
    "FastStatusBlock",
    "HARDWARE_ERROR_BITS",
    "HEADER",
    "Instruction",
    "MAX_ID",
    "StatusError",
    "StuffingError",
    "build_fast_status",
    "build_instruction",
    "build_status",
    "crc16",
    "decode_hardware_error",
    "describe_status_error",
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
