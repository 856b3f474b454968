"""A servo bus for the lab tools: find servos at any baud rate, read and write registers by name.

The control cycle (:mod:`drivers.dynamixel.cycle`) is lean and fixed to one set of
IDs; this is its general, slow companion for scanning, diagnosing and
calibrating: one transaction at a time, any ID, any X-series baud rate, and
registers looked up by name in each model's own control table
(:mod:`drivers.dynamixel.models`). Raw register values are decoded here, so callers
see bit/s, volts, °C, seconds, shaft radians and fault names — never ticks.

Framing is :mod:`drivers.dynamixel.protocol`'s (stuffed both ways). A broadcast
PING waits as long as dynamixel-sdk's ``broadcastPing`` does (every ID may
answer, each in its own slot), so one scan per baud rate is all it takes.
"""

from __future__ import annotations

import errno
import os
from dataclasses import asdict, dataclass, field
from typing import Optional

import serial

from drivers import CommunicationError, BackendSetupError
from drivers.dynamixel.control_table import Register, x_series_table
from drivers.dynamixel.models import model_name, register_layout
from drivers.dynamixel.parser import Packet, PacketParser, reply_mismatch
from drivers.dynamixel.protocol import (
    BROADCAST_ID,
    MAX_ID,
    Instruction,
    build_instruction,
    decode_hardware_error,
    describe_status_error,
)
from drivers.dynamixel.units import BAUD_RATES, MODE_NAMES
from drivers.link import drain_until_quiet, is_virtual_port, link_of, open_port


__all__ = ["PingReply", "ServoBus", "ServoStatus", "open_error"]

_LATENCY_S = 0.034  # as the SDK: 2 x 16 ms USB latency + 2 ms
_SIGNED = {"Homing Offset", "Present Position", "Goal Position", "Present Velocity",
           "Goal Velocity", "Present Current", "Goal Current", "Present PWM", "Goal PWM",
           "Present Load"}


@dataclass(frozen=True)
class PingReply:
    """A servo that answered a PING: its ID, model number and firmware version."""

    id: int
    model: int
    firmware: int

    @property
    def model_name(self) -> str:
        return model_name(self.model)


@dataclass(frozen=True)
class ServoStatus:
    """What a servo says about itself, decoded (None: the model has no such register)."""

    id: int
    model: int
    model_name: str
    firmware: int
    baud: Optional[int] = None  # bit/s, from the Baud Rate register
    operating_mode: Optional[str] = None
    torque: Optional[bool] = None
    hardware_error: list[str] = field(default_factory=list)
    return_delay_s: Optional[float] = None
    voltage_v: Optional[float] = None
    voltage_min_v: Optional[float] = None
    voltage_max_v: Optional[float] = None
    temperature_c: Optional[float] = None
    temperature_limit_c: Optional[float] = None

    def as_dict(self) -> dict:
        return asdict(self)


def open_error(port: str, exc: BaseException | None = None) -> str:
    """One line saying why a serial port cannot be used, naming the fix."""
    if is_virtual_port(port):
        return f"cannot open {port}: {exc}" if exc else f"cannot open {port}"
    if not os.path.exists(port):
        return f"port {port} not found (is the adapter plugged in? see ls /dev/serial/by-id/)"
    if not os.access(port, os.R_OK | os.W_OK) or (
            isinstance(exc, OSError) and exc.errno in (errno.EACCES, errno.EPERM)):
        return (f"no read/write permission on {port}: add yourself to its group with "
                f"`sudo usermod -aG dialout $USER`, then log out and in again")
    return f"cannot open {port}: {exc}" if exc else f"cannot open {port}"


