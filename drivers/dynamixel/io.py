"""Drop-in replacements for two dynamixel-sdk classes that misbehave on the wire.

* :class:`StuffingPacketHandler` — ``Protocol2PacketHandler.txPacket`` in
  dynamixel-sdk 4.1.0 calls ``addStuffing`` but throws the stuffed copy away
  whenever stuffing changes the length, so an instruction whose parameters
  hold ``FF FF FD`` (e.g. Goal Position -131073 = ``FF FF FD FF``) goes out
  unstuffed and a servo re-synchronises on the bogus header inside it. This
  subclass frames with :mod:`drivers.dynamixel.protocol` both ways; the SDK's group
  classes (GroupSyncRead/Write, GroupBulkRead/Write, fast sync/bulk read)
  work through it unchanged because it keeps the SDK's list-based
  ``txPacket``/``rxPacket`` contract. Its ``txRxPacket`` never trusts a
  reply: the status must come from the ID asked, with exactly the
  parameters asked for (3 for a PING), and nothing after it; anything else
  is ``COMM_RX_CORRUPT`` (the SDK otherwise hands a short reply's CRC bytes
  to the caller as register values), and after any failure the line is
  drained until quiet so a late answer cannot pass for the next one.
* :class:`BlockingPortHandler` — the SDK's ``PortHandler`` opens the port with
  ``timeout=0`` and the packet handler spins on ``readPort`` until the packet
  deadline, burning a core per bus. This subclass waits on the port's
  :class:`~drivers.link.Link` (the kernel's ``select`` on a real port) until
  bytes arrive or the SDK's packet deadline passes. It opens the port by URL,
  so the same handler talks to an emulated line on a virtual clock, whose
  deadlines are that clock's.
"""

from __future__ import annotations

import os
from typing import Sequence

from dynamixel_sdk import PortHandler, Protocol2PacketHandler
from dynamixel_sdk.protocol2_packet_handler import (
    PKT_ERROR,
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
    INST_ACTION,
    INST_BULK_READ,
    INST_SYNC_READ,
    MAX_ID,
)

from drivers import CommunicationError, BackendSetupError
from drivers.dynamixel.identity import EMULATED_ADDRESS, EMULATED_LENGTH, is_emulated_reply
from drivers.dynamixel.parser import Packet, PacketParser, reply_mismatch, reply_params_expected
from drivers.dynamixel.protocol import HEADER, Instruction, build_instruction
from drivers.clock import WALL, Clock
from drivers.link import Link, drain_until_quiet, is_virtual_port, link_of, open_port

__all__ = ["BlockingPortHandler", "RegisterAccess", "StuffingPacketHandler", "port_hint"]


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

    #: Why the last unicast transaction failed (empty after a success).
    last_problem: str = ""
    _last_packet: Packet | None = None

    def txRxPacket(  # noqa: N802 - SDK name
        self, port: PortHandler, txpacket: list[int]
    ) -> tuple[list[int] | None, int, int]:
        sid, instruction = txpacket[PKT_ID], txpacket[PKT_INSTRUCTION]
        if sid == BROADCAST_ID or instruction in (INST_ACTION, INST_BULK_READ, INST_SYNC_READ):
            return super().txRxPacket(port, txpacket)  # no single status to check
        length = txpacket[PKT_LENGTH_L] | (txpacket[PKT_LENGTH_H] << 8)
        try:
            wanted = reply_params_expected(instruction, txpacket[PKT_INSTRUCTION + 1:
                                                                 PKT_INSTRUCTION + length - 2])
        except ValueError:
            return None, COMM_TX_ERROR, 0
        result = self.txPacket(port, txpacket)
        if result != COMM_SUCCESS:
            return None, result, 0
        port.setPacketTimeout(wanted + 11)  # as the SDK: the reply's bytes plus latency
        self._last_packet = None
        rxpacket, result = self.rxPacket(port, False, accept_id=sid)
        packet = self._last_packet
        if result == COMM_SUCCESS and packet is not None:
            problem = reply_mismatch(packet, sid, wanted)
            if problem is None and _pending(port):
                problem = f"bytes after the status from ID {sid} (a duplicated or late reply)"
        else:
            problem = "no reply" if result == COMM_RX_TIMEOUT else "a corrupt reply"
        if problem is not None:
            self.last_problem = problem
            _quiet_line(port)
            return [], (COMM_RX_TIMEOUT if result == COMM_RX_TIMEOUT else COMM_RX_CORRUPT), 0
        self.last_problem = ""
        return rxpacket, COMM_SUCCESS, rxpacket[PKT_ERROR]

    def rxPacket(  # noqa: N802 - SDK name
        self, port: PortHandler, fast_option: bool, accept_id: int | None = None
    ) -> tuple[list[int], int]:
        """One status frame; with ``accept_id`` the first status of any ID, for the caller to check."""
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
                    if event.instruction != Instruction.STATUS or (
                            accept_id is None and event.id > max_id):
                        continue  # not an answer (an echo, say); keep listening, as the SDK does
                    self._last_packet = event
                    rxpacket = list(event.raw) if fast_option else _sdk_layout(event)
                    result = COMM_SUCCESS
                    break
            if result is None and timed_out:
                result = COMM_RX_CORRUPT if received_any else COMM_RX_TIMEOUT
        port.is_using = False
        return rxpacket, result


