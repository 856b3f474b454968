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

Wire timing (off by default): an instruction counts as arrived once its bytes
would have crossed the wire after the previous transfer (``bytes × 10 / baud``);
each status packet then follows after the servo's Return Delay Time plus its
own transfer time, servos answering one after the other, with sleeps accurate
to a few µs (the serving thread asks Linux for 1 ns timer slack and yields
through the last 100 µs; ~50 µs where the slack cannot be set).

A servo's firmware runs its 1 ms loop while bytes are on the wire, and nothing
the host sends can take effect before the wire is free; so with the wire-time
model the physics steps falling due while the wire is modelled busy run during
that stretch, each only if it ends before the stretch does, instead of after
every answer; between instructions the physics otherwise waits until it is two
steps behind. With or without the wire-time model, before a state read is
answered every step due by the read's instant has run, so the answer is at most
one step old, as a real servo's (without the wire-time model, two: the idle
loop's last), also after the emulator was held up (unless the physics has
fallen more than 30 steps behind real time: the answer then goes first). A catch-up otherwise runs two steps at a time and yields to an
instruction waiting on the port.

The bus is cut at its seams: this module is the transport (the pty, the serving
thread, framing and dispatch); :mod:`.instructions` executes each instruction,
:mod:`.wire` times and sends the status packets, :mod:`.clock` keeps the physics
in step with the wire.

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
from collections import deque
from dataclasses import dataclass, field
from operator import itemgetter
from typing import Callable, Mapping

import numpy as np

from drivers.dynamixel.parser import CrcError, Packet, PacketParser
from drivers.dynamixel.protocol import BROADCAST_ID, StatusError
from drivers.emulator.clock import PhysicsClock
from drivers.emulator.instructions import STATE_READS, WAKING, InstructionSet
from drivers.emulator.plant import InertiaPlant, Plant
from drivers.emulator.service import PtyService
from drivers.emulator.servo import ServoModel
from drivers.emulator.wire import StatusWire
from drivers.servo.model import ServoArray
from drivers.timing import tighten_timer_slack

__all__ = ["BusFaults", "BusStats", "DynamixelBusEmulator"]

_TCGETS2 = 0x802C542A  # Linux asm-generic: _IOR('T', 0x2A, struct termios2)
#: Last stretch of a wait spent yielding rather than asleep: with the default 50 µs
#: timer slack a sleep may overshoot by that much, with 1 ns slack by a few µs.
_SPIN_LOOSE_S = 0.0015
_SPIN_TIGHT_S = 0.0001
_BY_ID = itemgetter(0)
_REST_POLL_S = 0.05


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
    rest_s: float = 0.0  # wall time the physics was paused because nothing moved


def _baud_constants() -> dict[int, int]:
    table = {}
    for name in dir(termios):
        if name.startswith("B") and name[1:].isdigit():
            table[getattr(termios, name)] = int(name[1:])
    return table


_BAUD_BY_CONSTANT = _baud_constants()