class ServoBus:
    """One serial port to a Protocol 2.0 bus: ``with ServoBus(port, baud) as bus: bus.broadcast_ping()``."""

    def __init__(self, port: str, baud: int, tries: int = 6) -> None:
        self.port = port
        self.tries = max(1, int(tries))  # per transaction: a noisy bus or a busy host loses some
        self._models: dict[int, int] = {}
        try:
            self._ser = open_port(port, baud)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise BackendSetupError(open_error(port, getattr(exc, "__cause__", None) or exc)) from None
        self._link = link_of(self._ser, "dynamixel")
        self.clock = self._link.clock  # the wall clock; an emulated line's virtual one
        self._byte_s = 10.0 / baud
        self._heard = False  # bytes arrived during the last receive
        #: servo ID -> the request it last left unanswered: its answer may still be on its way
        self._unanswered: dict[int, bytes] = {}
        self._trailing = False  # and more came after its first status
        self.last_problem = ""  # what was wrong with the replies of the last failed transaction

    # -- port ---------------------------------------------------------------------
    @property
    def baud(self) -> int:
        return int(self._ser.baudrate)

    def set_baud(self, baud: int) -> None:
        """Talk at another speed from now on (servos at other speeds stay silent)."""
        try:
            self._ser.baudrate = baud
        except (serial.SerialException, ValueError, OSError) as exc:
            raise BackendSetupError(f"cannot set {baud} bps on {self.port}: {exc}") from None
        self._byte_s = 10.0 / baud
        self._drain()

    def close(self) -> None:
        try:
            self._ser.close()
        except (serial.SerialException, OSError):
            pass

    def __enter__(self) -> "ServoBus":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- finding servos -------------------------------------------------------------
    def broadcast_ping(self, max_id: int = MAX_ID) -> list[PingReply]:
        """Every servo listening at this speed, in ID order.

        Waits as dynamixel-sdk's ``broadcastPing`` does for IDs up to ``max_id``:
        14 bytes and 3 ms per ID plus 16 ms, the answers' worst case.
        """
        slots = max(1, min(max_id, MAX_ID))
        wait = (14 * slots * self._byte_s) + 0.003 * slots + 0.016
        self._drain()
        self._send(build_instruction(BROADCAST_ID, Instruction.PING, b""))
        found: dict[int, PingReply] = {}
        for pkt in self._receive(self.clock.now() + wait):
            if len(pkt.params) == 3 and pkt.id <= max_id:  # a PING answer is exactly 3 bytes
                found[pkt.id] = PingReply(pkt.id, pkt.params[0] | (pkt.params[1] << 8), pkt.params[2])
        for reply in found.values():
            self._models[reply.id] = reply.model
        return [found[k] for k in sorted(found)]

    def ping(self, sid: int, tries: Optional[int] = None) -> Optional[PingReply]:
        """The servo with this ID, or None if it does not answer at this speed."""
        pkt = self._transact(sid, Instruction.PING, b"", 3, required=False, tries=tries)
        if pkt is None:
            return None
        reply = PingReply(sid, pkt.params[0] | (pkt.params[1] << 8), pkt.params[2])
        self._models[sid] = reply.model
        return reply

    # -- registers by name -----------------------------------------------------------
    def has(self, sid: int, name: str) -> bool:
        return name in register_layout(self._model(sid))

    def read(self, sid: int, name: str) -> int:
        """A register's raw value (two's complement decoded where the register is signed)."""
        address, size = self._where(sid, name)
        params = address.to_bytes(2, "little") + size.to_bytes(2, "little")
        pkt = self._transact(sid, Instruction.READ, params, size)
        assert pkt is not None
        return int.from_bytes(pkt.params, "little", signed=name in _SIGNED)

    def write(self, sid: int, name: str, value: int) -> None:
        address, size = self._where(sid, name)
        data = int(value).to_bytes(size, "little", signed=value < 0)
        self._transact(sid, Instruction.WRITE, address.to_bytes(2, "little") + data, 0)

    def status(self, reply: PingReply) -> ServoStatus:
        """Identity, bus settings, torque, faults, supply voltage and temperature of one servo."""
        sid = reply.id

        def get(name: str) -> Optional[int]:
            return self.read(sid, name) if self.has(sid, name) else None

        baud, mode, torque, hw = get("Baud Rate"), get("Operating Mode"), get("Torque Enable"), \
            get("Hardware Error Status")
        rdt, volts, vmin, vmax = get("Return Delay Time"), get("Present Input Voltage"), \
            get("Min Voltage Limit"), get("Max Voltage Limit")
        temp, tlim = get("Present Temperature"), get("Temperature Limit")
        return ServoStatus(
            id=sid, model=reply.model, model_name=reply.model_name, firmware=reply.firmware,
            baud=BAUD_RATES.get(baud) if baud is not None else None,
            operating_mode=MODE_NAMES.get(mode, f"mode {mode}") if mode is not None else None,
            torque=bool(torque) if torque is not None else None,
            hardware_error=decode_hardware_error(hw) if hw else [],
            return_delay_s=_si("Return Delay Time", rdt),
            voltage_v=_si("Present Input Voltage", volts), voltage_min_v=_si("Min Voltage Limit", vmin),
            voltage_max_v=_si("Max Voltage Limit", vmax),
            temperature_c=_si("Present Temperature", temp),
            temperature_limit_c=_si("Temperature Limit", tlim))

    # -- shaft angle and zero ------------------------------------------------------------
    def shaft_angle(self, sid: int) -> float:
        """Present Position as a shaft angle (rad, 0 at the centre tick, Homing Offset included)."""
        return _register("Present Position").to_si(self.read(sid, "Present Position"))

    def homing_offset(self, sid: int) -> float:
        """The Homing Offset register as a shaft angle (rad)."""
        return _register("Homing Offset").to_si(self.read(sid, "Homing Offset"))

    def shift_zero(self, sid: int, shaft_rad: float) -> float:
        """Make the servo report ``shaft_rad`` more from now on, through its Homing Offset.

        Homing Offset lives in EEPROM, writable only with torque off: torque
        goes off for the write and back to what it was. Returns the shift
        applied, a whole number of ticks.
        """
        register = _register("Homing Offset")
        ticks = register.nearest(shaft_rad)
        new = self.read(sid, "Homing Offset") + ticks
        if abs(new) > register.maximum:
            raise BackendSetupError(
                f"servo ID {sid}: Homing Offset {new} ticks is beyond ±{register.maximum}; "
                f"the joint is too far from its reference for a register offset")
        torque = self.read(sid, "Torque Enable")
        try:
            if torque:
                self.write(sid, "Torque Enable", 0)
            self.write(sid, "Homing Offset", new)
        finally:
            if torque:
                self.write(sid, "Torque Enable", 1)
        return register.to_si(ticks)

    # -- transactions ---------------------------------------------------------------------
    def _model(self, sid: int) -> int:
        if sid not in self._models and self.ping(sid) is None:
            raise CommunicationError(f"servo ID {sid} did not answer a ping on {self.port} at "
                                     f"{self.baud} bps ({self.last_problem})")
        return self._models[sid]

    def _where(self, sid: int, name: str) -> tuple[int, int]:
        layout = register_layout(self._model(sid))
        if name not in layout:
            raise BackendSetupError(f"servo ID {sid} ({model_name(self._models[sid])}) has no "
                                     f"register {name!r}")
        return layout[name]

    def _transact(self, sid: int, instruction: int, params: bytes, reply_params: int,
                  required: bool = True, tries: Optional[int] = None) -> Optional[Packet]:
        """Send one instruction and return the servo's status packet (reads and writes repeat safely).

        The reply must come from ``sid`` with exactly ``reply_params`` parameters and
        nothing after it; anything else is retried after the line falls quiet, so a
        late answer to an earlier request is never taken for this one's.
        """
        packet = build_instruction(sid, instruction, params)
        wait = (len(packet) + 11 + reply_params) * self._byte_s + _LATENCY_S
        problem = "no reply"
        # That servo left another request unanswered: its late answer (held up on a loaded host
        # or in the adapter) would pass for this one's, its ID and length matching. The line falls
        # quiet first, and a status is taken only once no second one follows it closely.
        stale = self._unanswered.pop(sid, packet) != packet
        if stale:
            drain_until_quiet(self._link, wait, 4 * wait)
        for _ in range(self.tries if tries is None else max(1, tries)):
            self._drain()
            self._send(packet)
            replies = self._receive(self.clock.now() + wait, until_any=True)
            if not replies:
                problem = "a corrupt reply" if self._heard else "no reply"
                self._unanswered[sid] = packet  # a late answer to the same request is its answer
                if self._heard:  # the rest of a broken reply may still be on its way
                    drain_until_quiet(self._link, wait, 4 * wait)
                continue
            pkt = replies[0]
            if stale and not (self._trailing or self._pending()):
                self._trailing = self._link.wait(self.clock.now() + wait)
            problem = reply_mismatch(pkt, sid, reply_params) or (
                "bytes after the status (a duplicated or late reply)"
                if self._trailing or self._pending() else None)
            if problem is not None:
                drain_until_quiet(self._link, wait, 4 * wait)
                continue
            if pkt.error and pkt.error & 0x7F:
                raise BackendSetupError(f"servo ID {sid} refused {Instruction(instruction).name} "
                                         f"{params.hex(' ')}: {describe_status_error(pkt.error)}")
            return pkt
        self.last_problem = problem
        if required:
            raise CommunicationError(f"servo ID {sid} did not answer {Instruction(instruction).name} "
                                     f"on {self.port} at {self.baud} bps ({problem})")
        return None

    def _pending(self) -> bool:
        return self._link.waiting()

    def _receive(self, deadline: float, until_any: bool = False) -> list[Packet]:
        """Status packets until the deadline (or the first one, with ``until_any``)."""
        parser = PacketParser(stuffed=True, resync_on_header=False)
        got: list[Packet] = []
        self._heard = self._trailing = False
        while True:
            if self.clock.now() >= deadline or not self._link.wait(deadline):
                return got
            try:
                data = self._link.take(4096)
            except OSError as exc:
                raise CommunicationError(f"reading {self.port} failed: {exc}") from None
            self._heard = self._heard or bool(data)
            events = parser.feed(data)
            for k, event in enumerate(events):
                if isinstance(event, Packet) and event.is_status:
                    got.append(event)
                    if until_any:
                        self._trailing = k + 1 < len(events) or parser.pending > 0
                        return got

    def _send(self, packet: bytes) -> None:
        try:
            self._link.send(packet)
        except OSError as exc:
            raise CommunicationError(f"writing to {self.port} failed: {exc}") from None

    def _drain(self) -> None:
        try:
            while self._link.waiting():
                if not self._link.take(4096):
                    return
        except OSError:
            return


def _register(name: str) -> Register:
    """An X-series register, with its unit (every model the bus meets shares them)."""
    return x_series_table()[name]


def _si(name: str, raw: Optional[int]) -> Optional[float]:
    """A register's raw value in SI (its unit in the control table), or None when unread."""
    return float(_register(name).to_si(raw)) if raw is not None else None