def _pending(port: PortHandler) -> bool:
    """Bytes already waiting after a reply: a servo sends one status per request, never more."""
    link = getattr(port, "link", None)
    return link is not None and link.waiting()


def _quiet_line(port: PortHandler) -> None:
    """After a failed transaction: wait (bounded) for the line to fall silent."""
    link = getattr(port, "link", None)
    if link is None:
        return
    quiet_s = max(float(getattr(port, "packet_timeout", 0.0)) / 1000.0, 0.002)
    try:
        drain_until_quiet(link, quiet_s, 4 * quiet_s)
    except (OSError, ValueError):
        pass


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
    2 x 16 ms latency + 2 ms) is inherited unchanged, on the link's clock (the
    monotonic clock on a real port). Any positive baud rate is accepted (pyserial
    sets custom rates), so 4.5 Mbps works where the SDK's table refuses it.
    """

    #: The open port's link (None while closed).
    link: Link | None = None

    @property
    def clock(self) -> Clock:
        """The clock the port keeps time by (the wall clock on a real port)."""
        return self.link.clock if self.link is not None else WALL

    def getCurrentTime(self) -> float:  # noqa: N802 - SDK name
        return self.clock.now() * 1000.0

    def getCFlagBaud(self, baudrate: int) -> int:  # noqa: N802 - SDK name
        return int(baudrate) if int(baudrate) > 0 else -1

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - SDK name
        if self.is_open:
            self.closePort()
        self.ser = open_port(self.port_name, self.baudrate)
        self.link = link_of(self.ser, "dynamixel")
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def _deadline_s(self) -> float:
        """The clock's time (s) at which the current packet times out."""
        return (self.packet_start_time + self.packet_timeout) / 1000.0

    def isPacketTimeout(self) -> bool:  # noqa: N802 - SDK name
        # At or past the deadline the wait of readPort ended on: a virtual clock lands on it exactly
        # (the SDK's strict ">" would then never time out), a wall clock just past it.
        if self.clock.now() >= self._deadline_s():
            self.packet_timeout = 0
            return True
        return False

    def closePort(self) -> None:  # noqa: N802 - SDK name
        super().closePort()
        self.link = None

    def writePort(self, packet) -> int:  # noqa: N802 - SDK name
        """The packet on the line through the link (a wire capture holds it); the bytes written."""
        if self.link is None:
            return 0
        data = bytes(packet)
        try:
            self.link.send(data)
        except (OSError, ValueError):
            return 0
        return len(data)

    def readPort(self, length: int) -> bytes:  # noqa: N802 - SDK name
        if length <= 0 or self.link is None:
            return b""
        link = self.link
        deadline = self._deadline_s()
        buf = bytearray()
        while len(buf) < length:
            if not link.wait(deadline):
                break
            try:
                chunk = link.take(length - len(buf))
            except OSError:
                break
            if not chunk:
                break  # the other end went away: report what arrived, the SDK times out
            buf += chunk  # past the deadline the wait no longer waits: drain, then stop
        return bytes(buf)


#: After a failed register access, the line must be silent this long before the next try (s), a
#: late answer dropped meanwhile; one later still is caught by the confirming read ...
SETTLE_QUIET_S = 0.02
#: ... but never more than this in all, so a babbling peer cannot hold the host.
SETTLE_MAX_S = 0.5


