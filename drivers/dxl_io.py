"""Drop-in replacements for two dynamixel-sdk classes that misbehave on the wire.

* :class:`StuffingPacketHandler` — ``Protocol2PacketHandler.txPacket`` in
  dynamixel-sdk 4.1.0 calls ``addStuffing`` but throws the stuffed copy away
  whenever stuffing changes the length, so an instruction whose parameters
  hold ``FF FF FD`` (e.g. Goal Position -131073 = ``FF FF FD FF``) goes out
  unstuffed and a servo re-synchronises on the bogus header inside it. This
  subclass frames with :mod:`drivers.dxl_protocol` both ways; the SDK's group
  classes (GroupSyncRead/Write, GroupBulkRead/Write, fast sync/bulk read)
  work through it unchanged because it keeps the SDK's list-based
  ``txPacket``/``rxPacket`` contract.
* :class:`BlockingPortHandler` — the SDK's ``PortHandler`` opens the port with
  ``timeout=0`` and the packet handler spins on ``readPort`` until the packet
  deadline, burning a core per bus. This subclass sleeps in ``select`` until
  bytes arrive or the SDK's packet deadline passes.
"""

from __future__ import annotations

import os
import select
import time

import serial
from dynamixel_sdk import PortHandler, Protocol2PacketHandler
from dynamixel_sdk.protocol2_packet_handler import (
    PKT_ID,
    PKT_INSTRUCTION,
    PKT_LENGTH_H,
    PKT_LENGTH_L,
    RXPACKET_MAX_LEN,
    TXPACKET_MAX_LEN,
)
from dynamixel_sdk.robotis_def import (
    BROADCAST_ID,
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    COMM_TX_ERROR,
    COMM_TX_FAIL,
    MAX_ID,
)

from drivers.dxl_protocol import (
    HEADER,
    Instruction,
    Packet,
    PacketParser,
    build_instruction,
)

__all__ = ["BlockingPortHandler", "StuffingPacketHandler"]


class StuffingPacketHandler(Protocol2PacketHandler):
    """``Protocol2PacketHandler`` that stuffs what it sends and unstuffs what it receives.

    ``txPacket`` takes the SDK's unstuffed list (header placeholders, ID, LEN,
    INST, params) and writes the correctly stuffed packet; the list's
    parameters are left untouched because the SDK reads them back afterwards
    (e.g. the READ length that sets the packet timeout). ``rxPacket`` reads
    exactly one frame by its LEN field, checks the CRC and returns the SDK's
    list layout with the parameters unstuffed — except for Fast Sync/Bulk
    Read replies (``fast_option=True``), which are not stuffed on the wire
    and are returned raw for the SDK's positional parsing.
    """

    def txPacket(self, port: PortHandler, txpacket: list[int]) -> int:  # noqa: N802 - SDK name
        if port.is_using:
            return COMM_PORT_BUSY
        port.is_using = True

        length = txpacket[PKT_LENGTH_L] | (txpacket[PKT_LENGTH_H] << 8)
        body = txpacket[PKT_INSTRUCTION : PKT_INSTRUCTION + length - 2]
        if length < 3 or len(body) != length - 2:
            port.is_using = False
            return COMM_TX_ERROR
        try:
            packet = build_instruction(txpacket[PKT_ID], body[0], body[1:])
        except ValueError:
            port.is_using = False
            return COMM_TX_ERROR
        if len(packet) > TXPACKET_MAX_LEN:
            port.is_using = False
            return COMM_TX_ERROR
        txpacket[0:4] = HEADER  # as the SDK does; nothing reads the CRC slots back

        port.clearPort()
        if port.writePort(packet) != len(packet):
            port.is_using = False
            return COMM_TX_FAIL
        return COMM_SUCCESS

    def rxPacket(  # noqa: N802 - SDK name
        self, port: PortHandler, fast_option: bool
    ) -> tuple[list[int], int]:
        max_id = BROADCAST_ID if fast_option else MAX_ID
        parser = PacketParser(
            stuffed=not fast_option, resync_on_header=False, max_length=RXPACKET_MAX_LEN
        )
        rxpacket: list[int] = []
        received_any = False
        result = None
        while result is None:
            # Checked before reading, so bytes already waiting get one last read
            # after the deadline instead of being reported as a timeout.
            timed_out = port.isPacketTimeout()
            data = port.readPort(parser.bytes_wanted())
            if data:
                received_any = True
                for event in parser.feed(data):
                    if not isinstance(event, Packet):
                        result = COMM_RX_CORRUPT  # bad CRC or bad stuffing
                        break
                    if event.instruction != Instruction.STATUS or event.id > max_id:
                        continue  # not an answer for us; keep listening, as the SDK does
                    rxpacket = list(event.raw) if fast_option else _sdk_layout(event)
                    result = COMM_SUCCESS
                    break
            if result is None and timed_out:
                result = COMM_RX_CORRUPT if received_any else COMM_RX_TIMEOUT
        port.is_using = False
        return rxpacket, result


def _sdk_layout(packet: Packet) -> list[int]:
    """Status packet as the SDK's list: header, ID, unstuffed LEN, INST, ERR, params, CRC."""
    body = bytes((packet.instruction, packet.error or 0)) + packet.params
    length = len(body) + 2
    return list(HEADER + bytes((packet.id, length & 0xFF, length >> 8)) + body + packet.raw[-2:])


class BlockingPortHandler(PortHandler):
    """``PortHandler`` whose ``readPort`` sleeps in the kernel instead of polling.

    ``readPort(length)`` returns as soon as ``length`` bytes have arrived or
    the packet deadline set by ``setPacketTimeout``/``setPacketTimeoutMillis``
    has passed, whichever is first; with no deadline pending it returns what
    is already buffered. The SDK's timeout arithmetic (per-byte time plus
    2 x 16 ms latency + 2 ms) is inherited unchanged, on a monotonic clock.
    Any positive baud rate is accepted (pyserial sets custom rates), so
    4.5 Mbps works where the SDK's table refuses it.
    """

    def getCurrentTime(self) -> float:  # noqa: N802 - SDK name
        return time.monotonic() * 1000.0

    def getCFlagBaud(self, baudrate: int) -> int:  # noqa: N802 - SDK name
        return int(baudrate) if int(baudrate) > 0 else -1

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - SDK name
        if self.is_open:
            self.closePort()
        self.ser = serial.Serial(
            port=self.port_name,
            baudrate=self.baudrate,
            bytesize=serial.EIGHTBITS,
            timeout=0,
        )
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def _deadline_s(self) -> float:
        """Monotonic time (s) at which the current packet times out."""
        return (self.packet_start_time + self.packet_timeout) / 1000.0

    def readPort(self, length: int) -> bytes:  # noqa: N802 - SDK name
        if length <= 0:
            return b""
        fd = self.ser.fileno()
        deadline = self._deadline_s()
        buf = bytearray()
        while len(buf) < length:
            remaining = deadline - time.monotonic()
            try:
                ready, _, _ = select.select([fd], [], [], max(0.0, remaining))
            except InterruptedError:  # pragma: no cover - PEP 475 retries already
                continue
            if not ready:
                break
            try:
                chunk = os.read(fd, length - len(buf))
            except BlockingIOError:
                continue
            except OSError:
                break  # the other end went away: report what arrived, the SDK times out
            if not chunk:
                break
            buf += chunk  # past the deadline select() no longer waits: drain, then stop
        return bytes(buf)
