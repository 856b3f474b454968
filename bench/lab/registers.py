"""One servo's whole control table as Dynamixel Wizard shows it, read only: each register's name,
address, size, access, raw value and its value in SI with the unit.

Every conversion is the register's own (:class:`drivers.dynamixel.control_table.Register`),
so this view and the driver can never disagree on what a raw value means. Nothing is
written: the view is safe on a rig that is running.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Callable, Iterator, Optional

from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.control_table import Area, model_spec
from drivers.errors import CommunicationError

__all__ = ["RegisterReading", "ServoTable", "read_table", "watch_table"]


@dataclass(frozen=True)
class RegisterReading:
    """One register as read: raw value, and its SI value and unit (None, "" for a code or a count)."""

    name: str
    address: int
    size: int
    access: str
    area: str
    raw: int
    value: Optional[float]
    unit: str

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ServoTable:
    """A servo's control table as read at ``time`` (s, monotonic)."""

    id: int
    model: str
    time: float
    registers: tuple[RegisterReading, ...]

    def as_dict(self) -> dict:
        return {"id": self.id, "model": self.model,
                "registers": [{k: v for k, v in r.as_dict().items() if k != "area"} for r in self.registers]}


def read_table(bus: ServoBus, sid: int, ram_only: bool = False) -> ServoTable:
    """Every register of servo ``sid`` (its model's table), by address; ``ram_only``: the RAM
    area alone (what changes while it runs). CommunicationError when the servo does not answer."""
    reply = bus.ping(sid)
    if reply is None:
        raise CommunicationError(f"servo ID {sid} did not answer a ping on {bus.port} at {bus.baud} bps"
                                 + (f" ({bus.last_problem})" if bus.last_problem else ""))
    spec = model_spec(reply.model)
    readings = []
    for reg in spec.table:
        if ram_only and reg.area is not Area.RAM:
            continue
        raw = bus.read(sid, reg.name)
        value = float(reg.to_si(raw)) if reg.unit else None
        readings.append(RegisterReading(reg.name, reg.address, reg.size, reg.access.value, reg.area.value,
                                        raw, value, reg.unit))
    return ServoTable(sid, spec.name, time.monotonic(), tuple(readings))


def watch_table(bus: ServoBus, sid: int, period_s: float = 0.2,
                stop: Callable[[], bool] = lambda: False) -> Iterator[ServoTable]:
    """The whole table once, then its RAM area every ``period_s`` until ``stop()``: the EEPROM
    registers only change with torque off, the RAM ones as the servo runs."""
    whole = read_table(bus, sid)
    yield whole
    eeprom = tuple(r for r in whole.registers if r.area != Area.RAM.value)
    while not stop():
        t_next = time.monotonic() + period_s
        ram = read_table(bus, sid, ram_only=True)
        yield ServoTable(sid, ram.model, ram.time, tuple(sorted(eeprom + ram.registers, key=lambda r: r.address)))
        time.sleep(max(0.0, t_next - time.monotonic()))
