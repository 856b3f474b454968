"""One emulated X-series servo: control-table memory, firmware rules and motor physics.

Register rules (ROBOTIS e-manual, Protocol 2.0 and X-series control tables):

* EEPROM (address < 64) is writable only with Torque Enable = 0, otherwise
  Access Error 0x07; so are read-only items and addresses holding no item.
* A value outside an item's fixed range gets Data Range Error 0x04 (e.g.
  Operating Mode 2, Return Delay Time 255, Goal Position beyond ±1,048,575
  in extended position mode).
* A value beyond a bound set by another register gets Data Limit Error 0x06
  ("data to be written is outside of the Limit value"): Goal Position outside
  Min/Max Position Limit in Position Control Mode, |Goal Current| > Current
  Limit, |Goal Velocity| > Velocity Limit, |Goal PWM| > PWM Limit. Users of
  real XM430s report this error for Goal Current above Current Limit.
* A write covering only part of a multi-byte item gets Data Length Error 0x05.
* A rejected write changes nothing (the whole instruction is refused).

Emulator choices where the e-manual is silent (documented, not firmware-verified):
Torque Enable 0 -> 1 sets Goal Position to Present Position so the servo holds
still; Torque Enable = 1 while a shutdown error is latched answers Result Fail
0x01; hardware-error bits latch until REBOOT and the alert bit (0x80) is set on
every status packet while any is latched; bits not selected in Shutdown(63)
are reported but do not switch the torque off.

Physics per substep (the firmware's loop runs at ``CONTROL_PERIOD_S`` = 1 ms):

1. Profile: Goal Position -> Position/Velocity Trajectory with Profile
   Velocity (0.229 rev/min) and Profile Acceleration (214.577 rev/min²), a
   trapezoid; 0 means unlimited. Drive Mode bit 2 selects the time-based
   profile (Profile Velocity = total time, Profile Acceleration = ramp time,
   in ms).
2. Position PID on the encoder reading (integer ticks): KPP = P/128,
   KPI = I/65536, KPD = D/16 per 1 ms sample, output in PWM units (885 = 100 %)
   limited by Goal PWM and PWM Limit — or, in Current-based Position Control
   Mode, in current units limited by Goal Current. Velocity mode: KVP = P/128,
   KVI = I/65536. Feed-forward gains are stored but not applied.
3. Motor: V = PWM/885 · V_in, I = (V − Ke·w)/R, clamped to ±Current Limit,
   torque = Kt·I. R, Ke, Kt come from the datasheet stall/no-load figures
   (:class:`~drivers.dynamixel.control_table.MotorSpec`); XM430-W350 at 12 V:
   4.1 N·m / 2.3 A -> Kt = 1.78 N·m/A, R = 5.2 Ω, Ke = 2.49 V·s/rad (46 rpm).
4. Reports: Present Position = encoder ticks (4096/rev, 0.088°) + Homing
   Offset, tick 2048 = 0 rad; Present Velocity in 0.229 rev/min; Present
   Current in 2.69 mA (Present Load in 0.1 % of stall current on XL/XC430);
   Moving = |Present Velocity| > Moving Threshold or a profile in progress.
5. Overload: |I| at >= ``overload_fraction`` of the largest current the
   supply and Current Limit allow, continuously for more than
   ``overload_time_s`` -> Hardware Error Status bit 5; with the default
   Shutdown (52) that switches the torque off until REBOOT.

An optional deadband (ticks) makes the servo stop correcting once it is
within ±deadband of the goal, like a worn or deliberately detuned unit.
"""

from __future__ import annotations

import math
import struct
from typing import Mapping, NoReturn

from drivers.dynamixel.control_table import XM430_W350, Access, Area, ModelSpec, Register, model_spec
from drivers.dynamixel.protocol import ALERT_BIT, HARDWARE_ERROR_BITS, StatusError
from drivers.dynamixel.units import BAUD_RATES, OperatingMode
from drivers.emulator.firmware import CONTROL_PERIOD_S, NOT_LOOP_INPUTS, REPORTED, ServoFirmware
from drivers.servo.model import ServoParams