class RegisterAccess:
    """Register reads and writes on one port, each retried, each reply checked by the handler.

    A read returns the value the servo sent for exactly that register, or raises
    :class:`~drivers.CommunicationError` saying what was wrong with the replies;
    a servo refusing a write is a :class:`~drivers.BackendSetupError`.
    """

    def __init__(self, port: PortHandler, handler: StuffingPacketHandler, retries: int) -> None:
        self.port, self.ph, self.tries = port, handler, max(0, int(retries)) + 1

    def ping_all(self, ids: Sequence[int], tries: int) -> dict[int, tuple[int | None, str]]:
        """Each servo's model number (None if no good answer in ``tries``) and why not, in rounds: a
        round pings every servo still silent, then waits a little longer than the last (a bus just
        plugged in may be slow). After a round that no servo answered, the next asks one servo first
        and the others only once it answers: a dead bus costs one timeout a round, not one a servo."""
        found: dict[int, tuple[int | None, str]] = {sid: (None, "") for sid in ids}
        heard = True
        for attempt in range(tries):
            silent = [sid for sid, (model, _) in found.items() if model is None]
            if not silent:
                break
            if attempt:
                self.port.clock.sleep(0.01 * attempt)
            answered = False
            for sid in silent:
                model, result, err = self.ph.ping(self.port, sid)
                if result == COMM_SUCCESS and not err & 0x7F:
                    found[sid], answered = (model, ""), True
                else:  # error bits 1-7: the instruction failed, whatever the parameters say
                    found[sid] = (None, f"a reply with error bits ({self.ph.getRxPacketError(err)})"
                                  if result == COMM_SUCCESS else self.ph.last_problem)
                    answered = answered or result == COMM_SUCCESS
                if not (heard or answered):  # the bus was silent and still is: probe again later
                    break
            heard = answered
        return found

    def read(self, sid: int, address: int, size: int, what: str, signed: bool = False) -> int:
        """The register's value. After a failed try the line is left to fall quiet for longer than
        a transaction's timeout, and a value counts only once two reads in a row agree: a servo that
        was held up (a loaded host, a busy bus) answers the failed try late, and Protocol 2.0's
        status names no register, so a 1-byte register's late answer passes for another's. A wrong
        Torque Enable or Operating Mode decides what set-up writes."""
        result, failed, candidate = COMM_TX_FAIL, False, None
        for _ in range(self.tries + 1):  # the one more is a confirmation's
            data, result, err = self.ph.readTxRx(self.port, sid, address, size)
            if result == COMM_SUCCESS and err & 0x7F:  # refused: the parameters are not the register
                raise BackendSetupError(f"servo ID {sid}: reading {what} refused: "
                                        f"{self.ph.getRxPacketError(err)}")
            if result != COMM_SUCCESS:
                failed, candidate = True, None
                self._settle()
                continue
            value = int.from_bytes(bytes(data), "little", signed=signed)
            if not failed or value == candidate:
                return value
            candidate = value
            self._settle()
        why = ("its answers after a failed try did not agree" if result == COMM_SUCCESS
               else self._why(result))
        raise CommunicationError(f"servo ID {sid}: reading {what} failed after {self.tries} tries: {why}")

    def _settle(self) -> None:
        """Wait (bounded) for a quiet line: a late answer to an earlier try is read and dropped."""
        link = getattr(self.port, "link", None)
        if link is not None:
            try:
                drain_until_quiet(link, SETTLE_QUIET_S, SETTLE_MAX_S)
            except (OSError, ValueError):
                pass

    def says_emulated(self, sid: int) -> bool:
        """Whether servo ``sid`` answers the identity READ as only the emulator does (one try:
        a real servo's refusal is immediate and is the answer; see :mod:`drivers.dynamixel.identity`)."""
        data, result, err = self.ph.readTxRx(self.port, sid, EMULATED_ADDRESS, EMULATED_LENGTH)
        return result == COMM_SUCCESS and is_emulated_reply(err, bytes(data))

    def write(self, sid: int, address: int, size: int, value: int, what: str) -> None:
        data = list((int(value) & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))
        result = COMM_TX_FAIL
        for _ in range(self.tries):
            result, err = self.ph.writeTxRx(self.port, sid, address, size, data)
            if result == COMM_SUCCESS:
                if err & 0x7F:
                    raise BackendSetupError(f"servo ID {sid}: writing {what} = {value} refused: "
                                             f"{self.ph.getRxPacketError(err)}")
                return
            self._settle()
        raise CommunicationError(f"servo ID {sid}: writing {what} failed after {self.tries} "
                                 f"tries: {self._why(result)}")

    def _why(self, result: int) -> str:
        """The SDK's words for a failed transaction, with what was wrong with the reply."""
        text = self.ph.getTxRxResult(result)
        return f"{text} ({self.ph.last_problem})" if self.ph.last_problem else text


def port_hint(port: str) -> str:
    """What to do about a serial port that would not open (missing, no permission), or ""."""
    if is_virtual_port(port):
        return ""
    if not os.path.exists(port):
        return " (is the adapter plugged in? rehearse without hardware with --emulate)"
    if not os.access(port, os.R_OK | os.W_OK):
        return " (no permission: add yourself to the dialout group, `sudo usermod -aG dialout $USER`)"
    return ""
