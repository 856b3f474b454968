"""The test stand on the emulated servo bus: one XL330 (ID 1 unless told, 1 Mbps) driving the stand's URDF
(a mass on an arm) through the shared servo model and plant, with hidden physics in the keys of
a servo model file — a stand to rehearse recording, identification and prediction on, whose
answer is known. One parameter path: the same parameters build the emulated servo's motor (Kt,
Ke, R) and the plant's friction, applied by the stick-slip law the stand's rollout applies."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Mapping, Optional

from bench.config.servo_model import apply_physics
from bench.paths import URDF_DIR
from bench.scene.urdf_writer import STAND_LENGTH_M, STAND_MASS_KG, stand_urdf
from bench.stand.logs import MOTORS
from bench.stand.simulate import GRAVITY
from drivers.clock import VirtualClock
from drivers.emulator import DynamixelBusEmulator, ServoModel, VirtualBusEmulator
from drivers.servo import ServoParams
from drivers.servo.plant import PyBulletPlant

__all__ = ["EmulatedStand"]

#: Baud Rate register value of 1 Mbps, as BAM's recordings ran.
BAUD_INDEX, BAUD = 3, 1_000_000


class _SaggingPlant(PyBulletPlant):
    """The stand's plant, whose step also sets the servo's supply: ``volts − source_ohm·|I|`` with I
    the motor's current (its torque over Kt), as a battery or bench supply with a source
    resistance sags under a stalled arm. Present Input Voltage reports it (0.1 V steps)."""

    servo: ServoModel | None = None
    volts: float = 7.0
    source_ohm: float = 0.0
    kt: float = 1.0

    def step(self, dt: float, torque) -> None:
        super().step(dt, torque)
        if self.servo is not None and self.source_ohm > 0:
            self.servo.input_voltage = self.volts - self.source_ohm * abs(float(torque[0])) / self.kt


class EmulatedStand:
    """A context manager serving the stand's bus on a pseudo-terminal (:attr:`port`). With
    ``realtime`` False the physics moves only through :meth:`advance`. ``source_ohm``: the
    supply's source resistance (0: a stiff supply at ``supply_v``). ``gravity_offset_rad``: the
    stand's zero from hanging plumb, as a stand model file's ``stand:`` gives it (gravity tilted
    about the shaft, so its torque is −m g L sin(q + offset), the rollout's). On a ``clock`` (a
    :class:`~drivers.clock.VirtualClock`) the bus is a ``virtual://`` line of this process and
    everything, the wire's time included, moves on that clock."""

    def __init__(self, physics: Mapping[str, float] | None = None, *, mass: float = STAND_MASS_KG,
                 length: float = STAND_LENGTH_M, supply_v: float = 7.0, motor: str = "xl330",
                 servo_id: int = 1, source_ohm: float = 0.0, realtime: bool = False,
                 gravity_offset_rad: float = 0.0, clock: Optional[VirtualClock] = None) -> None:
        number = MOTORS[motor]
        physics = dict(physics or {})
        self.params = apply_physics(ServoParams.datasheet([number]), [physics])
        self._tmp = None
        urdf = URDF_DIR / "test_stand_xl330.urdf"
        if (mass, length) != (STAND_MASS_KG, STAND_LENGTH_M):
            self._tmp = tempfile.TemporaryDirectory(prefix="stand-")
            urdf = Path(self._tmp.name) / "stand.urdf"
            urdf.write_text(stand_urdf(mass, length))
        tilt = (0.0, -GRAVITY * math.sin(gravity_offset_rad), -GRAVITY * math.cos(gravity_offset_rad))
        self.plant = _SaggingPlant(urdf, ["pendulum"], [1.0], [0.0], [0.0], self.params, gravity=tilt,
                                   friction_law="stick")
        servo = ServoModel(number, id=servo_id, registers={"Baud Rate": BAUD_INDEX}, input_voltage=supply_v,
                           motor=self.params, overload_time_s=60.0)
        self.plant.servo, self.plant.volts, self.plant.source_ohm = servo, supply_v, source_ohm
        self.plant.kt = float(self.params.kt[0])
        self.clock = clock
        if clock is None:
            self.bus = DynamixelBusEmulator({servo_id: servo}, self.plant, realtime=realtime)
        else:
            self.bus = VirtualBusEmulator({servo_id: servo}, self.plant, clock=clock, name=f"stand-{id(self):x}")
        self.mass, self.length, self.supply_v = mass, length, supply_v

    @property
    def port(self) -> str:
        return self.bus.port

    def advance(self, seconds: float) -> None:
        self.bus.advance(seconds)

    def __enter__(self) -> "EmulatedStand":
        self.bus.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bus.stop()
        self.plant.close()
        if self._tmp is not None:
            self._tmp.cleanup()
