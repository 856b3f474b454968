"""Checks of a rig before a trial, each one line that passes, warns or fails.

Everything a trial would trip over, found before anything moves: ports that
are missing or not ours, the USB latency timer, each configured servo (there,
the configured model, at the configured rate, no latched fault, supply
voltage and temperature inside its own limits, Return Delay Time and mode as
configured), the ultrasonic sensor (streaming fast enough for the driver,
readings inside what the train's travel allows, agreeing with the train's
servo) and the calibration in use. Nothing is written to the servos.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Literal, Optional

import numpy as np

from bench.config.calibration import calibration_of, calibration_path
from bench.config.models import ConfigError, TrialConfig
from bench.kinematics.arc_train import train_pose
from bench.kinematics.registry import get_robot
from drivers.errors import ActuatorError, BackendSetupError
from drivers.dynamixel.backend import latency_timer_ms
from drivers.dynamixel.bus import PingReply, ServoBus, ServoStatus, open_error
from drivers.dynamixel.control_table import x_series_table
from drivers.dynamixel.units import BAUD_RATES
from drivers.link import is_virtual_port, port_usable
from drivers.ultrasonic import UltrasonicSensor

__all__ = ["Check", "run_doctor"]

Status = Literal["pass", "warn", "fail"]
Add = Callable[[str, Status, str], None]  # records one check: name, status, detail

VOLTAGE_MARGIN_V = 0.5  # warn this close to a voltage limit
TEMPERATURE_MARGIN_C = 10.0  # warn this close to the temperature limit
RANGE_MARGIN_M = 0.015  # ultrasonic readings may stray this far past the travel (noise)
AGREEMENT_M = 0.010  # ultrasonic vs train servo: warn beyond this
NO_REPLY = "no reply"  # ServoBus.last_problem when nothing at all came back


@dataclass(frozen=True)
class Check:
    name: str
    status: Status
    detail: str

    def as_dict(self) -> dict:
        return asdict(self)


def run_doctor(config: TrialConfig, listen_s: float = 1.0,
               on_check: Optional[Callable[[Check], None]] = None) -> list[Check]:
    """All checks of a Dynamixel config's rig, in order; ``on_check`` sees each as it is made."""
    checks: list[Check] = []

    def add(name: str, status: Status, detail: str) -> None:
        c = Check(name, status, detail)
        checks.append(c)
        if on_check is not None:
            on_check(c)

    b = config.backend
    servo_ok = _port_check(add, "servo port", b.port)
    _latency_check(add, b.port, servo_ok)
    ultra_ok = _port_check(add, "ultrasonic port", b.ultrasonic.port) if b.ultrasonic else False
    train_q = _servo_checks(add, config) if servo_ok else None
    if b.ultrasonic is not None and ultra_ok:
        _ultrasonic_checks(add, config, listen_s, train_q)
    _calibration_check(add, config)
    return checks


# -- ports ---------------------------------------------------------------------------------


def _port_check(add: Add, name: str, port: str) -> bool:
    if port_usable(port):
        add(name, "pass", f"{port} is an emulated line on the virtual clock" if is_virtual_port(port)
            else f"{port} is readable and writable")
        return True
    add(name, "fail", open_error(port))
    return False


def _latency_check(add: Add, port: str, exists: bool) -> None:

    real = os.path.realpath(port)
    if not exists:
        return  # the port check already failed; there is no timer to read
    if is_virtual_port(port):
        add("latency timer", "pass", f"skipped: {port} is an emulated line, no USB latency timer")
        return
    if real.startswith("/dev/pts/"):
        add("latency timer", "pass", f"skipped: {port} is a pseudo-terminal (emulated bus), "
                                     f"no USB latency timer")
        return
    ms = latency_timer_ms(port)
    name = Path(real).name
    fix = f"`echo 1 | sudo tee /sys/bus/usb-serial/devices/{name}/latency_timer`"
    if ms is None:
        add("latency timer", "pass", f"skipped: {port} is not a USB-serial adapter with a latency timer")
    elif ms > 1:
        add("latency timer", "warn", f"{ms} ms on {port}{' (the FTDI default)' if ms == 16 else ''}: "
                                     f"it caps the control loop near {1000 // (2 * ms)} Hz; "
                                     f"set 1 ms with {fix}")
    else:
        add("latency timer", "pass", f"{ms} ms on {port}")


