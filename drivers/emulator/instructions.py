"""The emulated servos' Protocol 2.0 instructions, one method each: PING, READ, WRITE, REG WRITE,
ACTION, FACTORY RESET, REBOOT, CLEAR, the sync and bulk reads and writes (fast ones too)."""

from __future__ import annotations

from typing import Callable

from drivers.dynamixel.identity import EMULATED_ADDRESS, EMULATED_LENGTH, EMULATED_REPLY
from drivers.dynamixel.parser import Packet
from drivers.dynamixel.protocol import (
    BROADCAST_ID,
    FastStatusBlock,
    Instruction,
    StatusError,
    build_fast_status,
)
from drivers.emulator.servo import ServoModel

__all__ = ["InstructionSet"]

READ_INSTRUCTIONS = {
    Instruction.PING,
    Instruction.READ,
    Instruction.SYNC_READ,
    Instruction.FAST_SYNC_READ,
    Instruction.BULK_READ,
    Instruction.FAST_BULK_READ,
}
#: Instructions answering control-table state, which must be current when they are answered.
STATE_READS = frozenset(READ_INSTRUCTIONS - {Instruction.PING})
#: Instructions that can set something moving: they end a rest.
WAKING = frozenset(Instruction) - READ_INSTRUCTIONS - {Instruction.STATUS}


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)


class InstructionSet:
    """Part of :class:`~drivers.emulator.bus.DynamixelBusEmulator` (a mixin: it uses the bus's state)."""

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
        if (address, length) == (EMULATED_ADDRESS, EMULATED_LENGTH):  # the bus says it is emulated
            self._reply(servo, 0, EMULATED_REPLY, instruction=pkt.instruction)
            return
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
                self._deaf_until[id(servo)] = self._bus_now() + self.boot_time_s

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

    _HANDLERS: dict[int, Callable[["InstructionSet", Packet, dict[int, ServoModel]], None]] = {
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
