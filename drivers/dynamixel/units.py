"""X-series units and codes, written once: each register unit in SI (ticks, velocity,
acceleration, current, voltage, PWM, Return Delay Time...), operating modes and baud rates
(ROBOTIS e-manual). The control table (:mod:`drivers.dynamixel.control_table`) gives each
register its unit and converter from these; every other module converts through the
register (``table["Present Position"].to_si(raw)``), so a unit is written here and nowhere
else, and raw units never leave ``drivers/``."""

from __future__ import annotations

import math
from enum import IntEnum

__all__ = [
    "ACCEL_UNIT_RAD_S2", "BAUD_RATES", "CENTER_TICK", "CURRENT_REGISTERS", "CURRENT_UNIT_A",
    "CURRENT_UNIT_XL330_A", "PWM_SLOPE_UNIT_V_S",
    "LOAD_UNITS_PER_STALL", "MODE_NAMES", "OPERATING_MODES", "OperatingMode", "POSITION_MODES",
    "PWM_FULL_SCALE", "RAD_PER_TICK", "REALTIME_TICKS_PER_S", "REGISTER_UNITS", "RETURN_DELAY_UNIT_S",
    "TEMPERATURE_UNIT_C", "TICKS_PER_REV", "VELOCITY_UNIT_RAD_S", "VOLTAGE_UNITS_PER_V",
    "WATCHDOG_UNIT_S",
]

TICKS_PER_REV = 4096
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
#: Present Position of a servo at its zero (the middle of one turn).
CENTER_TICK = 2048
#: Velocity registers (Profile/Present Velocity): 0.229 rev/min per unit.
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0
#: Profile Acceleration: 214.577 rev/min² per unit.
ACCEL_UNIT_RAD_S2 = 214.577 * 2.0 * math.pi / 3600.0
#: Goal/Present Current and Current Limit of the XL330s: 1 mA.
CURRENT_UNIT_XL330_A = 1.0e-3
#: PWM Slope of the XL330s (how fast the drive voltage may change): 3.955 mV/ms per unit.
PWM_SLOPE_UNIT_V_S = 3.955
#: Goal/Present PWM at 100 % duty.
PWM_FULL_SCALE = 885
#: Goal/Present Current and Current Limit of the models that sense current (XM430, XM540): 2.69 mA.
CURRENT_UNIT_A = 2.69e-3
#: Present Load of the models that do not (XL430, XC430): units per stall torque (0.1 % each).
LOAD_UNITS_PER_STALL = 1000
#: Return Delay Time: 2 µs per unit.
RETURN_DELAY_UNIT_S = 2.0e-6
#: Present Input Voltage and the voltage limits: units per volt (0.1 V each).
VOLTAGE_UNITS_PER_V = 10
#: Present Temperature and Temperature Limit: 1 °C per unit.
TEMPERATURE_UNIT_C = 1.0
#: Realtime Tick: units per second (1 ms each; wraps at 32767).
REALTIME_TICKS_PER_S = 1000
#: Bus Watchdog: 20 ms per unit.
WATCHDOG_UNIT_S = 20.0e-3


def _times(unit: str, scale: float, zero: int = 0) -> tuple[str, float, int, int]:
    """A register worth ``scale`` of ``unit`` per raw unit (raw ``zero`` at SI zero)."""
    return unit, scale, zero, 0


def _per(unit: str, divisor: int) -> tuple[str, float, int, int]:
    """A register worth 1/``divisor`` of ``unit`` per raw unit: converted by dividing, so that
    120 of Present Input Voltage is 12.0 V exactly rather than 12.000000000000002."""
    return unit, 1.0 / divisor, 0, divisor


#: Register name -> (SI unit, SI per raw unit, raw value at SI zero, divisor or 0): the control
#: table gives each register its converter from these. Registers not named here are codes,
#: counts, flags or gains.
REGISTER_UNITS: dict[str, tuple[str, float, int, int]] = {
    "Return Delay Time": _times("s", RETURN_DELAY_UNIT_S),
    "Homing Offset": _times("rad", RAD_PER_TICK),
    "Moving Threshold": _times("rad/s", VELOCITY_UNIT_RAD_S),
    "Temperature Limit": _times("°C", TEMPERATURE_UNIT_C),
    "Present Temperature": _times("°C", TEMPERATURE_UNIT_C),
    "Max Voltage Limit": _per("V", VOLTAGE_UNITS_PER_V),
    "Min Voltage Limit": _per("V", VOLTAGE_UNITS_PER_V),
    "Present Input Voltage": _per("V", VOLTAGE_UNITS_PER_V),
    "PWM Limit": _per("1", PWM_FULL_SCALE),
    "PWM Slope": _times("V/s", PWM_SLOPE_UNIT_V_S),
    "Goal PWM": _per("1", PWM_FULL_SCALE),
    "Present PWM": _per("1", PWM_FULL_SCALE),
    "Present Load": _per("1", LOAD_UNITS_PER_STALL),
    "Velocity Limit": _times("rad/s", VELOCITY_UNIT_RAD_S),
    "Goal Velocity": _times("rad/s", VELOCITY_UNIT_RAD_S),
    "Present Velocity": _times("rad/s", VELOCITY_UNIT_RAD_S),
    "Velocity Trajectory": _times("rad/s", VELOCITY_UNIT_RAD_S),
    # Drive Mode bit 2 (time-based profile) makes these two ms instead.
    "Profile Velocity": _times("rad/s", VELOCITY_UNIT_RAD_S),
    "Profile Acceleration": _times("rad/s²", ACCEL_UNIT_RAD_S2),
    "Max Position Limit": _times("rad", RAD_PER_TICK, CENTER_TICK),
    "Min Position Limit": _times("rad", RAD_PER_TICK, CENTER_TICK),
    "Goal Position": _times("rad", RAD_PER_TICK, CENTER_TICK),
    "Present Position": _times("rad", RAD_PER_TICK, CENTER_TICK),
    "Position Trajectory": _times("rad", RAD_PER_TICK, CENTER_TICK),
    "Realtime Tick": _per("s", REALTIME_TICKS_PER_S),
    "Bus Watchdog": _times("s", WATCHDOG_UNIT_S),
}
#: The current registers: A, in the model's own unit (its ``current_unit``, e.g. CURRENT_UNIT_A).
CURRENT_REGISTERS = ("Current Limit", "Goal Current", "Present Current")


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