# -- servos --------------------------------------------------------------------------------


def _servo_checks(add: Add, config: TrialConfig) -> Optional[float]:
    """Per-servo checks; the train's joint value from its encoder (None if not read)."""

    b = config.backend
    order = [j for j in get_robot(config.robot).joint_names if j in b.servos]
    train = b.ultrasonic.joint if b.ultrasonic else None
    train_q = None
    try:
        bus = ServoBus(b.port, b.baud)
    except ActuatorError as e:
        add("servo bus", "fail", str(e))
        return None
    replies: dict[str, PingReply] = {}
    where: dict[str, int] = {}
    heard: dict[str, str] = {}  # joint -> what came back at the configured rate, when no answer did
    unreadable: dict[str, str] = {}  # joint -> why its registers could not be read after a ping
    statuses: dict[str, ServoStatus] = {}
    try:
        with bus:
            for joint in order:
                r, heard[joint] = _ping(bus, b.servos[joint].id)
                if r is not None:
                    replies[joint], where[joint] = r, b.baud
            missing = [j for j in order if j not in replies]
            for baud in (x for x in sorted(BAUD_RATES.values()) if x != b.baud and missing):
                bus.set_baud(baud)
                for joint in list(missing):
                    r, _ = _ping(bus, b.servos[joint].id, tries=1)
                    if r is not None:
                        replies[joint], where[joint] = r, baud
                        missing.remove(joint)
            for baud in sorted(set(where.values())):
                bus.set_baud(baud)
                for joint in (j for j in order if where.get(j) == baud):
                    try:
                        statuses[joint] = bus.status(replies[joint])
                        if joint == train and baud == b.baud:
                            train_q = _joint_value(config, joint, bus.shaft_angle(b.servos[joint].id))
                    except ActuatorError as e:  # answered the ping, then replied malformed or late
                        statuses.pop(joint, None)
                        unreadable[joint] = _unreadable(str(e), bus.last_problem)
    except ActuatorError as e:  # the port itself failed (unplugged, a rate it refuses)
        add("servo bus", "fail", str(e))
        return None
    for joint in order:
        sc = b.servos[joint]
        name = f"{joint} (ID {sc.id})"
        s = statuses.get(joint)
        if joint in unreadable:
            add(name, "fail", f"{unreadable[joint]}: check its cable and the bus termination, and "
                              f"that no second device answers to ID {sc.id}")
            continue
        if s is None:
            if heard.get(joint, NO_REPLY) != NO_REPLY:
                add(name, "fail", f"malformed reply at {b.baud} bps ({heard[joint]}) and no answer "
                                  f"at any other X-series rate: check its cable and the bus "
                                  f"termination, and that no second device answers to ID {sc.id}")
            else:
                add(name, "fail", f"no answer at {b.baud} bps nor at any other X-series rate: "
                                  f"check its cable, power and ID")
            continue
        if where[joint] != b.baud:
            add(name, "fail", f"{s.model_name} answers at {where[joint]} bps, the config says "
                              f"{b.baud}: set its Baud Rate register to {b.baud} bps "
                              f"(Dynamixel Wizard) or change backend.baud")
        elif s.model_name != sc.model:
            add(name, "fail", f"is {s.model_name} (model {s.model}), the config says {sc.model}: "
                              f"wrong servo on this ID, or fix the config")
        else:
            add(name, "pass", f"{s.model_name}, firmware {s.firmware}, at {b.baud} bps")
        _health_checks(add, joint, s, config)
    return train_q


def _ping(bus: ServoBus, sid: int, tries: Optional[int] = None) -> tuple[Optional[PingReply], str]:
    """The servo's answer to a ping, else None and what came instead ("no reply", or what was
    wrong with the reply: corrupt, foreign, short, error bits)."""
    try:
        reply = bus.ping(sid, tries=tries)
    except BackendSetupError as e:  # a status with error bits: an answer, but not a servo's ping
        return None, f"a reply with error bits ({e})"
    return reply, "" if reply is not None else (bus.last_problem or NO_REPLY)


