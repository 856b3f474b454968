"""X-series units and codes, written once: ticks, velocity and acceleration units, the PWM scale,
operating modes and baud rates (ROBOTIS e-manual). Raw units never leave ``drivers/``: the
backend, the lab bus and the emulator convert to SI here and nowhere else."""

from __future__ import annotations

import math
from enum import IntEnum

__all__ = [
    "ACCEL_UNIT_RAD_S2", "BAUD_RATES", "CENTER_TICK", "HOMING_OFFSET_LIMIT", "MODE_NAMES", "OPERATING_MODES",
    "OperatingMode", "POSITION_MODES", "PWM_FULL_SCALE", "RAD_PER_TICK", "TICKS_PER_REV",
    "VELOCITY_UNIT_RAD_S",
]

TICKS_PER_REV = 4096
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
#: Present Position of a servo at its zero (the middle of one turn).
CENTER_TICK = 2048
#: Homing Offset (20) range, ticks.
HOMING_OFFSET_LIMIT = 1_044_479
#: Velocity registers (Profile/Present Velocity): 0.229 rev/min per unit.
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0
#: Profile Acceleration: 214.577 rev/min² per unit.
ACCEL_UNIT_RAD_S2 = 214.577 * 2.0 * math.pi / 3600.0
#: Goal/Present PWM at 100 % duty.
PWM_FULL_SCALE = 885


class OperatingMode(IntEnum):
    """Operating Mode (11) values."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


#: The names configs use -> Operating Mode value.
OPERATING_MODES: dict[str, int] = {m.name.lower(): int(m) for m in OperatingMode}
#: Operating Mode value -> the name configs use.
MODE_NAMES: dict[int, str] = {v: k for k, v in OPERATING_MODES.items()}
#: The modes in which the firmware closes a position loop.
POSITION_MODES = frozenset({OperatingMode.POSITION, OperatingMode.EXTENDED_POSITION,
                            OperatingMode.CURRENT_BASED_POSITION})

#: Baud Rate (8) register value -> bit/s.
BAUD_RATES: dict[int, int] = {0: 9_600, 1: 57_600, 2: 115_200, 3: 1_000_000, 4: 2_000_000,
                              5: 3_000_000, 6: 4_000_000, 7: 4_500_000}