class DynamixelBusEmulator(PtyService, InstructionSet, StatusWire, PhysicsClock):
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
        rest_after_s: float | None = None,
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
        # One servo array for the bus: every physics step runs all the servos' loops at once.
        self._bank = ServoArray.gather([s for s, _ in self._servos])
        for slot, (servo, _) in enumerate(self._servos):
            servo.attach(self._bank, slot)
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
        #: After this long with no write instruction and every servo still (its Present
        #: Position within a few ticks), the physics pauses until the next write: an idle
        #: rig then costs next to no CPU. None: the physics never pauses (code that moves
        #: the plant or the servos directly, as tests do, needs that).
        self.rest_after_s = rest_after_s
        self._resting = False
        self._rest_since = 0.0
        self._still_since = 0.0
        self._still_lo: np.ndarray | None = None
        self._still_hi: np.ndarray | None = None
        self.faults = BusFaults()
        self.stats = BusStats()
        self.rng = np.random.default_rng(seed)
        #: Hold it to inspect or change servos and plant consistently while the bus runs.
        self.lock = threading.RLock()
        self._parser = PacketParser(stuffed=True, resync_on_header=True)
        self._unplugged = False
        self._deaf_until: dict[int, float] = {}
        self._init_service()
        self._sim_wall = 0.0
        self._last_rx = 0.0
        self._outbox: list[tuple[float, int, bytes]] = []
        self._wire_free = 0.0  # perf_counter time the wire is idle again (wire-time model)
        self._host_baud: int | None = None  # read once per pass over received bytes
        # Wall time of the last physics steps (s), and what a step is expected to take:
        # their median with a margin, so that one slow step (the process was preempted)
        # does not keep steps out of the wire windows for long.
        self._step_costs: deque[float] = deque(maxlen=15)
        self._step_cost = 0.0
        self._spin_s = _SPIN_LOOSE_S
        self._levels: dict[int, int] = {}
        self._ids: dict[int, int] = {}
        #: Exceptions raised while serving (the thread keeps serving); empty in a healthy run.
        self.errors: list[BaseException] = []

        self._open_transport()

        q, v = self.plant.position(), self.plant.velocity()
        for servo, joint in self._servos:
            servo.power_on(float(q[joint]), float(v[joint]))

    def _open_transport(self) -> None:
        """The pty the host opens, and the pipe that wakes the serving thread."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        attrs = termios.tcgetattr(self._slave)
        attrs[4] = attrs[5] = termios.B0  # "speed not set" until the host opens the port
        termios.tcsetattr(self._slave, termios.TCSANOW, attrs)
        os.set_blocking(self._master, False)
        self._port = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()

    def _bus_now(self) -> float:
        """The bus's time (s): the wall clock here, the virtual clock's instant on a virtual line."""
        return time.perf_counter()

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

    thread_name = "dxl-bus-emulator"

    def _before_start(self) -> None:
        self._sim_wall = time.perf_counter()

    def _interrupt_wait(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    def _fds(self) -> tuple[int, ...]:
        return (self._master, self._slave, self._wake_r, self._wake_w)

    def _input_waiting(self) -> bool:
        try:
            return bool(select.select([self._master], [], [], 0)[0])
        except (OSError, ValueError):
            return False

    def unplug(self) -> None:
        """Cable out: the servos neither hear nor answer anything."""
        with self.lock:
            self._unplugged = True
            self._parser.reset()

    def replug(self) -> None:
        with self.lock:
            self._unplugged = False

    def disturb(self, change: Callable[[Plant], None]) -> None:
        """Change the plant's physics while the bus runs (a contact on a joint, a friction that
        drifts): ``change(plant)`` under the lock, and a resting physics resumes, its rig no longer
        at rest."""
        with self.lock:
            change(self.plant)
            self._wake()

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
        if tighten_timer_slack():
            self._spin_s = _SPIN_TIGHT_S
        idle = min(0.005, max(self.physics_dt, 0.001))
        while not self._stop.is_set():
            try:
                # At rest nothing falls due: wake for bytes, or now and then for the
                # inter-byte timeout of a partial frame.
                ready, _, _ = select.select([self._master, self._wake_r], [], [],
                                            _REST_POLL_S if self._resting else idle)
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
        # a servo's. (A state read after a hold-up first runs the steps due, up to a
        # few ms of arithmetic: its answer is the state now, not before the hold-up.)
        # With the wire-time model the physics keeps to the stretches where the wire
        # is modelled busy instead (see the module docstring).
        now = time.perf_counter()
        try:
            self._answer(data, now)
        finally:
            if self.realtime:
                if self.wire_timing and data:
                    self._catch_up_between_instructions()
                else:
                    self._catch_up(time.perf_counter())

    def _answer(self, data: bytes, now: float) -> None:
        if data:
            self._last_rx = now
            if self._unplugged:
                return
            events = self._parser.feed(data)
            if not events:
                return
            self._host_baud = self.host_baud() if self.check_baud or self.wire_timing else None
            for event in events:
                if self.wire_timing and isinstance(event, Packet):
                    self._answer_on_wire(event, now)
                    continue
                if self.realtime and isinstance(event, Packet) and event.instruction in STATE_READS:
                    # after a hold-up, the state now; otherwise the idle loop's last step, as before
                    self._catch_up_for_read(time.perf_counter(), from_steps=2)
                self._handle(event)
            self._flush(now)
        elif self._parser.pending and now - self._last_rx > self.frame_timeout_s:
            self._parser.reset()  # inter-byte timeout: drop the partial frame

    def _answer_on_wire(self, packet: Packet, now: float) -> None:
        """Handle one instruction under the wire-time model.

        The pty delivers at once; a real wire carries the instruction first, one
        transfer at a time, so answers start only after its last byte would have
        arrived. The servo works on it meanwhile, as firmware parses bytes as
        they come: that is where a due physics step goes before a state read.
        """
        baud = self._host_baud or 1_000_000
        start = max(now, self._wire_free) + len(packet.raw) * 10.0 / baud
        if self.realtime and packet.instruction in STATE_READS:
            self._catch_up_for_read(max(start, time.perf_counter()))
        self._handle(packet)
        self._flush(start)
        self._wire_free = max(time.perf_counter(), start)

    # -- instruction handling -------------------------------------------------------
    def _listening(self) -> dict[int, ServoModel]:
        """Servos that can hear the host now (baud rate matches, not rebooting), by ID."""
        baud = self._host_baud if self.check_baud else None
        deaf_until = self._deaf_until
        now = self._bus_now() if deaf_until else 0.0
        out: dict[int, ServoModel] = {}
        for servo_id, servo in sorted([(servo.id, servo) for servo, _ in self._servos], key=_BY_ID):
            if baud is not None and servo.baud_rate != baud:
                continue
            if deaf_until and deaf_until.get(id(servo), 0.0) > now:
                continue
            out.setdefault(servo_id, servo)
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
        if self.rest_after_s is not None and event.instruction in WAKING:
            self._wake()
        listening = self._listening()
        broadcast = event.id == BROADCAST_ID
        if not broadcast and event.id not in listening:
            return
        # The ID and Status Return Level in force when the instruction arrived
        # govern its answer (a WRITE to ID 7 answers as the old ID).
        self._levels = {id(servo): servo.status_return_level for servo in listening.values()}
        self._ids = {id(servo): servo_id for servo_id, servo in listening.items()}
        handler = self._HANDLERS.get(event.instruction)
        if handler is None:
            if not broadcast:
                self._reply(listening[event.id], StatusError.INSTRUCTION, instruction=event.instruction)
            return
        handler(self, event, listening)