def _unreadable(error: str, problem: str) -> str:
    """Why a servo that answered its ping has no status: replies malformed, or late or lost."""
    if problem == NO_REPLY:
        return f"answers a ping, then no reply to a register read, late or lost ({error})"
    return f"malformed reply: answers a ping, then not a register read ({error})"


def _health_checks(add: Add, joint: str, s: ServoStatus, config: TrialConfig) -> None:
    if s.hardware_error:
        add(f"{joint} hardware error", "fail",
            f"{', '.join(s.hardware_error)} latched on ID {s.id}: find the cause, then reboot the "
            f"servo (power cycle, or set backend.reboot_on_hardware_error)")
    else:
        add(f"{joint} hardware error", "pass", "none")
    if s.voltage_v is None or s.voltage_min_v is None or s.voltage_max_v is None:
        add(f"{joint} voltage", "warn", f"{s.model_name} reports no input voltage")
    else:
        text = f"{s.voltage_v:.1f} V (limits {s.voltage_min_v:.1f}–{s.voltage_max_v:.1f} V)"
        if not s.voltage_min_v <= s.voltage_v <= s.voltage_max_v:
            add(f"{joint} voltage", "fail", f"{text}: outside its limits, check the supply")
        elif min(s.voltage_v - s.voltage_min_v, s.voltage_max_v - s.voltage_v) < VOLTAGE_MARGIN_V:
            add(f"{joint} voltage", "warn", f"{text}: close to a limit, check the supply under load")
        else:
            add(f"{joint} voltage", "pass", text)
    if s.temperature_c is None or s.temperature_limit_c is None:
        add(f"{joint} temperature", "warn", f"{s.model_name} reports no temperature")
    else:
        text = f"{s.temperature_c:.0f} °C (limit {s.temperature_limit_c:.0f} °C)"
        if s.temperature_c >= s.temperature_limit_c:
            add(f"{joint} temperature", "fail", f"{text}: let it cool down")
        elif s.temperature_c >= s.temperature_limit_c - TEMPERATURE_MARGIN_C:
            add(f"{joint} temperature", "warn", f"{text}: close to the limit")
        else:
            add(f"{joint} temperature", "pass", text)
    sc = config.backend.servos[joint]
    want_rdt = config.backend.return_delay_us
    problems = []
    rdt = x_series_table()["Return Delay Time"]
    if s.return_delay_s is not None and rdt.nearest(s.return_delay_s) != rdt.nearest(want_rdt * 1e-6):
        problems.append(f"Return Delay Time {s.return_delay_s * 1e6:.0f} µs (config {want_rdt} µs)")
    if s.operating_mode is not None and s.operating_mode != sc.mode:
        problems.append(f"{s.operating_mode} mode (config {sc.mode})")
    if problems:
        add(f"{joint} settings", "warn", "; ".join(problems) + ": a trial rewrites them with torque off")
    else:
        add(f"{joint} settings", "pass", f"Return Delay Time {want_rdt} µs, {sc.mode} mode")


def _joint_value(config: TrialConfig, joint: str, shaft: float) -> float:

    sc = config.backend.servos[joint]
    try:
        cal = calibration_of(config)
    except ConfigError:
        cal = None
    offset = cal.offset(joint, sc.offset) if cal else sc.offset
    return offset + sc.ratio * shaft


# -- ultrasonic ----------------------------------------------------------------------------


