"""X-series control tables for the servo emulator, and the motor figures behind them.

Layout (address, size, name) comes from the ``.model`` files that ship with
dynamixel-sdk (``dynamixel_easy_sdk/control_table``), so the emulator and the
SDK can never disagree on where a register lives. Those files carry nothing
else, so access, EEPROM/RAM area, defaults, ranges and signedness are written
out below from the ROBOTIS e-manual control-table pages of each model
(XM430-W350, XL430-W250, XM540-W270, XC430-W150). Indirect addresses are not
emulated.

Each register also carries its unit and its converter to and from SI
(``unit``, ``scale``, ``zero``, ``divisor``; the units themselves are written once in
:mod:`drivers.dynamixel.units`), as pypot's register table carries its
``dxl_to_si``/``si_to_dxl`` pair: the driver, the emulator, the servo model and
the lab tools convert through the register, never with a constant of their own.

Motor figures (:class:`MotorSpec`) are the e-manual's 12 V stall torque,
stall current and no-load speed; the servo model derives a DC-motor model
from them (R = V/I_stall, Kt = T_stall/I_stall, Ke = V/w_no_load).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from enum import Enum
from functools import lru_cache
from typing import Callable, Iterator, Mapping

from drivers import BackendSetupError
from drivers.dynamixel.models import sdk_rows
from drivers.dynamixel.units import CENTER_TICK, CURRENT_REGISTERS, CURRENT_UNIT_A, CURRENT_UNIT_XL330_A, REGISTER_UNITS

__all__ = [
    "Access",
    "Area",
    "ControlTable",
    "ModelSpec",
    "MotorSpec",
    "Register",
    "WriteSlot",
    "XC430_W150",
    "XL430_W250",
    "XM430_W350",
    "XM540_W270",
    "XL330_M077",
    "XL330_M288",
    "model_spec",
    "STATE_BLOCK",
    "state_block",
    "supported_models",
    "x_series_table",
]

XM430_W350 = 1020
XL430_W250 = 1060
XC430_W150 = 1070
XM540_W270 = 1120
XL330_M077 = 1190
XL330_M288 = 1200



class Access(Enum):
    R = "R"
    RW = "RW"


class Area(Enum):
    EEPROM = "EEPROM"  # addresses < 64: writable only with torque off
    RAM = "RAM"


@dataclass(frozen=True)
class Register:
    """One control-table item. ``minimum``/``maximum`` are the fixed range (None: none).

    ``unit`` is the SI unit of :meth:`to_si` ("" for codes, counts, flags and gains, which
    have none; "1" for a fraction such as a PWM duty); a raw value ``r`` means
    ``(r - zero) * scale`` of it, or ``(r - zero) / divisor`` when the unit is a whole
    fraction of it (0.1 V, 1/885 of full PWM), so that decimal values stay exact."""

    name: str
    address: int
    size: int
    access: Access
    area: Area
    default: int
    minimum: int | None
    maximum: int | None
    signed: bool
    unit: str = ""
    #: SI per raw unit.
    scale: float = 1.0
    #: The raw value at SI zero (the centre tick of a position).
    zero: int = 0
    #: Raw units per SI unit when the unit is a whole fraction of it (0: use ``scale``).
    divisor: int = 0

    def to_si(self, raw):
        """The SI value of a raw value (a number or a numpy array)."""
        if self.divisor:
            return (raw - self.zero) / self.divisor
        return (raw - self.zero) * self.scale

    def from_si(self, value):
        """The raw value of an SI value, unrounded (a number or a numpy array): the caller
        rounds as the firmware does (or keeps the fraction, as an encoder model does)."""
        if self.divisor:
            return value * self.divisor + self.zero
        return value / self.scale + self.zero

    def nearest(self, value: float) -> int:
        """The whole raw value nearest an SI value (what is written to the register).

        The quotient is cleaned of float noise first, so that a value written in a decimal
        unit lands as exactly: 123 µs of Return Delay Time is 61.5 units (62), not 61.4999…
        """
        return int(round(round(self.from_si(value), 9)))

    def encode(self, value: int) -> bytes:
        """Little-endian bytes of ``value`` (two's complement when signed)."""
        return int(value).to_bytes(self.size, "little", signed=self.signed and value < 0)

    def decode(self, raw: bytes) -> int:
        return int.from_bytes(raw, "little", signed=self.signed)

    @property
    def codec(self) -> struct.Struct:
        """Little-endian struct of the item (``<i`` for a signed 4-byte item...).

        Packing a value within the item's range gives the bytes of :meth:`encode`;
        the servo uses it to keep its byte image current without per-call dispatch.
        """
        try:
            return _CODECS[self.size, self.signed]
        except KeyError:
            raise ValueError(f"{self.name}: no struct for a {self.size}-byte item") from None


_CODECS: dict[tuple[int, bool], struct.Struct] = {
    (size, signed): struct.Struct("<" + (code.lower() if signed else code))
    for size, code in ((1, "B"), (2, "H"), (4, "I"))
    for signed in (False, True)
}

#: One item a WRITE sets: the register, its offset in the written data and its decoder.
WriteSlot = tuple[Register, int, Callable[[bytes, int], tuple[int]]]


@dataclass(frozen=True)
class MotorSpec:
    """Datasheet figures at ``voltage`` (V); SI units."""

    voltage: float
    stall_torque: float  # N·m
    stall_current: float  # A
    no_load_speed: float  # rad/s at the output shaft

    @property
    def kt(self) -> float:
        """Torque constant at the output shaft (N·m/A), T_stall / I_stall."""
        return self.stall_torque / self.stall_current

    @property
    def resistance(self) -> float:
        """Winding resistance (Ω) that makes V / R equal the stall current."""
        return self.voltage / self.stall_current

    @property
    def ke(self) -> float:
        """Back-EMF constant at the output shaft (V·s/rad), V / w_no_load."""
        return self.voltage / self.no_load_speed


def _rpm(value: float) -> float:
    return value * 2.0 * math.pi / 60.0


class ControlTable:
    """Registers of one model, by name and by address."""

    def __init__(self, registers: list[Register]) -> None:
        self._by_name = {r.name: r for r in registers}
        self._by_address = {r.address: r for r in registers}
        self.size = max(r.address + r.size for r in registers)
        self._ordered = tuple(sorted(registers, key=lambda r: r.address))
        # Every access asks again with the same few (address, length) pairs: keep the answers.
        self._covering: dict[tuple[int, int], tuple[Register, ...]] = {}
        self._writes: dict[tuple[int, int], tuple[WriteSlot, ...] | None] = {}

    def __getitem__(self, name: str) -> Register:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"no register named {name!r} in this control table") from None

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __iter__(self) -> Iterator[Register]:
        return iter(self._ordered)

    def __len__(self) -> int:
        return len(self._by_name)

    def at(self, address: int) -> Register | None:
        """The register starting at ``address``, if any."""
        return self._by_address.get(address)

    def covering(self, address: int, length: int) -> list[Register]:
        """Registers overlapping ``[address, address + length)``, in address order."""
        return list(self._overlapping(address, length))

    def readable(self, address: int, length: int) -> bool:
        """Whether ``[address, address + length)`` lies in the table and touches an item."""
        return (length > 0 and address >= 0 and address + length <= self.size
                and bool(self._overlapping(address, length)))

    def write_slots(self, address: int, length: int) -> tuple[WriteSlot, ...] | None:
        """The items a WRITE of ``length`` bytes at ``address`` sets, in address order.

        Each comes with its offset in the written data and its decoder
        (``unpack_from(data, offset)[0]`` is its value). None when an item is only
        partly covered (Data Length Error); empty when no item is touched.
        The layout never changes, so the answer is worked out once per (address, length).
        """
        key = (address, length)
        try:
            return self._writes[key]
        except KeyError:
            pass
        slots: list[WriteSlot] | None = []
        for register in self._overlapping(address, length):
            start = register.address - address
            if start < 0 or start + register.size > length:
                slots = None
                break
            slots.append((register, start, register.codec.unpack_from))
        found = self._writes[key] = None if slots is None else tuple(slots)
        return found

    def _overlapping(self, address: int, length: int) -> tuple[Register, ...]:
        key = (address, length)
        found = self._covering.get(key)
        if found is None:
            end = address + length
            found = self._covering[key] = tuple(r for r in self._ordered
                                                if r.address < end and r.address + r.size > address)
        return found


