"""Protocol 2.0 framing (drivers.dynamixel.protocol) and the SDK replacements (drivers.dynamixel.io)."""

from __future__ import annotations

import os
import time
import tty

import numpy as np
import pytest
from dynamixel_sdk import Protocol2PacketHandler
from dynamixel_sdk.robotis_def import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

from drivers.dynamixel.io import BlockingPortHandler, StuffingPacketHandler
from drivers.dynamixel.parser import CrcError, MalformedPacket, Packet, PacketParser, parse_fast_status
from drivers.dynamixel.protocol import (
    ALERT_BIT,
    CRC_TABLE,
    FastStatusBlock,
    Instruction,
    StatusError,
    StuffingError,
    build_fast_status,
    build_instruction,
    build_status,
    crc16,
    decode_hardware_error,
    describe_status_error,
    stuff,
    unstuff,
)

pytestmark = pytest.mark.timeout(30)

H = bytes.fromhex


# -- CRC ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "packet",
    [
        # e-manual Protocol 2.0 examples: PING, its status, READ, its status,
        # WRITE, REBOOT, SYNC READ, BULK READ status.
        "FF FF FD 00 01 03 00 01 19 4E",
        "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D",
        "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
        "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0",
        "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
        "FF FF FD 00 01 03 00 08 2F 4E",
        "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
        "FF FF FD 00 02 05 00 55 00 24 8B A9",
    ],
)
def test_crc_matches_emanual_examples(packet: str) -> None:
    raw = H(packet)
    assert crc16(raw[:-2]) == raw[-2] | (raw[-1] << 8)


def test_crc_table_is_the_sdk_table() -> None:
    sdk = Protocol2PacketHandler()
    rng = np.random.default_rng(1)
    for _ in range(50):
        data = rng.integers(0, 256, rng.integers(0, 40)).tolist()
        assert crc16(bytes(data)) == sdk.updateCRC(0, data, len(data))
    assert CRC_TABLE[1] == 0x8005 and len(CRC_TABLE) == 256


def test_builders_reproduce_emanual_packets() -> None:
    assert build_instruction(1, Instruction.PING) == H("FF FF FD 00 01 03 00 01 19 4E")
    assert build_status(1, 0, [0x06, 0x04, 0x26]) == H("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")
    assert build_instruction(0xFE, Instruction.SYNC_READ, H("84 00 04 00 01 02")) == H(
        "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"
    )
    with pytest.raises(ValueError, match="packet ID"):
        build_instruction(0xFD, Instruction.PING)


# -- stuffing -----------------------------------------------------------------------


def test_stuffing_inserts_fd_after_header_pattern() -> None:
    # Goal Position -131073 = FF FF FD FF written to address 116.
    packet = build_instruction(1, Instruction.WRITE, H("74 00 FF FF FD FF"))
    assert packet[7:-2] == H("03 74 00 FF FF FD FD FF")
    assert packet[5] | (packet[6] << 8) == 10  # LEN counts the stuffing byte
    assert stuff(H("FF FF FD FD")) == H("FF FF FD FD FD")
    assert stuff(H("FF FF FF FD")) == H("FF FF FF FD FD")
    assert stuff(H("FF FF FD FF FF FD")) == H("FF FF FD FD FF FF FD FD")
    assert stuff(H("00 FF FF")) == H("00 FF FF")


ADVERSARIAL = [
    b"",
    H("FF"),
    H("FF FF"),
    H("FF FF FD"),
    H("FF FF FD FD"),
    H("FF FF FF FD"),
    H("FF FF FD FF FF FD"),
    H("FF FF FD FD FF FF FD FD"),
    H("FD FD FD FF FF FD"),
    H("FF FF FD 00 FF FF FD"),
    H("55 00 FF FF FD FF FD FD"),
    H("00 00 FF FF"),
]


@pytest.mark.parametrize("body", ADVERSARIAL)
def test_unstuff_inverts_stuff_adversarial(body: bytes) -> None:
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    # No unstuffed header survives stuffing.
    for i in range(len(stuffed) - 2):
        if stuffed[i : i + 3] == H("FF FF FD"):
            assert i + 3 < len(stuffed) and stuffed[i + 3] == 0xFD


def test_unstuff_inverts_stuff_random() -> None:
    rng = np.random.default_rng(7)
    alphabet = np.array([0xFF, 0xFD, 0x00, 0x55])
    for _ in range(3000):
        body = bytes(rng.choice(alphabet, rng.integers(0, 24)).tolist())
        assert unstuff(stuff(body)) == body
    for _ in range(300):
        body = bytes(rng.integers(0, 256, 64).tolist())
        assert unstuff(stuff(body)) == body


