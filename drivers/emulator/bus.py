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
every answer. Before a state read is answered every step due by the read's
instant has run, so the answer is at most one step old, as a real servo's
(unless the physics has fallen more than a few steps behind real time: then
the answer goes first, as without wire timing); between instructions the
physics otherwise waits until it is two steps behind.

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

from drivers.dynamixel.protocol import (
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
from drivers.timing import sleep_until, tighten_timer_slack

__all__ = ["BusFaults", "BusStats", "DynamixelBusEmulator"]

_TCGETS2 = 0x802C542A  # Linux asm-generic: _IOR('T', 0x2A, struct termios2)
#: Last stretch of a wait spent yielding rather than asleep: with the default 50 µs
#: timer slack a sleep may overshoot by that much, with 1 ns slack by a few µs.
_SPIN_LOOSE_S = 0.0015
_SPIN_TIGHT_S = 0.0001
_READ_INSTRUCTIONS = {
    Instruction.PING,
    Instruction.READ,
    Instruction.SYNC_READ,
    Instruction.FAST_SYNC_READ,
    Instruction.BULK_READ,
    Instruction.FAST_BULK_READ,
}
#: Instructions answering control-table state, which must be current when they are answered.
_STATE_READS = frozenset(_READ_INSTRUCTIONS - {Instruction.PING})
#: Due physics steps a state read waits for; a longer backlog means the physics is not
#: keeping real time, and it is then caught up after the answer, as without wire timing.
_READ_WAITS_FOR_STEPS = 3
_BY_ID = itemgetter(0)
#: Instructions that can set something moving: they end a rest.
_WAKING = frozenset(Instruction) - _READ_INSTRUCTIONS - {Instruction.STATUS}
#: Present Position range (ticks) within which a servo counts as still: the hunt of a
#: holding servo is ±1 tick.
_STILL_TICKS = 3
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
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
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
        # a servo's. With the wire-time model the physics keeps to the stretches
        # where the wire is modelled busy instead (see the module docstring).
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
                else:
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
        if self.realtime and packet.instruction in _STATE_READS:
            self._catch_up_for_read(max(start, time.perf_counter()))
        self._handle(packet)
        self._flush(start)
        self._wire_free = max(time.perf_counter(), start)

    def _due_steps(self, now: float) -> int:
        """Physics steps due by ``now``; beyond ``max_catchup_s`` the backlog is skipped."""
        if self._resting:
            self._sim_wall = max(self._sim_wall, now)  # nothing moves: no steps fall due
            return 0
        steps = int((now - self._sim_wall) / self.physics_dt)
        if steps <= 0:
            return 0
        limit = max(1, int(self.max_catchup_s / self.physics_dt))
        if steps > limit:
            self.stats.physics_skipped_s += (steps - limit) * self.physics_dt
            self._sim_wall += (steps - limit) * self.physics_dt
            steps = limit
        return steps

    def _catch_up(self, now: float) -> None:
        steps = self._due_steps(now)
        if steps <= 0:
            return
        if self.max_batch_s is not None:  # the rest is due at the next pass
            steps = min(steps, max(1, int(self.max_batch_s / self.physics_dt)))
        self._run_physics(steps)

    def _catch_up_for_read(self, instant: float) -> None:
        """Run the steps due by a state read's ``instant``, so its answer is at most one step old."""
        steps = self._due_steps(instant)
        if 0 < steps <= _READ_WAITS_FOR_STEPS:
            self._run_physics(steps)

    def _catch_up_before(self, deadline: float) -> None:
        """Run the steps falling due by ``deadline``, one at a time, while each ends before it.

        No instruction can take effect before ``deadline`` (the wire is modelled
        busy, or a delayed status is still to go out), so a step may run ahead
        of its time: nothing it would have seen can change meanwhile.
        """
        while self._due_steps(deadline) and time.perf_counter() + self._step_cost <= deadline:
            self._run_physics(1)

    def _catch_up_between_instructions(self) -> None:
        """After a pass under the wire-time model: step in the wire's busy stretch only.

        The host's next instruction may come at any moment once the wire is idle,
        and a step then would delay its answer; so steps wait for a stretch where
        the wire is modelled busy, unless the physics would fall two steps behind.
        """
        self._catch_up_before(self._wire_free)
        now = time.perf_counter()
        if now - self._sim_wall >= 2 * self.physics_dt:
            self._catch_up(now)

    def _run_physics(self, steps: int) -> None:
        """Advance the physics by ``steps`` and update the estimate of one step's wall time."""
        t0 = time.perf_counter()
        self._physics(steps)
        self._sim_wall += steps * self.physics_dt
        self._step_costs.append((time.perf_counter() - t0) / steps)
        self._step_cost = 1.25 * sorted(self._step_costs)[len(self._step_costs) // 2]
        if self.rest_after_s is not None:
            self._watch_for_rest()

    def _watch_for_rest(self) -> None:
        """Pause the physics once every servo has stayed still for ``rest_after_s``."""
        ticks = np.fromiter((servo.get("Present Position") for servo, _ in self._servos),
                            float, len(self._servos))
        if self._still_lo is None or self._still_hi is None:
            self._still_lo, self._still_hi, self._still_since = ticks, ticks.copy(), self._sim_wall
            return
        np.minimum(self._still_lo, ticks, out=self._still_lo)
        np.maximum(self._still_hi, ticks, out=self._still_hi)
        if float(np.max(self._still_hi - self._still_lo)) > _STILL_TICKS:
            self._still_lo, self._still_hi, self._still_since = ticks, ticks.copy(), self._sim_wall
        elif self._sim_wall - self._still_since >= self.rest_after_s:
            self._resting, self._rest_since = True, time.perf_counter()

    def _wake(self) -> None:
        """A write instruction arrived: the physics resumes from now (the rest skipped no motion)."""
        self._still_lo = self._still_hi = None
        if self._resting:
            now = time.perf_counter()
            self._resting = False
            self.stats.rest_s += now - self._rest_since
            self._sim_wall = now

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
        baud = self._host_baud if self.check_baud else None
        deaf_until = self._deaf_until
        now = time.perf_counter() if deaf_until else 0.0
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
        if self.rest_after_s is not None and event.instruction in _WAKING:
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

    def _reply(
        self, servo: ServoModel, error: int, params: bytes = b"", *, instruction: int
    ) -> None:
        level = self._levels.get(id(servo))
        if level is None:
            level = servo.status_return_level
        if instruction != Instruction.PING and (
            level == 0 or (level == 1 and instruction not in _READ_INSTRUCTIONS)
        ):
            return
        servo_id = self._ids.get(id(servo))
        if servo_id is None:
            servo_id = servo.id
        packet = build_status(servo_id, servo.status_error(error), params)
        self._queue(servo_id, packet, servo)

    def _mute(self, servo_id: int) -> bool:
        return self.faults.silent or servo_id in self.faults.silent_ids

    def _queue(self, source_id: int, packet: bytes | None, servo: ServoModel) -> None:
        """Put a status packet in the outbox, through the faults; ``servo`` sets its timing."""
        faults = self.faults
        if self.wire_timing:
            return_delay_s, baud = servo.return_delay_s, servo.baud_rate
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
                self._wait_until(start + elapsed)
            self._write(packet)
        self._outbox.clear()

    def _wait_until(self, deadline: float) -> None:
        """Wait for a status packet's time; due physics steps that fit run meanwhile."""
        if self.realtime:
            self._catch_up_before(deadline)
        sleep_until(deadline, self._spin_s)

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
        self._queue(BROADCAST_ID, packet, first)

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
