"""The control cycle's two transactions, lean: one Sync Write of goals, one (Fast) Sync Read of state.

The bytes on the wire are exactly those of dynamixel-sdk's ``GroupSyncWrite``
and ``GroupSyncRead`` (``fastSyncRead``) — a test holds them equal — but built
and parsed here without the SDK's per-byte list handling, so the driver spends
a small fraction of the wire time in Python and sleeps in the kernel while it
waits. Stuffing is applied on send and undone on receive; the Fast Sync Read
status is not stuffed (as the firmware sends it).
"""

from __future__ import annotations

import os
import select
import struct
import time
from itertools import chain
from typing import Sequence

from drivers import CommunicationError
from drivers.dxl_protocol import (
    BROADCAST_ID, HEADER, Instruction, PacketParser, build_instruction, crc16,
)

_STATUS = Instruction.STATUS
_TRIPLE = b"\xff\xff\xfd"  # a header inside the parameters: the packet needs stuffing
_FAST_HEAD = HEADER + bytes((BROADCAST_ID,))


class SyncCycle:
    """Goal-position writes and state reads for a fixed set of servo IDs on one port."""

    def __init__(self, fd: int, baud: int, ids: Sequence[int], *, read_address: int = 126,
                 read_length: int = 10, write_address: int = 116, fast: bool = True,
                 latency_s: float = 0.002) -> None:
        self.fd = fd
        self.ids = list(ids)
        self.n = len(self.ids)
        self.read_address, self.read_length = read_address, read_length
        self.write_address = write_address
        self.fast = fast
        params = struct.pack("<HH", read_address, read_length) + bytes(self.ids)
        instr = Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ
        self._read_packet = build_instruction(BROADCAST_ID, instr, params)
        self._write_head = struct.pack("<HH", write_address, 4)
        self._goals = struct.Struct("<" + "Bi" * self.n)
        # Everything before the parameters of an unstuffed Sync Write (LEN is fixed then).
        length = 1 + len(self._write_head) + self._goals.size + 2
        self._write_prefix = HEADER + bytes(
            (BROADCAST_ID, length & 0xFF, length >> 8, Instruction.SYNC_WRITE))
        # ERR, ID, data and running CRC of each block of a Fast Sync Read status
        self._fast_blocks = struct.Struct("<8x" + f"BB{read_length}sH" * self.n)
        if fast:
            self._expect = 8 + self.n * (4 + read_length)
        else:
            self._expect = self.n * (11 + read_length)
        self._byte_time = 10.0 / baud
        # Late answers are expected after this long: wire time of the reply, plus slack.
        self.timeout_s = latency_s + 3 * (self._expect + len(self._read_packet)) * self._byte_time + 0.003
        self.last_error = ""

    # -- send -----------------------------------------------------------------
    def write_goals(self, ticks: Sequence[int]) -> None:
        """One Sync Write of Goal Position (4 bytes each) to every servo; no reply."""
        params = self._write_head + self._goals.pack(*chain.from_iterable(zip(self.ids, ticks)))
        if _TRIPLE in params:  # rare (e.g. Goal Position -131073): stuffing changes LEN
            packet = build_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, params)
        else:
            packet = self._write_prefix + params
            crc = crc16(packet)
            packet += bytes((crc & 0xFF, crc >> 8))
        self._send(packet)

    def _send(self, packet: bytes) -> None:
        view = memoryview(packet)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 0.01)
                continue
            except OSError as e:
                raise CommunicationError(f"writing to the servo port failed: {e}") from None
            view = view[n:]

    # -- receive ----------------------------------------------------------------
    def read_state(self) -> list[bytes] | None:
        """Send the (Fast) Sync Read and return each servo's data block, or None on failure.

        On failure ``last_error`` says what went wrong (timeout, CRC, servo error).
        """
        self._drain()
        self._send(self._read_packet)
        raw = self._receive(self._expect)
        if raw is None:
            return None
        return self._parse_fast(raw) if self.fast else self._parse_sync(raw)

    def _drain(self) -> None:
        """Drop bytes left from an earlier, failed transaction."""
        while select.select([self.fd], [], [], 0)[0]:
            try:
                if not os.read(self.fd, 4096):
                    return
            except (BlockingIOError, OSError):
                return

    def _receive(self, length: int) -> bytes | None:
        buf = b""
        deadline = time.monotonic() + self.timeout_s
        fd = self.fd
        while len(buf) < length:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            if not select.select([fd], [], [], remaining)[0]:
                break
            try:
                chunk = os.read(fd, 4096)
            except BlockingIOError:
                continue
            except OSError:
                break
            if not chunk:
                break
            buf = buf + chunk if buf else chunk  # usually one chunk: no copy
        if len(buf) < length:
            self.last_error = (f"timeout: {len(buf)} of {length} status bytes within "
                               f"{self.timeout_s * 1e3:.1f} ms")
            return None
        return buf

    def _parse_fast(self, raw: bytes) -> list[bytes] | None:
        n, L = self.n, self.read_length
        if raw[:5] != _FAST_HEAD or raw[7] != _STATUS:
            self.last_error = "fast sync read: bad header"
            return None
        declared = raw[5] | (raw[6] << 8)
        if declared != 1 + n * (4 + L):
            self.last_error = f"fast sync read: length {declared}, expected {1 + n * (4 + L)}"
            return None
        fields = self._fast_blocks.unpack_from(raw)
        blocks = []
        crc, counted, end = 0, 0, 8 + 2 + L  # running CRC of raw[:counted]; end of block k
        for k, sid in enumerate(self.ids):
            err, bid, data, block_crc = fields[4 * k : 4 * k + 4]
            # each block's CRC is the running CRC of every byte before it
            crc = crc16(raw[counted:end], crc)
            if block_crc != crc:
                self.last_error = f"fast sync read: CRC error in the block of servo {sid}"
                return None
            if bid != sid:
                self.last_error = f"fast sync read: block {k} is from ID {bid}, expected {sid}"
                return None
            if err & 0x7F:
                self.last_error = f"servo {sid} answered with error 0x{err:02X}"
                return None
            blocks.append(data)
            counted, end = end, end + 4 + L
        return blocks

    def _parse_sync(self, raw: bytes) -> list[bytes] | None:
        L = self.read_length
        size = 11 + L
        blocks = []
        for k, sid in enumerate(self.ids):
            p = raw[k * size:(k + 1) * size]
            if p[:4] != HEADER or p[4] != sid or (p[5] | (p[6] << 8)) != L + 4 or p[7] != _STATUS \
                    or crc16(p[:-2]) != (p[-2] | (p[-1] << 8)):
                return self._parse_sync_slow(raw)
            if p[8] & 0x7F:
                self.last_error = f"servo {sid} answered with error 0x{p[8]:02X}"
                return None
            blocks.append(p[9:9 + L])
        return blocks

    def _parse_sync_slow(self, raw: bytes) -> list[bytes] | None:
        """Stuffed or out-of-step statuses: the full parser (reads the rest of the bytes)."""
        parser = PacketParser(stuffed=True, resync_on_header=True)
        got: dict[int, bytes] = {}
        data = raw
        deadline = time.monotonic() + self.timeout_s
        while True:
            for ev in parser.feed(data):
                params = getattr(ev, "params", None)
                if params is not None and getattr(ev, "instruction", None) == _STATUS:
                    if ev.error and ev.error & 0x7F:
                        self.last_error = f"servo {ev.id} answered with error 0x{ev.error:02X}"
                        return None
                    got[ev.id] = params
                elif params is None:
                    self.last_error = f"sync read: {type(ev).__name__}"
                    return None
            if all(sid in got for sid in self.ids):
                return [got[sid][:self.read_length] for sid in self.ids]
            more = self._receive_more(deadline)
            if not more:
                missing = [sid for sid in self.ids if sid not in got]
                self.last_error = f"sync read: no status from servo(s) {missing}"
                return None
            data = more

    def _receive_more(self, deadline: float) -> bytes:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not select.select([self.fd], [], [], remaining)[0]:
            return b""
        try:
            return os.read(self.fd, 4096)
        except OSError:
            return b""


def unpack_state(blocks: list[bytes]) -> tuple[list[int], list[int], list[int]]:
    """Present Current (int16), Velocity (int32), Position (int32) of each servo's 10-byte block."""
    current, velocity, position = [], [], []
    for b in blocks:
        c, v, p = struct.unpack_from("<hii", b)
        current.append(c)
        velocity.append(v)
        position.append(p)
    return current, velocity, position
