"""Status packets onto the wire: Status Return Level, the bus faults (drop, corrupt, delay, silence),
the Return Delay Time and each packet's transfer time."""

from __future__ import annotations

import os

from drivers.dynamixel.protocol import Instruction, build_status
from drivers.emulator.instructions import READ_INSTRUCTIONS
from drivers.emulator.servo import ServoModel
from drivers.timing import sleep_until

__all__ = ["StatusWire"]



class StatusWire:
    """Part of :class:`~drivers.emulator.bus.DynamixelBusEmulator` (a mixin: it uses the bus's state)."""

    def _reply(
        self, servo: ServoModel, error: int, params: bytes = b"", *, instruction: int
    ) -> None:
        level = self._levels.get(id(servo))
        if level is None:
            level = servo.status_return_level
        if instruction != Instruction.PING and (
            level == 0 or (level == 1 and instruction not in READ_INSTRUCTIONS)
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
