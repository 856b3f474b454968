"""Find every servo on a port: one broadcast ping per baud rate, then each servo's own registers.

Servos fresh from the box listen at 57600 bps, the bench runs at 1 Mbps, and a
servo someone reconfigured may be anywhere in between; a servo answers only
at its own rate, so the scan pings at each rate asked for. Two servos with
the same ID at different rates are both listed (they would collide once at
the same rate).
"""

from __future__ import annotations

from typing import Callable, Iterable, Optional

from drivers.dynamixel.bus import PingReply, ServoBus, ServoStatus
from drivers.dynamixel.protocol import MAX_ID
from drivers.dynamixel.units import BAUD_RATES
from drivers.errors import CommunicationError

__all__ = ["ALL_BAUDS", "DEFAULT_BAUDS", "check_bauds", "scan_bus", "servo_row"]

ALL_BAUDS: tuple[int, ...] = tuple(sorted(BAUD_RATES.values()))
DEFAULT_BAUDS: tuple[int, ...] = (57_600, 1_000_000)  # factory default and the bench's default


def check_bauds(bauds: Iterable[int]) -> list[int]:
    """The rates in order, each an X-series rate (ValueError naming the bad one)."""
    out = []
    for b in bauds:
        if b not in ALL_BAUDS:
            raise ValueError(f"--baud {b} is not an X-series rate; choose from "
                             f"{', '.join(str(x) for x in ALL_BAUDS)}")
        if b not in out:
            out.append(b)
    return out


def scan_bus(port: str, bauds: Iterable[int], max_id: int = MAX_ID,
             progress: Optional[Callable[[int, int], None]] = None) -> list[ServoStatus]:
    """Every servo answering on ``port`` at any of ``bauds``, by baud rate then ID.

    ``progress(done, total)`` is called after each rate. Raises
    :class:`~drivers.BackendSetupError` (one line) when the port cannot be used.
    """
    rates = check_bauds(bauds)
    found: list[ServoStatus] = []
    with ServoBus(port, rates[0]) as bus:
        for k, baud in enumerate(rates):
            bus.set_baud(baud)
            for reply in bus.broadcast_ping(max_id):
                status = _status(bus, reply)
                if status.baud is None:  # a model without a Baud Rate register
                    status = ServoStatus(**{**status.as_dict(), "baud": baud})
                found.append(status)
            if progress is not None:
                progress(k + 1, len(rates))
    return found


def _status(bus: ServoBus, reply: PingReply) -> ServoStatus:
    """The servo's registers; a read lost to a busy host (or a noisy line) is asked once more,
    the whole status again, before the scan gives up with the one line saying which."""
    try:
        return bus.status(reply)
    except CommunicationError:
        return bus.status(reply)


def servo_row(s: ServoStatus) -> dict:
    """One servo as the JSON the CLI prints (SI units, fault names)."""
    return {"id": s.id, "model": s.model_name, "model_number": s.model, "firmware": s.firmware,
            "baud": s.baud, "operating_mode": s.operating_mode, "torque": s.torque,
            "hardware_error": s.hardware_error, "return_delay_s": s.return_delay_s,
            "voltage_v": s.voltage_v, "temperature_c": s.temperature_c}
