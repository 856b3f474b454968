"""The control cycle's two transactions, lean: one Sync Write of goals, one (Fast) Sync Read of state.

The bytes on the wire are exactly those of dynamixel-sdk's ``GroupSyncWrite``
and ``GroupSyncRead`` (``fastSyncRead``) — a test holds them equal — but built
and parsed here without the SDK's per-byte list handling, so the driver spends
a small fraction of the wire time in Python and sleeps in the kernel while it
waits (on a real port; on an emulated line on a virtual clock its waits advance
that clock: :mod:`drivers.link`). Stuffing is applied on send and undone on receive; the Fast Sync Read
status is not stuffed (as the firmware sends it).
"""

from __future__ import annotations

import struct
from typing import Sequence

import numpy as np

from drivers import CommunicationError
from drivers.dynamixel.control_table import state_block, x_series_table
from drivers.dynamixel.parser import Packet, PacketParser, reply_mismatch
from drivers.dynamixel.protocol import BROADCAST_ID, HEADER, Instruction, build_instruction
from drivers.dynamixel.protocol import crc16_bytes as _crc
from drivers.link import FdLink, Link, drain_until_quiet

_STATUS = Instruction.STATUS
_TRIPLE = b"\xff\xff\xfd"  # a header inside the parameters: the packet needs stuffing
_FAST_HEAD = HEADER + bytes((BROADCAST_ID,))
_LOW_7_BITS = bytes(b & 0x7F for b in range(256))


#: The state block every cycle reads: Present Current (int16), Present Velocity (int32)
#: and Present Position (int32), contiguous in the control table (10 bytes).
STATE_ADDRESS, STATE_LENGTH = state_block()
#: Where the cycle writes the goals (Goal Position, int32).
GOAL_ADDRESS = x_series_table()["Goal Position"].address
#: One servo's block of a Fast Sync Read status (after the 8-byte packet head).
_FAST_BLOCK = np.dtype({"names": ["err", "id", "cur", "vel", "pos", "crc"],
                        "formats": ["u1", "u1", "<i2", "<i4", "<i4", "<u2"],
                        "offsets": [0, 1, 2, 4, 8, 12], "itemsize": 14})
#: One unstuffed Sync Read status packet: head (header, ID, LEN, 0x55), error, state, CRC.
_SYNC_STATUS = np.dtype({"names": ["head", "err", "cur", "vel", "pos", "crc"],
                         "formats": ["V8", "u1", "<i2", "<i4", "<i4", "<u2"],
                         "offsets": [0, 8, 9, 11, 15, 19], "itemsize": 21})