@dataclass(frozen=True)
class ModelSpec:
    """Everything the emulator knows about one model."""

    number: int
    name: str
    table: ControlTable
    motor: MotorSpec
    operating_modes: frozenset[int]
    #: A per unit of Present/Goal Current; None for models reporting Present Load.
    current_unit: float | None
    extra: Mapping[str, object] = field(default_factory=dict)

    @property
    def senses_current(self) -> bool:
        return self.current_unit is not None

    @property
    def amps_per_unit(self) -> float:
        """A per unit of Present Current; on a model without current sensing, per unit of Present
        Load (its share of the stall current)."""
        if self.current_unit is not None:
            return self.current_unit
        return self.motor.stall_current * self.table["Present Load"].scale


# -- attributes written out from the e-manual ----------------------------------
# name: (access, default, minimum, maximum, signed)
_COMMON: dict[str, tuple[Access, int, int | None, int | None, bool]] = {
    "Model Number": (Access.R, 0, None, None, False),
    "Model Information": (Access.R, 0, None, None, False),
    "Firmware Version": (Access.R, 48, None, None, False),
    "ID": (Access.RW, 1, 0, 252, False),
    "Baud Rate": (Access.RW, 1, 0, 7, False),
    "Return Delay Time": (Access.RW, 250, 0, 254, False),
    "Drive Mode": (Access.RW, 0, 0, 13, False),
    "Operating Mode": (Access.RW, 3, 0, 16, False),
    "Secondary(Shadow) ID": (Access.RW, 255, 0, 255, False),
    # Protocol 1.0 is not emulated, so only 2 is accepted.
    "Protocol Type": (Access.RW, 2, 2, 2, False),
    "Homing Offset": (Access.RW, 0, -1_044_479, 1_044_479, True),
    "Moving Threshold": (Access.RW, 10, 0, 1023, False),
    "Temperature Limit": (Access.RW, 80, 0, 100, False),
    "Max Voltage Limit": (Access.RW, 160, 95, 160, False),
    "Min Voltage Limit": (Access.RW, 95, 95, 160, False),
    "PWM Limit": (Access.RW, 885, 0, 885, False),
    "PWM Slope": (Access.RW, 140, 1, 255, False),  # XL330 only (3.955 mV/ms)
    "Current Limit": (Access.RW, 1193, 0, 1193, False),
    "Velocity Limit": (Access.RW, 200, 0, 1023, False),
    "Max Position Limit": (Access.RW, 4095, 0, 4095, False),
    "Min Position Limit": (Access.RW, 0, 0, 4095, False),
    "External Port Mode 1": (Access.RW, 3, 0, 3, False),
    "External Port Mode 2": (Access.RW, 3, 0, 3, False),
    "External Port Mode 3": (Access.RW, 3, 0, 3, False),
    "Shutdown": (Access.RW, 52, 0, 255, False),
    "Torque Enable": (Access.RW, 0, 0, 1, False),
    "LED": (Access.RW, 0, 0, 1, False),
    "Status Return Level": (Access.RW, 2, 0, 2, False),
    "Registered Instruction": (Access.R, 0, None, None, False),
    "Hardware Error Status": (Access.R, 0, None, None, False),
    "Velocity I Gain": (Access.RW, 1920, 0, 16383, False),
    "Velocity P Gain": (Access.RW, 100, 0, 16383, False),
    "Position D Gain": (Access.RW, 0, 0, 16383, False),
    "Position I Gain": (Access.RW, 0, 0, 16383, False),
    "Position P Gain": (Access.RW, 800, 0, 16383, False),
    "Feedforward 2nd Gain": (Access.RW, 0, 0, 16383, False),
    "Feedforward 1st Gain": (Access.RW, 0, 0, 16383, False),
    "Bus Watchdog": (Access.RW, 0, 0, 127, False),
    # Goal PWM/Current/Velocity/Position are bounded by other registers (limit
    # checks in servo.py); the fixed ranges here are the register extremes.
    "Goal PWM": (Access.RW, 885, -885, 885, True),
    "Goal Current": (Access.RW, 1193, -2047, 2047, True),
    "Goal Velocity": (Access.RW, 0, -1023, 1023, True),
    "Profile Acceleration": (Access.RW, 0, 0, 32767, False),
    "Profile Velocity": (Access.RW, 0, 0, 32767, False),
    "Goal Position": (Access.RW, CENTER_TICK, -1_048_575, 1_048_575, True),
    "Realtime Tick": (Access.R, 0, None, None, False),
    "Moving": (Access.R, 0, None, None, False),
    "Moving Status": (Access.R, 0, None, None, False),
    "Present PWM": (Access.R, 0, None, None, True),
    "Present Current": (Access.R, 0, None, None, True),
    "Present Load": (Access.R, 0, None, None, True),
    "Present Velocity": (Access.R, 0, None, None, True),
    "Present Position": (Access.R, CENTER_TICK, None, None, True),
    "Velocity Trajectory": (Access.R, 0, None, None, True),
    "Position Trajectory": (Access.R, CENTER_TICK, None, None, True),
    "Present Input Voltage": (Access.R, 120, None, None, False),
    "Present Temperature": (Access.R, 30, None, None, False),
    "External Port Data 1": (Access.RW, 0, 0, 65535, False),
    "External Port Data 2": (Access.RW, 0, 0, 65535, False),
    "External Port Data 3": (Access.RW, 0, 0, 65535, False),
}

