"""One servo on a test stand, in SI: the host side of a stand recording (goal, torque, P gain
written; position, velocity, supply and temperature read), raw units converted here."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK, VELOCITY_UNIT_RAD_S

__all__ = ["StandSample", "StandServo"]


@dataclass(frozen=True)
class StandSample:
    """What the host reads each cycle: shaft angle (rad, 0 at tick 2048), velocity (rad/s),
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
        self.bus.write(self.sid, "Goal Position", CENTER_TICK + int(round(shaft_rad / RAD_PER_TICK)))

    def sample(self) -> StandSample:
        b, sid = self.bus, self.sid
        return StandSample(position=b.shaft_angle(sid),
                           velocity=b.read(sid, "Present Velocity") * VELOCITY_UNIT_RAD_S,
                           volts=b.read(sid, "Present Input Voltage") / 10.0,
                           temperature=float(b.read(sid, "Present Temperature")))