@pytest.mark.parametrize("bad", [H("FF FF FD"), H("FF FF FD 00"), H("01 FF FF FD FF")])
def test_unstuff_rejects_unstuffed_header(bad: bytes) -> None:
    with pytest.raises(StuffingError, match="FF FF FD"):
        unstuff(bad)


def test_sdk_remove_stuffing_is_not_an_exact_inverse() -> None:
    """dynamixel-sdk 4.1.0's in-place removeStuffing drops a genuine FD here."""
    body = H("55 00 FF FF FD FF FD FD")
    wire = list(build_status(1, 0, body[2:]))
    sdk = Protocol2PacketHandler().removeStuffing(wire)
    length = sdk[5] | (sdk[6] << 8)
    assert bytes(sdk[7 : 7 + length - 2]) != body
    assert unstuff(build_status(1, 0, body[2:])[7:-2]) == body


# -- hardware error and status error decoding ------------------------------------------


def test_decode_hardware_error() -> None:
    assert decode_hardware_error(0) == []
    assert decode_hardware_error(0x20) == ["overload"]
    assert decode_hardware_error(0x35) == [
        "input_voltage",
        "overheating",
        "electrical_shock",
        "overload",
    ]
    assert decode_hardware_error(0x08) == ["motor_encoder"]
    assert decode_hardware_error(0x40) == ["bit6"]
    with pytest.raises(ValueError, match="256"):
        decode_hardware_error(256)
    assert describe_status_error(StatusError.DATA_LIMIT | ALERT_BIT) == "DATA_LIMIT+ALERT"


# -- parser ----------------------------------------------------------------------------


def test_parser_byte_by_byte_with_garbage_between_packets() -> None:
    stream = (
        b"\x00\x12\xff"
        + build_instruction(1, Instruction.PING)
        + b"\xff\xff\x00"
        + build_instruction(2, Instruction.WRITE, H("74 00 FF FF FD FF"))
    )
    parser = PacketParser()
    out = []
    for byte in stream:
        out.extend(parser.feed(bytes((byte,))))
    assert [type(p) for p in out] == [Packet, Packet]
    assert out[0].id == 1 and out[0].instruction == Instruction.PING
    assert out[1].params == H("74 00 FF FF FD FF")  # unstuffed
    assert parser.pending == 0


def test_parser_reports_crc_errors() -> None:
    good = build_instruction(3, Instruction.READ, H("84 00 04 00"))
    bad = good[:-1] + bytes((good[-1] ^ 0x01,))
    out = PacketParser().feed(bad + build_instruction(3, Instruction.PING))
    assert isinstance(out[0], CrcError) and out[0].id == 3 and out[0].instruction == Instruction.READ
    assert isinstance(out[1], Packet)


def test_parser_resyncs_on_unstuffed_header_inside_a_packet() -> None:
    # What dynamixel-sdk 4.1.0 puts on the wire for Goal Position -131073.
    unstuffed = H("FF FF FD 00 01 09 00 03 74 00 FF FF FD FF")
    crc = crc16(unstuffed)
    broken = unstuffed + bytes((crc & 0xFF, crc >> 8))
    parser = PacketParser()
    assert parser.feed(broken) == []
    assert parser.resyncs == 1
    out = parser.feed(build_instruction(1, Instruction.PING))
    assert len(out) == 1 and out[0].instruction == Instruction.PING


def test_host_parser_reads_by_length_and_flags_bad_stuffing() -> None:
    unstuffed = H("FF FF FD 00 01 08 00 55 00 FF FF FD FF")
    crc = crc16(unstuffed)
    out = PacketParser(resync_on_header=False).feed(unstuffed + bytes((crc & 0xFF, crc >> 8)))
    assert len(out) == 1 and isinstance(out[0], MalformedPacket)


def test_fast_status_round_trip() -> None:
    blocks = [
        FastStatusBlock(1, 0, H("FF FF FD FF")),
        FastStatusBlock(2, 0x80, H("00 01 02 03")),
        FastStatusBlock(3, 0, H("FD FD FF FF")),
    ]
    raw = build_fast_status(blocks)
    assert raw[5] | (raw[6] << 8) == 1 + 3 * (4 + 4)  # e-manual: 3 devices x 4 bytes -> LEN 25
    (packet,) = PacketParser(stuffed=False, resync_on_header=False).feed(raw)
    assert packet.id == 0xFE and packet.error == 0
    assert parse_fast_status(packet, [4, 4, 4]) == blocks