#: What the XL330s (M077, M288) set apart from the common table.
_XL330: dict[str, tuple[int, int, int]] = {
    "Temperature Limit": (70, 0, 100),
    "Max Voltage Limit": (70, 31, 70),
    "Min Voltage Limit": (35, 31, 70),
    "Current Limit": (1750, 0, 1750),
    "Goal Current": (1750, -1750, 1750),
    "Position P Gain": (400, 0, 16383),
    "Position D Gain": (0, 0, 16383),
    "Present Input Voltage": (50, None, None),
}

# Per-model: model file, defaults/ranges that differ, motor, operating modes.
_MODELS: dict[int, dict] = {
    XM430_W350: dict(
        file="xm430_w350.model",
        name="XM430-W350",
        overrides={},
        motor=MotorSpec(12.0, 4.1, 2.3, _rpm(46.0)),
        modes=(0, 1, 3, 4, 5, 16), current_unit=CURRENT_UNIT_A,
    ),
    XM540_W270: dict(
        file="xm540_w270.model",
        name="XM540-W270",
        overrides={
            "Current Limit": (2047, 0, 2047),
            "Goal Current": (2047, -2047, 2047),
            "Velocity Limit": (128, 0, 1023),
        },
        motor=MotorSpec(12.0, 10.6, 4.4, _rpm(30.0)),
        modes=(0, 1, 3, 4, 5, 16), current_unit=CURRENT_UNIT_A,
    ),
    XL430_W250: dict(
        file="xl430_w250.model",
        name="XL430-W250",
        overrides={
            "Temperature Limit": (72, 0, 100),
            "Max Voltage Limit": (140, 60, 140),
            "Min Voltage Limit": (60, 60, 140),
            "Velocity Limit": (415, 0, 1023),
            "Velocity I Gain": (1000, 0, 16383),
            "Position D Gain": (4000, 0, 16383),
            "Position P Gain": (640, 0, 16383),
        },
        motor=MotorSpec(12.0, 1.5, 1.4, _rpm(61.0)),
        modes=(1, 3, 4, 16), current_unit=None,
    ),
    XC430_W150: dict(
        file="xc430_w150.model",
        name="XC430-W150",
        overrides={
            "Max Voltage Limit": (160, 60, 160),
            "Min Voltage Limit": (60, 60, 160),
            "Velocity Limit": (460, 0, 1023),
            "Position P Gain": (460, 0, 16383),
        },
        motor=MotorSpec(12.0, 1.6, 1.4, _rpm(106.0)),
        modes=(1, 3, 4, 16), current_unit=None,
    ),
    # XL330 (5 V figures of the e-manual). Its firmware divides the P gain by 256, not the
    # manual's 128: measured on a real XL330 by BAM (Rhoban, "Better Actuator Models").
    XL330_M288: dict(
        file="xl330_m288.model",
        name="XL330-M288",
        overrides=_XL330 | {"Velocity Limit": (445, 0, 2047)},
        motor=MotorSpec(5.0, 0.52, 1.47, _rpm(103.0)),
        modes=(0, 1, 3, 4, 5, 16), current_unit=CURRENT_UNIT_XL330_A,
        extra={"p_gain_divisor": 256.0},
    ),
    XL330_M077: dict(
        file="xl330_m077.model",
        name="XL330-M077",
        overrides=_XL330 | {"Velocity Limit": (1620, 0, 2047)},
        motor=MotorSpec(5.0, 0.215, 1.47, _rpm(383.0)),
        modes=(0, 1, 3, 4, 5, 16), current_unit=CURRENT_UNIT_XL330_A,
        extra={"p_gain_divisor": 256.0},
    ),
}


