"""The driver's lean control-cycle transactions put the SDK group classes' bytes on the wire."""

from __future__ import annotations

import os
import struct

import dynamixel_sdk as sdk
import pytest

from drivers.dynamixel.cycle import SyncCycle
from drivers.dynamixel.io import StuffingPacketHandler
from drivers.dynamixel.protocol import FastStatusBlock, build_fast_status, build_status
from drivers.link import FdLink

IDS = list(range(1, 10))


class RecordingPort:
    """Just enough of a PortHandler for the SDK's tx path."""

    is_using = False

    def __init__(self) -> None:
        self.sent = b""

    def clearPort(self):  # noqa: N802
        pass

    def writePort(self, packet):  # noqa: N802
        self.sent += bytes(packet)
        return len(packet)

    def setPacketTimeout(self, length):  # noqa: N802
        pass


@pytest.fixture
def pipe():
    r, w = os.pipe()
    yield r, w
    os.close(r)
    os.close(w)


def captured(fd_read: int) -> bytes:
    return os.read(fd_read, 65536)


@pytest.mark.parametrize("ticks", [[2048] * 9, [-131073] + [2048] * 8, list(range(0, 9000, 1000))])
def test_sync_write_bytes_equal_the_sdk_group_sync_write(pipe, ticks):
    r, w = pipe
    SyncCycle(w, 1_000_000, IDS).write_goals(ticks)
    ours = captured(r)
    port = RecordingPort()
    group = sdk.GroupSyncWrite(port, StuffingPacketHandler(), 116, 4)
    for sid, t in zip(IDS, ticks):
        group.addParam(sid, list((t & 0xFFFFFFFF).to_bytes(4, "little")))
    group.txPacket()
    assert ours == port.sent
    if ticks[0] == -131073:  # FF FF FD FF in the goal: the stuffed packet is one byte longer
        assert b"\xff\xff\xfd\xfd" in ours


@pytest.mark.parametrize("fast", [False, True])
def test_sync_read_instruction_equals_the_sdk(pipe, fast):
    r, w = pipe
    cyc = SyncCycle(w, 1_000_000, IDS, fast=fast, latency_s=0.0)
    cyc.timeout_s = 0.001
    assert cyc.read_state() is None  # nobody answers a pipe
    ours = captured(r)
    port = RecordingPort()
    group = sdk.GroupSyncRead(port, StuffingPacketHandler(), 126, 10)
    for sid in IDS:
        group.addParam(sid)
    (group.fastSyncReadTxPacket if fast else group.txPacket)()
    assert ours == port.sent


def state_block(current: int, velocity: int, position: int) -> bytes:
    return struct.pack("<hii", current, velocity, position)


def respond(cycle: SyncCycle, status: bytes) -> list | None:
    """Feed a status into the cycle's receive path through a pipe."""
    r, w = os.pipe()
    try:
        os.write(w, status)
        cycle.link = FdLink(r)
        cycle._drain = lambda: None  # the answer is already waiting
        cycle._send = lambda packet: None
        return cycle.read_state()
    finally:
        os.close(r)
        os.close(w)


def test_fast_status_parsed_and_crc_checked():
    cyc = SyncCycle(-1, 1_000_000, IDS, fast=True)
    values = [(-1, -3, -131073 + i) for i in range(9)]
    raw = build_fast_status([FastStatusBlock(i, 0, state_block(*v)) for i, v in zip(IDS, values)])
    state = respond(cyc, raw)
    assert state is not None
    pos, vel, cur = state
    assert list(zip(cur, vel, pos)) == values
    for byte in (10, 40, 133):  # a data byte early, one mid-packet, the last block's CRC
        bad = bytearray(raw)
        bad[byte] ^= 0x01
        cyc = SyncCycle(-1, 1_000_000, IDS, fast=True)
        assert respond(cyc, bytes(bad)) is None
        assert "CRC" in cyc.last_error


def test_stuffed_sync_read_statuses_arrive_intact():
    """Present Current -1 then Present Velocity -3 holds FF FF FD: those statuses are stuffed."""
    cyc = SyncCycle(-1, 1_000_000, IDS, fast=False)
    data = state_block(-1, -3, 2048)
    assert b"\xff\xff\xfd" in data
    status = b"".join(build_status(i, 0, data) for i in IDS)
    assert len(status) > 9 * 21  # stuffing added bytes
    state = respond(cyc, status)
    assert state is not None
    assert state.T.tolist() == [[2048, -3, -1]] * 9


def test_servo_error_in_a_status_is_reported():
    cyc = SyncCycle(-1, 1_000_000, IDS, fast=False)
    status = b"".join(build_status(i, 0x80 | (7 if i == 4 else 0), state_block(0, 0, 2048)) for i in IDS)
    assert respond(cyc, status) is None
    assert "servo 4" in cyc.last_error


def test_sync_read_statuses_parsed_and_each_crc_checked():
    values = [(i - 5, -3 * i, 2048 + 100 * i) for i in IDS]
    status = b"".join(build_status(i, 0, state_block(*v)) for i, v in zip(IDS, values))
    state = respond(SyncCycle(-1, 1_000_000, IDS, fast=False), status)
    assert state is not None
    assert [tuple(int(x) for x in col[::-1]) for col in state.T] == values
    bad = bytearray(status)
    bad[21 * 6 + 12] ^= 0x10  # a data byte of the seventh servo's status
    cyc = SyncCycle(-1, 1_000_000, IDS, fast=False)
    assert respond(cyc, bytes(bad)) is None
    assert "Crc" in cyc.last_error


def test_servo_error_in_a_fast_status_is_reported():
    blocks = [FastStatusBlock(i, 0x80 | (6 if i == 8 else 0), state_block(0, 0, 2048)) for i in IDS]
    cyc = SyncCycle(-1, 1_000_000, IDS, fast=True)
    assert respond(cyc, build_fast_status(blocks)) is None
    assert "servo 8" in cyc.last_error and "0x86" in cyc.last_error