class SyncCycle:
    """Goal-position writes and state reads for a fixed set of servo IDs on one port."""

    def __init__(self, link: Link | int, baud: int, ids: Sequence[int], *,
                 fast: bool = True, latency_s: float = 0.002) -> None:
        self.link = link if isinstance(link, Link) else FdLink(link)  # a port's link, or a descriptor's
        self.clock = self.link.clock
        self.ids = list(ids)
        self.n = n = len(self.ids)
        self.write_address = GOAL_ADDRESS
        self.fast = fast
        params = struct.pack("<HH", STATE_ADDRESS, STATE_LENGTH) + bytes(self.ids)
        instr = Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ
        self._read_packet = build_instruction(BROADCAST_ID, instr, params)
        # Sync Write: the parameters are (ID, goal) pairs after the address and length;
        # the IDs sit in a list whose odd slots take the goals of each cycle.
        self._goals = struct.Struct("<HH" + "Bi" * n)
        self._goal_args: list[int] = [GOAL_ADDRESS, 4] + [v for sid in self.ids for v in (sid, 0)]
        length = 1 + self._goals.size + 2  # LEN of an unstuffed Sync Write
        self._write_prefix = HEADER + bytes(
            (BROADCAST_ID, length & 0xFF, length >> 8, Instruction.SYNC_WRITE))
        self._id_bytes = bytes(self.ids)
        self._id_set = frozenset(self.ids)
        self._no_errors = bytes(n)
        # The head each unstuffed Sync Read status must carry: header, ID, LEN, 0x55.
        self._sync_heads = b"".join(
            HEADER + bytes((sid, STATE_LENGTH + 4, 0, _STATUS)) for sid in self.ids)
        if fast:
            self._expect = 8 + n * (4 + STATE_LENGTH)
        else:
            self._expect = n * (11 + STATE_LENGTH)
        self._byte_time = 10.0 / baud
        #: Reads that failed, and fast statuses found after stray bytes (for the record).
        self.failures = 0
        self.resyncs = 0
        self._servo_refused = False  # the last status parsed carried a servo's error
        # Late answers are expected after this long: wire time of the reply, plus slack.
        self.timeout_s = latency_s + 3 * (self._expect + len(self._read_packet)) * self._byte_time + 0.003
        self.last_error = ""
        #: Seconds spent in this cycle's transactions (writes and reads, failed ones included),
        #: timed here where they happen, on the link's clock; the backend hands it to the runner
        #: once a cycle.
        self.bus_s = 0.0

    # -- send -----------------------------------------------------------------
    def write_goals(self, ticks: Sequence[int]) -> None:
        """One Sync Write of Goal Position (4 bytes each) to every servo; no reply."""
        began = self.clock.now()
        args = self._goal_args
        args[3::2] = ticks
        params = self._goals.pack(*args)
        if _TRIPLE in params:  # rare (e.g. Goal Position -131073): stuffing changes LEN
            packet = build_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, params)
        else:
            packet = self._write_prefix + params
            crc = _crc(packet, 0)
            packet += bytes((crc & 0xFF, crc >> 8))
        try:
            self._send(packet)
        finally:
            self.bus_s += self.clock.now() - began

    def _send(self, packet: bytes) -> None:
        try:
            self.link.send(packet)
        except (OSError, ValueError) as e:
            raise CommunicationError(f"writing to the servo port failed: {e}") from None

    # -- receive ----------------------------------------------------------------
    def read_state(self) -> np.ndarray | None:
        """Send the (Fast) Sync Read; the state of every servo, or None on failure.

        The state is a (3, n) float array in servo order and raw units: rows
        Present Position (ticks), Present Velocity (0.229 rpm units), Present
        Current (model units). On failure ``last_error`` says what went wrong
        (timeout, CRC, servo error).
        """
        began = self.clock.now()
        try:
            return self._transact()
        finally:
            self.bus_s += self.clock.now() - began

    def _transact(self) -> np.ndarray | None:
        """The read's request and its status, parsed; a failure waits for a quiet line."""
        self._drain()
        self._send(self._read_packet)
        raw = self._receive(self._expect)
        if raw is None:
            state = None
        elif self.fast:
            state = self._parse_fast(raw)
            if state is None and not self._servo_refused:
                state = self._resync_fast(raw)  # stray bytes, an echo or a duplicate before it
        else:
            state = self._parse_sync(raw)
        if state is not None and self.link.waiting():
            self.last_error = "more bytes after the status (a late or duplicated reply)"
            state = None
        if state is None:
            self.failures += 1
            # A late answer to this request must not pass for the next one's: wait for a
            # quiet line, briefly (the cycle's retries must still end well inside a second).
            quiet = min(self.timeout_s / 4, 0.02)
            drain_until_quiet(self.link, quiet, 4 * quiet)
        return state

    def _resync_fast(self, raw: bytes) -> np.ndarray | None:
        """Stray bytes before the status: hunt for its header, read the rest, parse from there."""
        deadline = self.clock.now() + self.timeout_s
        buf, first_error = raw, self.last_error
        start = 1
        while True:
            k = buf.find(_FAST_HEAD, start)
            if k < 0:
                more = b"" if len(buf) > 4 * self._expect else self._receive_more(deadline)
                if not more:
                    self.last_error = f"{first_error}; no status header in {len(buf)} bytes"
                    return None
                start = max(0, len(buf) - len(_FAST_HEAD) + 1)
                buf += more
                continue
            while len(buf) - k < self._expect:
                more = self._receive_more(deadline)
                if not more:
                    self.last_error = (f"fast sync read: {len(buf) - k} of {self._expect} status "
                                       f"bytes after {k} stray bytes within "
                                       f"{self.timeout_s * 1e3:.1f} ms")
                    return None
                buf += more
            state = self._parse_fast(buf[k:])
            if state is not None:
                self.resyncs += 1
                return state
            if len(buf) > k + self._expect:
                return None  # bytes after it as well: out of step, retry from a quiet line
            start = k + 1  # a header inside the garbage: look further

    def _drain(self) -> None:
        """Drop bytes left from an earlier, failed transaction."""
        try:
            while self.link.waiting():
                if not self.link.take(4096):
                    return
        except OSError:
            return

    def _receive(self, length: int) -> bytes | None:
        """Sleep in the kernel until ``length`` bytes are in, or the timeout."""
        buf = b""
        link = self.link
        deadline = self.clock.now() + self.timeout_s
        while len(buf) < length:
            if self.clock.now() >= deadline or not link.wait(deadline):
                break
            try:
                chunk = link.take(4096)
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

    def _parse_fast(self, raw: bytes) -> np.ndarray | None:
        n = self.n
        self._servo_refused = False
        if raw[:5] != _FAST_HEAD or raw[7] != _STATUS:
            self.last_error = "fast sync read: bad header"
            return None
        if len(raw) > self._expect:
            self.last_error = (f"fast sync read: {len(raw) - self._expect} bytes after the status "
                               f"(a duplicated or late reply)")
            return None
        declared, expected = raw[5] | (raw[6] << 8), self._expect - 7  # LEN: instruction .. CRC
        if declared != expected:
            self.last_error = f"fast sync read: length {declared}, expected {expected}"
            return None
        # Each block's CRC continues over every byte before it, earlier CRCs included,
        # so the last one covers the whole packet: checking it is the packet's CRC check.
        if _crc(raw[:-2], 0) != raw[-2] | (raw[-1] << 8):
            self.last_error = "fast sync read: CRC error"
            return None
        ids = raw[9::14][:n]
        if ids != self._id_bytes:
            self.last_error = f"fast sync read: blocks from IDs {list(ids)}, expected {self.ids}"
            return None
        return self._state(np.frombuffer(raw, _FAST_BLOCK, n, 8), raw[8::14][:n])

    def _parse_sync(self, raw: bytes) -> np.ndarray | None:
        if len(raw) != self._expect:
            return self._parse_sync_slow(raw)
        packets = np.frombuffer(raw, _SYNC_STATUS, self.n)
        if packets["head"].tobytes() != self._sync_heads:
            return self._parse_sync_slow(raw)
        crcs = packets["crc"].tolist()
        size = 11 + STATE_LENGTH
        for k in range(self.n):
            if _crc(raw[k * size:(k + 1) * size - 2], 0) != crcs[k]:
                return self._parse_sync_slow(raw)
        return self._state(packets, raw[8::size][:self.n])

    def _state(self, blocks: np.ndarray, errors: bytes) -> np.ndarray | None:
        """Position, velocity and current rows of the parsed blocks, unless a servo reports an error."""
        # 0x80 is the hardware-error alert, not a failed instruction: only the low 7 bits count
        self._servo_refused = errors.translate(_LOW_7_BITS) != self._no_errors
        if self._servo_refused:
            k = next(k for k, e in enumerate(errors) if e & 0x7F)
            self.last_error = f"servo {self.ids[k]} answered with error 0x{errors[k]:02X}"
            return None
        return np.array((blocks["pos"], blocks["vel"], blocks["cur"]), dtype=float)

    def _parse_sync_slow(self, raw: bytes) -> np.ndarray | None:
        """Stuffed or out-of-step statuses: the full parser (reads the rest of the bytes)."""
        parser = PacketParser(stuffed=True, resync_on_header=True)
        got: dict[int, bytes] = {}
        data = raw
        deadline = self.clock.now() + self.timeout_s
        fed = bytearray()
        while True:
            events = parser.feed(data)
            fed += data
            if len(got) + len(events) > self.n or (
                    len(got) + len(events) == self.n and not fed.endswith(events[-1].raw)):
                self.last_error = ("sync read: more bytes than the statuses asked for "
                                   "(a late or duplicated reply)")
                return None
            for ev in events:
                if not isinstance(ev, Packet):
                    self.last_error = f"sync read: {type(ev).__name__}"
                    return None
                if ev.instruction != _STATUS:
                    continue  # an echo of an instruction is not an answer
                problem = (reply_mismatch(ev, ev.id, STATE_LENGTH) if ev.id in self._id_set
                           else f"a status from ID {ev.id}, which was not asked")
                if problem is None and ev.id in got:
                    problem = f"two statuses from ID {ev.id} (a late or duplicated reply)"
                if problem is not None:
                    self.last_error = f"sync read: {problem}"
                    return None
                if ev.error and ev.error & 0x7F:
                    self.last_error = f"servo {ev.id} answered with error 0x{ev.error:02X}"
                    return None
                got[ev.id] = ev.params
            if len(got) == self.n:
                return unpack_state([got[sid] for sid in self.ids])
            more = self._receive_more(deadline)
            if not more:
                missing = [sid for sid in self.ids if sid not in got]
                self.last_error = f"sync read: no status from servo(s) {missing}"
                return None
            data = more

    def _receive_more(self, deadline: float) -> bytes:
        if self.clock.now() >= deadline or not self.link.wait(deadline):
            return b""
        try:
            return self.link.take(4096)
        except OSError:
            return b""


def unpack_state(blocks: list[bytes]) -> np.ndarray:
    """The (3, n) position, velocity, current rows of each servo's 10-byte state block."""
    cur, vel, pos = zip(*(struct.unpack_from("<hii", b) for b in blocks))
    return np.array((pos, vel, cur), dtype=float)