def _sdk_layout(filename: str) -> tuple[tuple[int, int, str], ...]:
    """(address, size, name) rows of a dynamixel-sdk ``.model`` file; refused when missing."""
    rows = sdk_rows(filename)
    if not rows:
        raise BackendSetupError(
            f"no [control table] rows in dynamixel-sdk file {filename!r} (dynamixel_easy_sdk "
            "package); install dynamixel-sdk>=4.0")
    return rows


@lru_cache(maxsize=None)
def model_spec(model: int) -> ModelSpec:
    """The :class:`ModelSpec` for a model number (1020, 1060, 1070, 1120, 1190 or 1200)."""
    try:
        info = _MODELS[model]
    except KeyError:
        raise BackendSetupError(
            f"model number {model} is not emulated; supported: {sorted(_MODELS)}"
        ) from None
    registers = []
    for address, size, name in _sdk_layout(info["file"]):
        if name.startswith("Indirect") or name in {r.name for r in registers}:
            continue
        try:
            access, default, lo, hi, signed = _COMMON[name]
        except KeyError:
            raise BackendSetupError(
                f"register {name!r} (address {address}) of {info['name']} has no attributes here"
            ) from None
        if name in info["overrides"]:
            default, lo, hi = info["overrides"][name]
        if name == "Model Number":
            default = model
        area = Area.EEPROM if address < 64 else Area.RAM
        if name in CURRENT_REGISTERS:
            unit = ("A", info["current_unit"], 0, 0)
        else:
            unit = REGISTER_UNITS.get(name, ("", 1.0, 0, 0))
        registers.append(Register(name, address, size, access, area, default, lo, hi, signed, *unit))
    return ModelSpec(
        number=model,
        name=info["name"],
        table=ControlTable(registers),
        motor=info["motor"],
        operating_modes=frozenset(info["modes"]),
        current_unit=info["current_unit"],
        extra=info.get("extra", {}),
    )


def supported_models() -> dict[int, str]:
    """Model number -> model name of every emulated model."""
    return {number: info["name"] for number, info in _MODELS.items()}


def x_series_table() -> ControlTable:
    """The register layout the supported X-series models share (the host-side drivers use it;
    a test checks every emulated model agrees on each register the drivers touch)."""
    return model_spec(XM430_W350).table


#: The registers every control cycle reads, contiguous in this order.
STATE_BLOCK = ("Present Current", "Present Velocity", "Present Position")


@lru_cache(maxsize=None)
def state_block() -> tuple[int, int]:
    """(address, length) of :data:`STATE_BLOCK`: one Sync Read per cycle gets all three."""
    table = x_series_table()
    regs = [table[name] for name in STATE_BLOCK]
    for r, nxt in zip(regs, regs[1:]):
        if r.address + r.size != nxt.address:
            raise BackendSetupError(f"{r.name} and {nxt.name} are not contiguous in the control table")
    return regs[0].address, regs[-1].address + regs[-1].size - regs[0].address
