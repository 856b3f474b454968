"""A DYNAMIXEL Protocol 2.0 bus on a pseudo-terminal, served by emulated servos.

The host opens :attr:`DynamixelBusEmulator.port` (the pty's slave device)
like a U2D2; a background thread reads instructions from the master side,
lets the addressed :class:`~drivers.emulator.servo.ServoModel` answer, and
advances the :class:`~drivers.emulator.plant.Plant` with wall-clock time in
fixed substeps, so servos move in real time while the driver talks to them.

Bus behaviour, after the e-manual's Protocol 2.0 page:

* strict framing: received packets are unstuffed and CRC-checked; a packet
  holding an unstuffed ``FF FF FD`` is lost because the servos re-synchronise
  on that header; a bad CRC gets a status with CRC Error 0x03 from the
  addressed servo; an unknown instruction gets Instruction Error 0x02;
* no status for broadcast instructions (except PING and the sync/bulk
  reads) nor for IDs nobody has; Status Return Level is honoured;
* broadcast PING: every servo answers, in ID order; SYNC/BULK READ: one
  status per listed servo, in list order; FAST SYNC/BULK READ: one combined,
  unstuffed packet with a running CRC per block;
* a servo listens only at its own Baud Rate: when the host has set the pty's
  speed (read back with ``TCGETS2``/``tcgetattr``) and it differs, that servo
  neither executes nor answers — so a scan at several rates finds servos
  configured at different rates. If the speed cannot be read, all listen.

Wire timing (off by default): each status packet is delayed by the servo's
Return Delay Time plus ``bytes × 10 / baud``, servos answering one after the
other, with sleeps accurate to ~50 µs (the tail is busy-waited).

Fault hooks (:class:`BusFaults`, seeded by ``seed``): drop a fraction of status
packets, corrupt their CRC, delay them, silence some IDs or all, or pass each
packet through a callable; :meth:`DynamixelBusEmulator.unplug` makes the
whole bus deaf and mute until :meth:`DynamixelBusEmulator.replug`.
"""

from __future__ import annotations

import array
import fcntl
import os
import select
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from drivers.dxl_protocol import (
    BROADCAST_ID,
    CrcError,
    FastStatusBlock,
    Instruction,
    Packet,
    PacketParser,
    StatusError,
    build_fast_status,
    build_status,
)
from drivers.emulator.plant import InertiaPlant, Plant
from drivers.emulator.servo import ServoModel

__all__ = ["BusFaults", "BusStats", "DynamixelBusEmulator"]

_TCGETS2 = 0x802C542A  # Linux asm-generic: _IOR('T', 0x2A, struct termios2)
_READ_INSTRUCTIONS = {
    Instruction.PING,
    Instruction.READ,
    Instruction.SYNC_READ,
    Instruction.FAST_SYNC_READ,
    Instruction.BULK_READ,
    Instruction.FAST_BULK_READ,
}


@dataclass
class BusFaults:
    """What goes wrong with status packets; change the fields while the bus runs."""

    drop_prob: float = 0.0  # fraction of status packets never sent
    corrupt_crc_prob: float = 0.0  # fraction sent with a wrong CRC
    delay_s: float = 0.0  # extra latency before every status packet
    silent: bool = False  # servos execute instructions but never answer
    silent_ids: set[int] = field(default_factory=set)  # these IDs never answer
    # Last word on every status packet: (servo ID or 0xFE, bytes) -> bytes, or None to drop.
    hook: Callable[[int, bytes], bytes | None] | None = None


@dataclass
class BusStats:
    """Counters for tests and diagnostics."""

    packets: int = 0  # well-formed instruction packets received
    crc_errors: int = 0
    malformed: int = 0
    status_sent: int = 0
    status_dropped: int = 0  # by faults, unplug, or a full pty buffer
    physics_steps: int = 0
    physics_skipped_s: float = 0.0  # wall time the physics could not keep up with


def _baud_constants() -> dict[int, int]:
    table = {}
    for name in dir(termios):
        if name.startswith("B") and name[1:].isdigit():
            table[getattr(termios, name)] = int(name[1:])
    return table