def _ultrasonic_checks(add: Add, config: TrialConfig, listen_s: float, train_q: Optional[float]) -> None:

    u = config.backend.ultrasonic
    assert u is not None
    try:
        sensor = UltrasonicSensor(u.port, **u.sensor_options())
    except ActuatorError as e:
        add("ultrasonic stream", "fail", str(e))
        return
    stamps: list[float] = []
    values: list[float] = []
    with sensor:
        clock = sensor.clock  # the wall clock; an emulated line's virtual one
        t0 = clock.now()
        seen = 0
        while clock.now() - t0 < listen_s:
            n = sensor.counters.readings
            if n > seen:
                seen = n
                stamps.append(clock.now())
                values.append(sensor.read(allow_stale=True)[0])
            clock.sleep(0.002)
        counters = sensor.counters
        stale_s = sensor.stale_after_s
    bad = (f"{counters.parse_errors} unreadable line(s), {counters.no_target} no-target "
           f"reading(s) (R{u.max_range_mm})")
    if len(stamps) < 2:
        add("ultrasonic stream", "fail", f"no readings on {u.port} in {listen_s:.1f} s at {u.baud} bps; "
                                         f"{bad} (check the sensor's power, cable, aim and "
                                         f"backend.ultrasonic.baud)")
        return
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    gap = max(max(np.diff(stamps)), stamps[0] - t0)
    text = (f"{rate:.1f} readings/s (nominal {u.rate_hz:g}), longest gap {gap * 1e3:.0f} ms, "
            f"{counters.dropouts} dropout(s), {bad}")
    if rate < 1.0 / stale_s:
        add("ultrasonic stream", "fail", f"{text}: slower than one reading per {stale_s * 1e3:.0f} ms "
                                         f"(stale after), trials would see stale readings")
    elif gap > stale_s or counters.parse_errors or counters.no_target:
        add("ultrasonic stream", "warn", f"{text}: dropouts longer than {stale_s * 1e3:.0f} ms stop "
                                         f"a trial; no-target readings mean the echo is lost")
    elif abs(rate - u.rate_hz) > 0.2 * u.rate_hz:
        add("ultrasonic stream", "warn", f"{text}: the measured rate is not the configured "
                                         f"backend.ultrasonic.rate_hz; set it to the sensor's")
    else:
        add("ultrasonic stream", "pass", text)

    robot = get_robot(config.robot)
    row = robot.chain.rows[robot.joint_names.index(u.joint)]
    d2_lo, d2_hi = (float(train_pose(x, robot.params).d2) for x in (row.lower, row.upper))
    try:
        cal = calibration_of(config)
    except ConfigError:
        cal = None
    uc = cal.ultrasonic if cal else None
    offset, scale = (uc.offset_mm * 1e-3, uc.scale) if uc else (u.standoff_mm * 1e-3, 1.0)
    lo, hi = offset + scale * d2_lo, offset + scale * d2_hi
    reading = float(np.median(values))
    span = f"{lo * 1e3:.0f}–{hi * 1e3:.0f} mm"
    why = (f"d2 {d2_lo * 1e3:.0f}–{d2_hi * 1e3:.0f} mm, {'calibrated' if uc else 'standoff'} "
           f"{offset * 1e3:.0f} mm")
    if not lo - RANGE_MARGIN_M <= reading <= hi + RANGE_MARGIN_M:
        add("ultrasonic range", "fail", f"reads {reading * 1e3:.0f} mm, outside the {span} the train's "
                                        f"travel allows ({why}): is the sensor aimed at the train?")
    else:
        add("ultrasonic range", "pass", f"reads {reading * 1e3:.0f} mm, within {span} ({why})")

    if train_q is None or not math.isfinite(train_q):
        return
    expected = offset + scale * float(train_pose(train_q, robot.params).d2)
    diff = reading - expected
    text = (f"reads {reading * 1e3:.1f} mm, the train's servo ({math.degrees(train_q):.1f}°) "
            f"gives {expected * 1e3:.1f} mm")
    if abs(diff) > AGREEMENT_M:
        add("ultrasonic vs train servo", "warn", f"{text} ({diff * 1e3:+.1f} mm): calibrate with "
                                                 f"`hilbench calibrate {config.source or 'CONFIG'}`")
    else:
        add("ultrasonic vs train servo", "pass", f"{text} ({diff * 1e3:+.1f} mm)")


# -- calibration ---------------------------------------------------------------------------


def _calibration_check(add: Add, config: TrialConfig) -> None:

    if config.calibration is None:
        add("calibration", "pass", "none: joint offsets and ultrasonic standoff as configured")
        return
    try:
        cal = calibration_of(config)
    except ConfigError as e:
        add("calibration", "fail", str(e))
        return
    assert cal is not None
    parts = []
    if cal.servos:
        parts.append(f"{len(cal.servos)} joint offsets")
    if cal.homing_offsets:
        parts.append(f"{len(cal.homing_offsets)} homing offsets (in the servos)")
    if cal.ultrasonic:
        parts.append(f"ultrasonic (residual {cal.ultrasonic.residual_mm:.2f} mm)")
    add("calibration", "pass", f"{calibration_path(config)} of {cal.created}: "
                               f"{', '.join(parts) or 'empty'}")