__all__ = ["CONTROL_PERIOD_S", "ServoModel"]

_CLEAR_MAGIC = bytes((0x01, 0x44, 0x58, 0x4C, 0x22))


_HW_BIT = {name: bit for bit, name in HARDWARE_ERROR_BITS.items()}
#: Items whose accepted values depend on other registers (see ``_check_limits``).
_INT32 = struct.Struct("<i")
_CROSS_CHECKED = frozenset(
    {"Operating Mode", "Goal Position", "Goal Current", "Goal Velocity", "Goal PWM",
     "Torque Enable"}
)


class ServoModel(ServoFirmware):
    """An emulated servo with its own control table, driven through the bus emulator.

    ``registers`` sets initial values by item name on top of the factory
    defaults (e.g. ``{"Baud Rate": 3, "Operating Mode": 4}``) without write
    checks; FACTORY_RESET returns to the factory defaults, REBOOT keeps EEPROM.
    """

    def __init__(
        self,
        model: int | ModelSpec = XM430_W350,
        *,
        id: int = 1,  # noqa: A002 - the register's name
        registers: Mapping[str, int] | None = None,
        deadband_ticks: int = 0,
        overload_time_s: float = 1.0,
        overload_fraction: float = 0.95,
        input_voltage: float = 12.0,
        temperature_c: float = 30.0,
        kt_scale: float = 1.0,
        motor: ServoParams | None = None,
    ) -> None:
        self.spec = model if isinstance(model, ModelSpec) else model_spec(model)
        self.table = self.spec.table
        if not kt_scale > 0:
            raise ValueError(f"kt_scale must be > 0, got {kt_scale}")
        # The motor the firmware drives: the servo parameters of a model file (``motor``, one slot:
        # Kt, Ke, R as identified), or the datasheet's, kt_scale making it stronger or weaker (Kt and
        # Ke are one constant in SI).
        if motor is not None:
            if motor.n != 1:
                raise ValueError(f"an emulated servo runs one motor, got parameters of {motor.n}")
            self._motor = motor
        else:
            spec = self.spec.motor
            self._motor = ServoParams.datasheet([self.spec.number]).with_(
                kt=spec.kt * kt_scale, ke=spec.ke * kt_scale, resistance=spec.resistance)
        self._kt, self._ke, self._resistance = (float(self._motor.kt[0]), float(self._motor.ke[0]),
                                                float(self._motor.resistance[0]))
        self._amps_per_unit = self.spec.amps_per_unit
        # The registers whose units the 1 ms loop converts with (the control table's).
        self._position_reg, self._velocity_reg, self._accel_reg, self._voltage_reg, \
            self._temperature_reg, self._tick_reg = (
                self.table[n] for n in ("Present Position", "Present Velocity", "Profile Acceleration",
                                        "Present Input Voltage", "Present Temperature", "Realtime Tick"))
        self._has_current_limit = "Current Limit" in self.table
        # The cycle's Goal Position writes take a short path when the item is the usual
        # 4-byte signed RAM register (every X-series model); -1: always the general one.
        goal = self.table["Goal Position"] if "Goal Position" in self.table else None
        fast_goal = (goal is not None and goal.size == 4 and goal.signed
                     and goal.access is Access.RW and goal.area is Area.RAM)
        self._goal_register = goal
        self._goal_address = goal.address if fast_goal else -1
        if deadband_ticks < 0:
            raise ValueError(f"deadband_ticks must be >= 0, got {deadband_ticks}")
        if overload_time_s <= 0:
            raise ValueError(f"overload_time_s must be > 0 s, got {overload_time_s}")
        if not 0 < overload_fraction <= 1:
            raise ValueError(f"overload_fraction must be in (0, 1], got {overload_fraction}")
        self.deadband_ticks = int(deadband_ticks)
        self.overload_time_s = float(overload_time_s)
        self.overload_fraction = float(overload_fraction)
        #: Supply voltage (V); change it to provoke an input-voltage error.
        self.input_voltage = float(input_voltage)
        #: Internal temperature (°C); raise it above Temperature Limit to provoke overheating.
        self.temperature_c = float(temperature_c)
        # Item values live in a dict (the physics touches ~40 of them per step);
        # the byte image the bus reads is brought up to date lazily.
        self._memory = bytearray(self.table.size)
        self._fmt = {r.name: (r.address, r.size, r.signed) for r in self.table}
        self._packers = {r.name: (r.codec.pack_into, r.address) for r in self.table}
        self._bounds = {
            r.name: (-(1 << (8 * r.size - 1)), (1 << (8 * r.size - 1)) - 1)
            if r.signed
            else (0, (1 << (8 * r.size)) - 1)
            for r in self.table
        }
        self._values: dict[str, int] = {}
        self._dirty: set[str] = set()
        self._forced: dict[str, int] = {}
        self._registered: tuple[int, bytes] | None = None
        self._time = 0.0
        self._turn_offset = 0.0
        self._factory_reset_memory()
        self.set("ID", id)
        for name, value in (registers or {}).items():
            self.set(name, value)
        self._reset_controller(goal_to_present=True)

    # -- register access ------------------------------------------------------
    def get(self, name: str) -> int:
        """Current value of an item (no access rules)."""
        if self._pending is not None and name in REPORTED:  # only reports wait to be written
            self._flush_reports()
        try:
            return self._values[name]
        except KeyError:
            self._missing(name)

    def set(self, name: str, value: int) -> None:
        """Store an item's value directly (no access or range rules; for set-up and physics)."""
        if self._pending is not None:
            self._flush_reports()
        try:
            low, high = self._bounds[name]
        except KeyError:
            self._missing(name)
        value = int(value)
        if not low <= value <= high:
            raise ValueError(f"{name} = {value} does not fit {self._fmt[name][1]} byte(s)")
        self._values[name] = value
        self._dirty.add(name)
        if name not in NOT_LOOP_INPUTS:
            self._writes += 1

    def _report(self, name: str, value: int) -> None:
        """:meth:`set` for what the physics reports: most steps leave most items as they were."""
        if self._values[name] != value:
            self.set(name, value)

    @property
    def memory(self) -> bytes:
        """The control table as bytes, as a READ sees it."""
        self._flush_reports()
        self._sync_memory()
        return bytes(self._memory)

    def _sync_memory(self) -> None:
        dirty, values, packers, memory = self._dirty, self._values, self._packers, self._memory
        while dirty:  # pop, not iterate: another thread may force() meanwhile
            name = dirty.pop()
            pack_into, address = packers[name]
            pack_into(memory, address, values[name])  # set() keeps the value within the item

    def _missing(self, name: str) -> NoReturn:
        raise KeyError(f"{self.spec.name} has no control-table item {name!r}")

    def has(self, name: str) -> bool:
        return name in self._fmt

    def force(self, name: str, value: int) -> None:
        """Pin a reported item (e.g. a stuck sensor): physics no longer updates it."""
        self._flush_reports()
        self.set(name, value)
        self._forced[name] = int(value)

    def release(self, name: str) -> None:
        """Undo :meth:`force`."""
        self._flush_reports()
        self._forced.pop(name, None)

    # -- identity and bus settings -------------------------------------------
    @property
    def id(self) -> int:
        return self.get("ID")

    @property
    def model_number(self) -> int:
        return self.get("Model Number")

    @property
    def firmware_version(self) -> int:
        return self.get("Firmware Version")

    @property
    def baud_rate(self) -> int:
        """Configured bus speed in bit/s."""
        return BAUD_RATES.get(self.get("Baud Rate"), 57_600)

    @property
    def return_delay_s(self) -> float:
        return self.table["Return Delay Time"].to_si(self.get("Return Delay Time"))

    @property
    def status_return_level(self) -> int:
        return self.get("Status Return Level")

    @property
    def torque_enabled(self) -> bool:
        return self.get("Torque Enable") == 1

    @property
    def hardware_error_status(self) -> int:
        return self.get("Hardware Error Status")

    @property
    def has_registered_instruction(self) -> bool:
        return self._registered is not None

    def status_error(self, error: int = 0) -> int:
        """ERR byte for a status packet: ``error`` plus the alert bit if a fault is latched."""
        return error | (ALERT_BIT if self.hardware_error_status else 0)

    # -- instructions -----------------------------------------------------------
    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error, data) for a READ of ``length`` bytes at ``address``."""
        if not self.table.readable(address, length):
            return StatusError.ACCESS, b""
        self._flush_reports()
        self._sync_memory()
        return 0, bytes(self._memory[address : address + length])

    def check_write(self, address: int, data: bytes) -> int:
        """Error code a WRITE of ``data`` at ``address`` would get (0: accepted)."""
        self._flush_reports()
        return self._validate(address, bytes(data))[0]

    def write(self, address: int, data: bytes) -> int:
        """Apply a WRITE; returns the status error code (0: done, nothing changed otherwise)."""
        self._flush_reports()
        if address == self._goal_address and len(data) == 4:
            return self._write_goal_position(_INT32.unpack(data)[0])
        error, items = self._validate(address, bytes(data))
        if error:
            return error
        before_torque = self.torque_enabled
        before_mode = self.get("Operating Mode")
        for register, value in items:
            self.set(register.name, value)
        written = {register.name for register, _ in items}
        if "Operating Mode" in written and self.get("Operating Mode") != before_mode:
            self._reset_controller(goal_to_present=True)
            if self.get("Operating Mode") == OperatingMode.POSITION:
                self._wrap_turns()
        if "Torque Enable" in written and self.torque_enabled != before_torque:
            self._reset_controller(goal_to_present=self.torque_enabled)
        if "Goal Position" in written:
            self._plan_profile()
        if "Homing Offset" in written:  # reported at once, not at the next physics step
            raw = getattr(self, "_raw_ticks", float(self._position_reg.zero))
            self.set("Present Position", math.floor(raw + 0.5) + self.get("Homing Offset"))
            self._apply_forced()
        return 0

    def _write_goal_position(self, value: int) -> int:
        """WRITE of Goal Position alone, every cycle's instruction: the checks of
        :meth:`_validate` and the effects of :meth:`write` for that one item."""
        register = self._goal_register
        if (register.minimum is not None and value < register.minimum) or (
                register.maximum is not None and value > register.maximum):
            return StatusError.DATA_RANGE
        values = self._values
        if values["Operating Mode"] == OperatingMode.POSITION and not (
                values["Min Position Limit"] <= value <= values["Max Position Limit"]):
            return StatusError.DATA_LIMIT
        self.set("Goal Position", value)
        self._plan_profile()
        return 0

    def register_write(self, address: int, data: bytes) -> int:
        """REG_WRITE: validate now, apply on :meth:`action`."""
        self._flush_reports()
        error = self.check_write(address, data)
        if error:
            return error
        self._registered = (address, bytes(data))
        self.set("Registered Instruction", 1)
        return 0

    def action(self) -> int:
        """ACTION: apply the registered write; Instruction Error if there is none."""
        self._flush_reports()
        if self._registered is None:
            return StatusError.INSTRUCTION
        address, data = self._registered
        self._registered = None
        self.set("Registered Instruction", 0)
        return self.write(address, data)

    def reboot(self) -> None:
        """REBOOT: RAM back to defaults, latched faults cleared, EEPROM kept."""
        self._flush_reports()
        for register in self.table:
            if register.area is Area.RAM:
                self.set(register.name, register.default)
        self._registered = None
        self._forced.clear()
        self._wrap_turns()
        self._reset_controller(goal_to_present=True)

    def factory_reset(self, option: int) -> int:
        """FACTORY_RESET: 0xFF everything, 0x01 all but ID, 0x02 all but ID and baud rate."""
        self._flush_reports()
        if option not in (0xFF, 0x01, 0x02):
            return StatusError.DATA_RANGE
        keep = {"ID": self.get("ID"), "Baud Rate": self.get("Baud Rate")}
        self._factory_reset_memory()
        if option in (0x01, 0x02):
            self.set("ID", keep["ID"])
        if option == 0x02:
            self.set("Baud Rate", keep["Baud Rate"])
        self._registered = None
        self._forced.clear()
        self._wrap_turns()
        self._reset_controller(goal_to_present=True)
        return 0

    def clear(self, params: bytes) -> int:
        """CLEAR 0x01: Present Position back into one turn; Result Fail while moving."""
        self._flush_reports()
        if bytes(params) != _CLEAR_MAGIC:
            return StatusError.DATA_RANGE
        if self.get("Moving"):
            return StatusError.RESULT_FAIL
        self._wrap_turns()
        self._reset_controller(goal_to_present=True)
        return 0

    def raise_hardware_error(self, fault: str | int) -> None:
        """Latch a hardware fault by name (``'overload'``...) or bit; shut down if selected."""
        self._flush_reports()
        bit = _HW_BIT[fault] if isinstance(fault, str) else int(fault)
        if not 0 <= bit <= 7:
            raise ValueError(f"hardware error bit must be 0..7, got {fault!r}")
        mask = 1 << bit
        self.set("Hardware Error Status", self.hardware_error_status | mask)
        if self.get("Shutdown") & mask and self.torque_enabled:
            self.set("Torque Enable", 0)
            self._reset_controller(goal_to_present=False)

    # -- internals ------------------------------------------------------------------
    def _factory_reset_memory(self) -> None:
        self._memory[:] = bytes(len(self._memory))
        self._values.clear()
        self._dirty.clear()
        for register in self.table:
            self.set(register.name, register.default)

    def _validate(self, address: int, data: bytes) -> tuple[int, list[tuple[Register, int]]]:
        if not data or address < 0 or address + len(data) > self.table.size:
            return StatusError.ACCESS, []
        slots = self.table.write_slots(address, len(data))
        if slots is None:
            return StatusError.DATA_LENGTH, []
        if not slots:
            return StatusError.ACCESS, []
        items = [(register, unpack_from(data, start)[0]) for register, start, unpack_from in slots]
        new = {register.name: value for register, value in items}
        for register, value in items:
            if register.access is Access.R:
                return StatusError.ACCESS, []
            if register.area is Area.EEPROM and self.torque_enabled:
                return StatusError.ACCESS, []
            if register.minimum is not None and value < register.minimum:
                return StatusError.DATA_RANGE, []
            if register.maximum is not None and value > register.maximum:
                return StatusError.DATA_RANGE, []
            if register.name in _CROSS_CHECKED:
                error = self._check_limits(register.name, value, new)
                if error:
                    return error, []
        return 0, items

    def _check_limits(self, name: str, value: int, new: Mapping[str, int]) -> int:
        def now(item: str) -> int:
            return new[item] if item in new else self.get(item)

        if name == "Operating Mode" and value not in self.spec.operating_modes:
            return StatusError.DATA_RANGE
        if name == "Goal Position" and now("Operating Mode") == OperatingMode.POSITION:
            if not now("Min Position Limit") <= value <= now("Max Position Limit"):
                return StatusError.DATA_LIMIT
        if name == "Goal Current" and abs(value) > now("Current Limit"):
            return StatusError.DATA_LIMIT
        if name == "Goal Velocity" and abs(value) > now("Velocity Limit"):
            return StatusError.DATA_LIMIT
        if name == "Goal PWM" and abs(value) > now("PWM Limit"):
            return StatusError.DATA_LIMIT
        if name == "Torque Enable" and value == 1:
            if self.hardware_error_status & self.get("Shutdown"):
                return StatusError.RESULT_FAIL
        return 0

    def __repr__(self) -> str:
        return (
            f"ServoModel({self.spec.name}, id={self.id}, torque={'on' if self.torque_enabled else 'off'}, "
            f"hw_error={self.hardware_error_status:#04x})"
        )