_BAUD_BY_CONSTANT = _baud_constants()


class DynamixelBusEmulator:
    """Servos on a pty: ``with DynamixelBusEmulator({1: ServoModel()}) as bus: PortHandler(bus.port)``.

    ``servos`` maps each servo's starting ID to its model (the ID register is
    set from the key); ``joints`` maps those IDs to plant joint indices
    (default: dict order). Without a ``plant`` each servo drives an
    :class:`~drivers.emulator.plant.InertiaPlant` joint of 0.01 kg·m².
    With ``realtime=False`` physics advances only through :meth:`advance`.
    """

    def __init__(
        self,
        servos: Mapping[int, ServoModel],
        plant: Plant | None = None,
        *,
        joints: Mapping[int, int] | None = None,
        physics_dt: float = 0.001,
        wire_timing: bool = False,
        check_baud: bool = True,
        seed: int = 0,
        frame_timeout_s: float = 0.1,
        boot_time_s: float = 0.0,
        realtime: bool = True,
        max_catchup_s: float = 0.5,
        max_batch_s: float | None = None,
    ) -> None:
        if not servos:
            raise ValueError("a bus needs at least one servo")
        if physics_dt <= 0:
            raise ValueError(f"physics_dt must be > 0 s, got {physics_dt}")
        self.plant: Plant = plant if plant is not None else InertiaPlant(len(servos))
        joint_of = dict(joints) if joints is not None else {k: i for i, k in enumerate(servos)}
        self._servos: list[tuple[ServoModel, int]] = []
        for key, servo in servos.items():
            if key not in joint_of:
                raise ValueError(f"servo ID {key} has no plant joint in joints={joint_of}")
            joint = joint_of[key]
            if not 0 <= joint < self.plant.joint_count:
                raise ValueError(
                    f"servo ID {key} mapped to joint {joint}, plant has {self.plant.joint_count}"
                )
            servo.set("ID", key)
            self._servos.append((servo, joint))
        self.physics_dt = float(physics_dt)
        self.wire_timing = wire_timing
        self.check_baud = check_baud
        self.frame_timeout_s = frame_timeout_s
        self.boot_time_s = boot_time_s
        self.realtime = realtime
        self.max_catchup_s = max_catchup_s
        #: Physics run at most this much simulated time between two looks at the
        #: port (None: all that is due), so the servos keep answering while the
        #: physics catches up after the host was busy.
        self.max_batch_s = max_batch_s
        self.faults = BusFaults()
        self.stats = BusStats()
        self.rng = np.random.default_rng(seed)
        #: Hold it to inspect or change servos and plant consistently while the bus runs.
        self.lock = threading.RLock()
        self._parser = PacketParser(stuffed=True, resync_on_header=True)
        self._unplugged = False
        self._deaf_until: dict[int, float] = {}
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self._sim_wall = 0.0
        self._last_rx = 0.0
        self._outbox: list[tuple[float, int, bytes]] = []
        self._wire_free = 0.0  # perf_counter time the wire is idle again (wire-time model)
        self._levels: dict[int, int] = {}
        self._ids: dict[int, int] = {}
        #: Exceptions raised while serving (the thread keeps serving); empty in a healthy run.
        self.errors: list[BaseException] = []

        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        attrs = termios.tcgetattr(self._slave)
        attrs[4] = attrs[5] = termios.B0  # "speed not set" until the host opens the port
        termios.tcsetattr(self._slave, termios.TCSANOW, attrs)
        os.set_blocking(self._master, False)
        self._port = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()

        q, v = self.plant.position(), self.plant.velocity()
        for servo, joint in self._servos:
            servo.power_on(float(q[joint]), float(v[joint]))

    # -- public API -----------------------------------------------------------
    @property
    def port(self) -> str:
        """Device path the host opens (the pty slave)."""
        return self._port

    @property
    def servos(self) -> dict[int, ServoModel]:
        """Servos by their current ID register."""
        return {servo.id: servo for servo, _ in self._servos}

    def servo(self, servo_id: int) -> ServoModel:
        for servo, _ in self._servos:
            if servo.id == servo_id:
                return servo
        raise KeyError(f"no servo with ID {servo_id} on the bus (IDs: {sorted(self.servos)})")

    def start(self) -> "DynamixelBusEmulator":
        if self._closed:
            raise RuntimeError("this bus emulator was stopped; create a new one")
        if self._thread is None:
            self._sim_wall = time.perf_counter()
            self._thread = threading.Thread(target=self._run, name="dxl-bus-emulator", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty (the port disappears); idempotent."""
        if self._closed:
            return
        self._stop.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._closed = True
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    close = stop

    def __enter__(self) -> "DynamixelBusEmulator":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Cable out: the servos neither hear nor answer anything."""
        with self.lock:
            self._unplugged = True
            self._parser.reset()

    def replug(self) -> None:
        with self.lock:
            self._unplugged = False

    def advance(self, seconds: float) -> None:
        """Step the physics by ``seconds`` (rounded to substeps) outside real time."""
        with self.lock:
            self._physics(max(1, round(seconds / self.physics_dt)))

    def host_baud(self) -> int | None:
        """Speed the host set on the port (bit/s), or None if unset or unreadable."""
        speed = 0
        try:
            if sys.platform.startswith("linux"):
                buf = array.array("i", [0] * 64)
                fcntl.ioctl(self._slave, _TCGETS2, buf)
                speed = buf[10]  # c_ospeed after 4 flags, c_line and c_cc[19]
            else:  # pragma: no cover - non-Linux
                speed = _BAUD_BY_CONSTANT.get(termios.tcgetattr(self._slave)[5], 0)
        except (OSError, termios.error):
            try:
                speed = _BAUD_BY_CONSTANT.get(termios.tcgetattr(self._slave)[5], 0)
            except (OSError, termios.error):
                return None
        return speed or None

    # -- serving thread ---------------------------------------------------------
    def _run(self) -> None:
        idle = min(0.005, max(self.physics_dt, 0.001))
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master, self._wake_r], [], [], idle)
            except (OSError, ValueError):
                return
            if self._stop.is_set():
                return
            data = b""
            if self._master in ready:
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:
                    time.sleep(idle)  # pty hung up; the wake pipe still ends the loop
                    continue
            with self.lock:
                try:
                    self._serve(data)
                except Exception as exc:  # keep the bus alive; the error is kept for inspection
                    self.errors.append(exc)
                    self._outbox.clear()

    def _serve(self, data: bytes) -> None:
        # Answer first, then catch the physics up: the idle loop steps the physics
        # every millisecond, so an answer's state is at most about that old, and
        # the host does not wait for the emulator's arithmetic as it would not for
        # a servo's.
        now = time.perf_counter()
        try:
            self._answer(data, now)
        finally:
            if self.realtime:
                self._catch_up(time.perf_counter())

    def _answer(self, data: bytes, now: float) -> None:
        if data:
            self._last_rx = now
            if self._unplugged:
                return
            for event in self._parser.feed(data):
                if self.wire_timing and isinstance(event, Packet):
                    # The pty delivers at once; a real wire carries the instruction
                    # first, one at a time: answers start after it has arrived.
                    baud = self.host_baud() or 1_000_000
                    start = max(now, self._wire_free) + len(event.raw) * 10.0 / baud
                    self._handle(event)
                    self._flush(start)
                    self._wire_free = max(time.perf_counter(), start)
                else:
                    self._handle(event)
            self._flush(now)
        elif self._parser.pending and now - self._last_rx > self.frame_timeout_s:
            self._parser.reset()  # inter-byte timeout: drop the partial frame

    def _catch_up(self, now: float) -> None:
        steps = int((now - self._sim_wall) / self.physics_dt)
        if steps <= 0:
            return
        limit = max(1, int(self.max_catchup_s / self.physics_dt))
        if steps > limit:
            self.stats.physics_skipped_s += (steps - limit) * self.physics_dt
            self._sim_wall += (steps - limit) * self.physics_dt
            steps = limit
        if self.max_batch_s is not None:  # the rest is due at the next pass
            steps = min(steps, max(1, int(self.max_batch_s / self.physics_dt)))
        self._physics(steps)
        self._sim_wall += steps * self.physics_dt

    def _physics(self, steps: int) -> None:
        dt = self.physics_dt
        plant = self.plant
        torque = np.zeros(plant.joint_count)
        for _ in range(steps):
            q, v = plant.position(), plant.velocity()
            torque[:] = 0.0
            for servo, joint in self._servos:
                torque[joint] += servo.step(dt, float(q[joint]), float(v[joint]))
            plant.step(dt, torque)
        q, v = plant.position(), plant.velocity()
        for servo, joint in self._servos:
            servo.observe(float(q[joint]), float(v[joint]))
        self.stats.physics_steps += steps

    # -- instruction handling -------------------------------------------------------
    def _listening(self) -> dict[int, ServoModel]:
        """Servos that can hear the host now (baud rate matches, not rebooting), by ID."""
        baud = self.host_baud() if self.check_baud else None
        now = time.perf_counter()
        out: dict[int, ServoModel] = {}
        for servo, _ in sorted(self._servos, key=lambda item: item[0].id):
            if baud is not None and servo.baud_rate != baud:
                continue
            if self._deaf_until.get(id(servo), 0.0) > now:
                continue
            out.setdefault(servo.id, servo)
        return out

    def _handle(self, event: object) -> None:
        self._levels, self._ids = {}, {}
        if isinstance(event, CrcError):
            self.stats.crc_errors += 1
            servo = self._listening().get(event.id)
            if servo is not None:
                self._reply(servo, StatusError.CRC, instruction=event.instruction)
            return
        if not isinstance(event, Packet):
            self.stats.malformed += 1
            return
        if event.is_status:
            return  # another device's answer
        self.stats.packets += 1
        listening = self._listening()
        broadcast = event.id == BROADCAST_ID
        if not broadcast and event.id not in listening:
            return
        # The ID and Status Return Level in force when the instruction arrived
        # govern its answer (a WRITE to ID 7 answers as the old ID).
        self._levels = {id(servo): servo.status_return_level for servo in listening.values()}
        self._ids = {id(servo): servo.id for servo in listening.values()}
        handler = self._HANDLERS.get(event.instruction)
        if handler is None:
            if not broadcast:
                self._reply(listening[event.id], StatusError.INSTRUCTION, instruction=event.instruction)
            return
        handler(self, event, listening)

    def _reply(
        self, servo: ServoModel, error: int, params: bytes = b"", *, instruction: int
    ) -> None:
        level = self._levels.get(id(servo), servo.status_return_level)
        if instruction != Instruction.PING and (
            level == 0 or (level == 1 and instruction not in _READ_INSTRUCTIONS)
        ):
            return
        servo_id = self._ids.get(id(servo), servo.id)
        packet = build_status(servo_id, servo.status_error(error), params)
        self._queue(servo_id, packet, servo.return_delay_s, servo.baud_rate)

    def _mute(self, servo_id: int) -> bool:
        return self.faults.silent or servo_id in self.faults.silent_ids

    def _queue(self, source_id: int, packet: bytes | None, return_delay_s: float, baud: int) -> None:
        faults = self.faults
        if self._mute(source_id):
            packet = None
        elif faults.drop_prob and self.rng.random() < faults.drop_prob:
            packet = None
        if packet is not None and faults.corrupt_crc_prob and self.rng.random() < faults.corrupt_crc_prob:
            packet = packet[:-1] + bytes((packet[-1] ^ 0xFF,))
        if packet is not None and faults.hook is not None:
            packet = faults.hook(source_id, packet)
        if packet is None:
            self.stats.status_dropped += 1
            return
        delay = faults.delay_s
        if self.wire_timing:
            delay += return_delay_s + len(packet) * 10.0 / baud
        self._outbox.append((delay, source_id, packet))

    def _flush(self, start: float) -> None:
        """Send queued status packets, delays counted from ``start`` (when the instruction arrived)."""
        if not self._outbox:
            return
        elapsed = 0.0
        for delay, _, packet in self._outbox:
            if delay > 0:
                elapsed += delay
                _sleep_until(start + elapsed)
            self._write(packet)
        self._outbox.clear()

    def _write(self, packet: bytes) -> None:
        view = memoryview(packet)
        while view:
            try:
                written = os.write(self._master, view)
            except BlockingIOError:
                self.stats.status_dropped += 1  # host not reading: the pty buffer is full
                return
            except OSError:
                return
            view = view[written:]
        self.stats.status_sent += 1

    # One method per instruction: (packet, listening servos by ID).
    def _ping(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        targets = listening.values() if pkt.id == BROADCAST_ID else [listening[pkt.id]]
        for servo in targets:
            model = servo.model_number
            params = bytes((model & 0xFF, model >> 8, servo.firmware_version))
            self._reply(servo, 0, params, instruction=Instruction.PING)

    def _read(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if pkt.id == BROADCAST_ID:
            return
        servo = listening[pkt.id]
        if len(pkt.params) != 4:
            self._reply(servo, StatusError.DATA_LENGTH, instruction=pkt.instruction)
            return
        address, length = _u16(pkt.params, 0), _u16(pkt.params, 2)
        error, data = servo.read(address, length)
        self._reply(servo, error, data, instruction=pkt.instruction)

    def _write_like(self, pkt: Packet, listening: dict[int, ServoModel], register: bool) -> None:
        targets = list(listening.values()) if pkt.id == BROADCAST_ID else [listening[pkt.id]]
        for servo in targets:
            if len(pkt.params) < 3:
                error = StatusError.DATA_LENGTH
            else:
                address, data = _u16(pkt.params, 0), pkt.params[2:]
                error = (servo.register_write if register else servo.write)(address, data)
            if pkt.id != BROADCAST_ID:
                self._reply(servo, error, instruction=pkt.instruction)

    def _write_instr(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        self._write_like(pkt, listening, register=False)

    def _reg_write(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        self._write_like(pkt, listening, register=True)

    def _action(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if pkt.id == BROADCAST_ID:
            for servo in listening.values():
                if servo.has_registered_instruction:
                    servo.action()
            return
        servo = listening[pkt.id]
        self._reply(servo, servo.action(), instruction=pkt.instruction)

    def _factory_reset(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        option = pkt.params[0] if len(pkt.params) == 1 else None
        if pkt.id == BROADCAST_ID:
            if option in (0x01, 0x02):  # broadcast "reset all" is refused by X firmware >= 42
                for servo in listening.values():
                    servo.factory_reset(option)
            return
        servo = listening[pkt.id]
        if option is None:
            self._reply(servo, StatusError.DATA_LENGTH, instruction=pkt.instruction)
            return
        if option not in (0xFF, 0x01, 0x02):
            self._reply(servo, StatusError.DATA_RANGE, instruction=pkt.instruction)
            return
        self._reply(servo, 0, instruction=pkt.instruction)  # answered before resetting
        servo.factory_reset(option)

    def _reboot(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        targets = list(listening.values()) if pkt.id == BROADCAST_ID else [listening[pkt.id]]
        for servo in targets:
            if pkt.id != BROADCAST_ID:
                self._reply(servo, 0, instruction=pkt.instruction)
            servo.reboot()
            if self.boot_time_s > 0:
                self._deaf_until[id(servo)] = time.perf_counter() + self.boot_time_s

    def _clear(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        targets = list(listening.values()) if pkt.id == BROADCAST_ID else [listening[pkt.id]]
        for servo in targets:
            error = servo.clear(pkt.params)
            if pkt.id != BROADCAST_ID:
                self._reply(servo, error, instruction=pkt.instruction)

    def _not_broadcast(self, pkt: Packet, listening: dict[int, ServoModel]) -> bool:
        """Sync/bulk instructions must be broadcast; a unicast one is an instruction error."""
        if pkt.id == BROADCAST_ID:
            return False
        self._reply(listening[pkt.id], StatusError.INSTRUCTION, instruction=pkt.instruction)
        return True

    def _sync_read(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if self._not_broadcast(pkt, listening) or len(pkt.params) < 5:
            return
        address, length = _u16(pkt.params, 0), _u16(pkt.params, 2)
        requests = [(i, address, length) for i in pkt.params[4:]]
        self._reads(pkt, listening, requests)

    def _bulk_read(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if self._not_broadcast(pkt, listening) or not pkt.params or len(pkt.params) % 5:
            return
        p = pkt.params
        requests = [(p[i], _u16(p, i + 1), _u16(p, i + 3)) for i in range(0, len(p), 5)]
        self._reads(pkt, listening, requests)

    def _reads(
        self,
        pkt: Packet,
        listening: dict[int, ServoModel],
        requests: list[tuple[int, int, int]],
    ) -> None:
        fast = pkt.instruction in (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)
        if not fast:
            for servo_id, address, length in requests:
                servo = listening.get(servo_id)
                if servo is not None:
                    error, data = servo.read(address, length)
                    self._reply(servo, error, data, instruction=pkt.instruction)
            return
        blocks = []
        first: ServoModel | None = None
        for servo_id, address, length in requests:
            servo = listening.get(servo_id)
            if servo is None or self._levels.get(id(servo)) == 0 or self._mute(servo_id):
                continue  # its block is missing: the packet comes out short
            error, data = servo.read(address, length)
            blocks.append(FastStatusBlock(servo.id, servo.status_error(error), data or bytes(length)))
            first = first or servo
        if first is None:
            return
        packet = build_fast_status(blocks, [length for _, _, length in requests])
        self._queue(BROADCAST_ID, packet, first.return_delay_s, first.baud_rate)

    def _sync_write(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if self._not_broadcast(pkt, listening) or len(pkt.params) < 4:
            return
        address, length = _u16(pkt.params, 0), _u16(pkt.params, 2)
        chunk = length + 1
        body = pkt.params[4:]
        if length == 0 or len(body) % chunk:
            self.stats.malformed += 1
            return
        for i in range(0, len(body), chunk):
            servo = listening.get(body[i])
            if servo is not None:
                servo.write(address, body[i + 1 : i + chunk])

    def _bulk_write(self, pkt: Packet, listening: dict[int, ServoModel]) -> None:
        if self._not_broadcast(pkt, listening):
            return
        p, i = pkt.params, 0
        while i + 5 <= len(p):
            servo_id, address, length = p[i], _u16(p, i + 1), _u16(p, i + 3)
            data = p[i + 5 : i + 5 + length]
            if len(data) != length:
                self.stats.malformed += 1
                return
            servo = listening.get(servo_id)
            if servo is not None:
                servo.write(address, data)
            i += 5 + length

    _HANDLERS: dict[int, Callable[["DynamixelBusEmulator", Packet, dict[int, ServoModel]], None]] = {
        Instruction.PING: _ping,
        Instruction.READ: _read,
        Instruction.WRITE: _write_instr,
        Instruction.REG_WRITE: _reg_write,
        Instruction.ACTION: _action,
        Instruction.FACTORY_RESET: _factory_reset,
        Instruction.REBOOT: _reboot,
        Instruction.CLEAR: _clear,
        Instruction.SYNC_READ: _sync_read,
        Instruction.FAST_SYNC_READ: _sync_read,
        Instruction.SYNC_WRITE: _sync_write,
        Instruction.BULK_READ: _bulk_read,
        Instruction.FAST_BULK_READ: _bulk_read,
        Instruction.BULK_WRITE: _bulk_write,
    }


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)


def _sleep_until(deadline: float) -> None:
    """Sleep to ``deadline`` (perf_counter s) within ~50 µs: coarse sleep, busy-wait the tail."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > 0.002:
            time.sleep(remaining - 0.0015)
        else:
            time.sleep(0)
