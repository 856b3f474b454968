"""One servo on a test stand, in SI: the host side of a stand recording (goal, torque, P gain
written; position, velocity, supply and temperature read), raw units converted here."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.control_table import x_series_table

__all__ = ["StandSample", "StandServo"]

_TABLE = x_series_table()  # every unit below converts through its register


@dataclass(frozen=True)
class StandSample:
    """What the host reads each cycle: shaft angle (rad, 0 at the centre tick), velocity (rad/s),
    supply (V) and temperature (°C)."""

    position: float
    velocity: float
    volts: float
    temperature: float


class StandServo:
    """The servo ``sid`` on ``bus`` as a stand recording drives it."""

    def __init__(self, bus: ServoBus, sid: int = 1) -> None:
        self.bus = bus
        self.sid = sid

    def set_p_gain(self, kp: int) -> None:
        self.bus.write(self.sid, "Position P Gain", int(kp))

    def torque(self, on: bool) -> None:
        self.bus.write(self.sid, "Torque Enable", 1 if on else 0)

    def goal(self, shaft_rad: float) -> None:
        self.bus.write(self.sid, "Goal Position", _TABLE["Goal Position"].nearest(shaft_rad))

    def sample(self) -> StandSample:
        b, sid = self.bus, self.sid
        return StandSample(position=b.shaft_angle(sid),
                           velocity=float(_TABLE["Present Velocity"].to_si(b.read(sid, "Present Velocity"))),
                           volts=float(_TABLE["Present Input Voltage"].to_si(b.read(sid, "Present Input Voltage"))),
                           temperature=float(_TABLE["Present Temperature"].to_si(b.read(sid, "Present Temperature"))))