# -- StuffingPacketHandler against a recording port ---------------------------------------


class RecordingPort:
    """Just enough of PortHandler for txPacket/rxPacket: records writes, replays reads."""

    def __init__(self, incoming: bytes = b"") -> None:
        self.is_using = False
        self.written = b""
        self.incoming = bytearray(incoming)
        self.timeouts = 0

    def clearPort(self) -> None:  # noqa: N802
        pass

    def writePort(self, packet) -> int:  # noqa: N802
        self.written += bytes(packet)
        return len(packet)

    def readPort(self, length: int) -> bytes:  # noqa: N802
        chunk = bytes(self.incoming[:length])
        del self.incoming[:length]
        return chunk

    def setPacketTimeout(self, length) -> None:  # noqa: N802
        pass

    def isPacketTimeout(self) -> bool:  # noqa: N802
        self.timeouts += 1
        return not self.incoming


def test_sdk_txpacket_sends_unstuffed_bytes_and_ours_stuffs() -> None:
    data = [0xFF, 0xFF, 0xFD, 0xFF]
    stock = RecordingPort()
    Protocol2PacketHandler().writeTxOnly(stock, 1, 116, 4, data)
    assert stock.written[7:-2] == H("03 74 00 FF FF FD FF")  # the defect: no stuffing
    assert stock.written[5] == 9

    ours = RecordingPort()
    StuffingPacketHandler().writeTxOnly(ours, 1, 116, 4, data)
    assert ours.written == build_instruction(1, Instruction.WRITE, H("74 00 FF FF FD FF"))


def test_stuffing_handler_rx_unstuffs_and_checks_crc() -> None:
    params = H("FF FF FD FF FF FF")  # Present Current -1, Present Velocity -3
    port = RecordingPort(build_status(5, 0, params))
    rx, result = StuffingPacketHandler().rxPacket(port, False)
    assert result == COMM_SUCCESS
    assert bytes(rx[9:-2]) == params and rx[5] | (rx[6] << 8) == len(params) + 4

    corrupt = bytearray(build_status(5, 0, params))
    corrupt[-1] ^= 0x55
    _, result = StuffingPacketHandler().rxPacket(RecordingPort(bytes(corrupt)), False)
    assert result == COMM_RX_CORRUPT
    _, result = StuffingPacketHandler().rxPacket(RecordingPort(b""), False)
    assert result == COMM_RX_TIMEOUT


# -- BlockingPortHandler --------------------------------------------------------------------


@pytest.fixture
def silent_pty():
    master, slave = os.openpty()
    tty.setraw(slave)
    yield os.ttyname(slave), master
    os.close(master)
    os.close(slave)


def _cpu_fraction_while_pinging(port_cls, name: str, seconds: float = 0.4) -> float:
    """CPU seconds per wall second spent pinging a servo that never answers."""
    port = port_cls(name)
    assert port.setBaudRate(1_000_000)
    handler = Protocol2PacketHandler()
    results = set()
    cpu0, wall0 = time.process_time(), time.monotonic()
    while time.monotonic() - wall0 < seconds:
        _, result, _ = handler.ping(port, 1)
        results.add(result)
    fraction = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    port.closePort()
    assert results == {COMM_RX_TIMEOUT}
    return fraction


def test_blocking_port_handler_sleeps_while_waiting(silent_pty) -> None:
    name, _ = silent_pty
    fraction = _cpu_fraction_while_pinging(BlockingPortHandler, name)
    assert fraction <= 0.3, f"BlockingPortHandler used {fraction:.2f} CPU s per wall s"


def test_blocking_port_handler_keeps_packet_timeout_semantics(silent_pty) -> None:
    name, master = silent_pty
    port = BlockingPortHandler(name)
    assert port.setBaudRate(4_500_000)  # not in the SDK's table, fine with pyserial
    port.setPacketTimeoutMillis(60)
    t0 = time.monotonic()
    assert port.readPort(5) == b""
    waited = time.monotonic() - t0
    assert 0.05 <= waited < 0.5
    assert port.isPacketTimeout()

    os.write(master, b"abcdef")
    port.setPacketTimeoutMillis(500)
    t0 = time.monotonic()
    assert port.readPort(4) == b"abcd"  # returns as soon as the bytes are there
    assert time.monotonic() - t0 < 0.2
    assert not port.isPacketTimeout()
    port.closePort()
