"""Real Dynamixel X-series servos (Protocol 2.0) behind the :class:`~drivers.Actuators` interface.

Start-up never enables torque until every check has passed: each configured ID
answers a ping with the configured model, no servo reports a hardware error
(unless told to reboot it), and the EEPROM settings (Return Delay Time,
Operating Mode, Current Limit) are written with torque off. Each control cycle
is one GroupSyncWrite of goal positions and one GroupSyncRead (Fast Sync Read
where the model supports it) of present current, velocity and position.
Framing is done by :class:`~drivers.dynamixel.io.StuffingPacketHandler`, which stuffs
and de-stuffs correctly both ways, over a port handler that sleeps in the
kernel while it waits.

Units: joint values in rad or m. A servo's shaft angle maps to its joint by
``joint = offset + ratio · shaft`` (ratio in joint units per shaft radian: 1
for a direct revolute joint, the pinion radius in m/rad for a rack, the
pinion/arc radius ratio for the train). Ticks and raw currents stay here.

The train joint can be a composite: its servo is commanded, but its measured
position comes from the ultrasonic sensor (d2 mapped back to the arc angle by
a function the caller supplies), and the host closes a slow outer loop on it.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from drivers import (
    ActuatorsBase,
    CommunicationError,
    BackendSetupError,
    HardwareFault,
    JointLimits,
    JointState,
)
from drivers.clock import WALL, Clock
from drivers.dynamixel.control_table import model_spec, x_series_table
from drivers.dynamixel.cycle import SyncCycle
from drivers.dynamixel.goals import GoalBounds, GoalOutOfRange, outside_limits
from drivers.dynamixel.io import BlockingPortHandler, RegisterAccess, StuffingPacketHandler, port_hint
from drivers.dynamixel.protocol import decode_hardware_error
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.settle import settle_all
from drivers.dynamixel.units import OPERATING_MODES
from drivers.train_loop import TrainLoop
from drivers.ultrasonic import UltrasonicSensor

log = logging.getLogger(__name__)

FAST_SYNC_READ_FIRMWARE = 45  # X-series firmware that answers Fast Sync Read


def _register(name: str) -> tuple[int, int]:
    """(address, size) of an X-series register, from the one control table."""
    reg = x_series_table()[name]
    return reg.address, reg.size


def latency_timer_ms(port: str) -> Optional[int]:
    """The USB-serial latency timer of an FTDI adapter (None when not an FTDI device)."""
    name = Path(os.path.realpath(port)).name
    path = Path(f"/sys/bus/usb-serial/devices/{name}/latency_timer")
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


class DynamixelActuators(ActuatorsBase):
    """Servos on one bus (and optionally the ultrasonic train sensor)."""

    #: What the backend keeps time by: its port's clock (the wall clock at a rig, an emulated
    #: line's virtual clock in a rehearsal), set when the port opens.
    clock: Clock = WALL

    def __init__(self, settings: DynamixelSettings) -> None:
        import dynamixel_sdk as sdk  # heavy: loaded only with servos

        self.settings = s = settings
        self._sdk = sdk
        self._validate(s)
        names = list(s.joint_names)
        self._servo_of = {sv.joint: sv for sv in s.servos}
        self._index = [names.index(sv.joint) for sv in s.servos]
        self._ids = [sv.id for sv in s.servos]
        self._ratio = np.array([sv.ratio for sv in s.servos])
        self._offset = np.array([sv.offset for sv in s.servos])
        self._zero = np.array([sv.zero_tick for sv in s.servos], dtype=float)
        # Unit conversions per servo, precomputed for the control cycle.
        self._q_per_tick = self._ratio * x_series_table()["Present Position"].scale
        self._qd_per_unit = self._ratio * x_series_table()["Present Velocity"].scale
        self._effort_per_unit = np.array(
            [_kt(sv.model) * _current_unit(sv.model) for sv in s.servos]) / self._ratio
        # The same, as one (3, n) scale on raw position, velocity, current and the
        # position at tick 0: one multiply-add per cycle.
        self._si_per_raw = np.array([self._q_per_tick, self._qd_per_unit, self._effort_per_unit])
        self._q_at_tick0 = self._offset - self._q_per_tick * self._zero
        self._ticks_per_q = 1.0 / self._q_per_tick
        self._in_joint_order = self._index == list(range(len(names)))
        self._servo_of_joint = np.argsort(self._index)
        self._limits = JointLimits(np.asarray(s.lower, float), np.asarray(s.upper, float),
                                   np.asarray(s.velocity, float), np.asarray(s.effort, float))
        self._t0 = 0.0  # the clock's time at start, once the port is open
        self._last: Optional[JointState] = None
        self._lost = False  # the bench lost the train's last reading (HostLoop)
        self._fails = 0
        self.firmware: dict[int, int] = {}
        self.emulated: dict[int, bool] = {}  # what each servo said it is (drivers.dynamixel.identity)
        self.safe_stop_report: Optional[str] = None
        self.models: dict[int, int] = {}
        self.port = BlockingPortHandler(s.port)
        self.ph = StuffingPacketHandler()
        self._regs = RegisterAccess(self.port, self.ph, s.retries)
        self._sensor = None
        self._train = names.index(s.ultrasonic.joint) if s.ultrasonic else None
        self._train_loop = TrainLoop(self._train if self._train is not None else 0,
                                     s.ultrasonic.loop_gain if s.ultrasonic else 0.0,
                                     s.ultrasonic.max_correction if s.ultrasonic else 0.0)
        try:
            try:
                opened = self.port.openPort()
            except Exception as e:  # pyserial's SerialException: no such device, permissions
                raise BackendSetupError(
                    f"cannot open servo port {s.port}: {e}" + port_hint(s.port)) from None
            if not opened:
                raise BackendSetupError(f"cannot open servo port {s.port}" + port_hint(s.port))
            if not self.port.setBaudRate(s.baud):
                raise BackendSetupError(f"cannot set {s.baud} bps on {s.port}")
            self.clock = self.port.clock  # the wall clock; an emulated line's virtual one
            self._t0 = self.clock.now()
            self._check_latency()
            self._check_servos()
            self._configure()
            self._bounds = self._goal_bounds()
            self._setup_groups()
            if s.ultrasonic:
                u = s.ultrasonic
                self._sensor = UltrasonicSensor(u.port, baud=u.baud, median_window=u.median_window,
                                                stale_after_s=u.stale_after_s,
                                                expected_rate_hz=u.rate_hz, range_m=u.range_m,
                                                no_target_m=u.no_target_m)
                self._sensor.wait_for_reading()
            self._last = self._read_bus()
        except BaseException:
            self._shutdown_port()
            raise

    # -- start-up checks ------------------------------------------------------
    @staticmethod
    def _validate(s: DynamixelSettings) -> None:
        names = list(s.joint_names)
        joints = [sv.joint for sv in s.servos]
        if sorted(joints) != sorted(names):
            missing = sorted(set(names) - set(joints))
            extra = sorted(set(joints) - set(names))
            raise BackendSetupError(
                f"servos must cover every joint once: missing {missing}, unknown {extra}")
        ids = [sv.id for sv in s.servos]
        if len(set(ids)) != len(ids):
            raise BackendSetupError(f"duplicate servo IDs in {ids}")
        for sv in s.servos:
            if sv.mode not in OPERATING_MODES:
                raise BackendSetupError(
                    f"servo {sv.id} ({sv.joint}): unknown mode {sv.mode!r}; modes: {sorted(OPERATING_MODES)}")
            if sv.ratio == 0 or not math.isfinite(sv.ratio):
                raise BackendSetupError(f"servo {sv.id} ({sv.joint}): ratio must be non-zero")

    def _check_latency(self) -> None:
        ms = latency_timer_ms(self.settings.port)
        if ms is not None and ms >= 16:
            self._warn(f"USB latency timer of {self.settings.port} is {ms} ms (the FTDI default): "
                       f"it caps the loop near {1000 // (2 * ms)} Hz; set it to 1 ms with "
                       f"`echo 1 | sudo tee /sys/bus/usb-serial/devices/"
                       f"{Path(os.path.realpath(self.settings.port)).name}/latency_timer`")

    def _warn(self, msg: str) -> None:
        self.settings.warnings.append(msg)
        log.warning(msg)

    def _check_servos(self) -> None:
        s = self.settings
        missing = []
        pinged = self._regs.ping_all([sv.id for sv in s.servos], tries=max(s.retries, 3) + 1)
        for sv in s.servos:
            model, problem = pinged[sv.id]
            if model is None:
                missing.append(f"{sv.id} ({sv.joint})" + (f" [{problem}]" if problem != "no reply" else ""))
                continue
            if model != sv.model:
                raise BackendSetupError(
                    f"servo ID {sv.id} ({sv.joint}) is model {model} ({_model_name(model)}), the "
                    f"config says {sv.model} ({_model_name(sv.model)}); torque not enabled")
            self.models[sv.id] = model
            self.firmware[sv.id] = self._read(sv.id, "Firmware Version")
            self.emulated[sv.id] = self._regs.says_emulated(sv.id)
        if missing:
            raise BackendSetupError(
                f"servo ID(s) {', '.join(missing)} did not answer a ping on {s.port} at {s.baud} "
                f"bps; torque not enabled")
        faulty = {}
        for sv in s.servos:
            hw = self._read(sv.id, "Hardware Error Status")
            if hw:
                faulty[sv.id] = decode_hardware_error(hw)
        if faulty and s.reboot_on_hardware_error:
            for sid in faulty:
                self.ph.reboot(self.port, sid)
            self.clock.sleep(0.6)
            still = {sid: decode_hardware_error(self._read(sid, "Hardware Error Status"))
                     for sid in faulty}
            faulty = {k: v for k, v in still.items() if v}
        if faulty:
            text = "; ".join(f"ID {k}: {', '.join(v)}" for k, v in faulty.items())
            raise HardwareFault(f"hardware error on servo(s) {text}; refusing to start "
                                f"(reboot them, or set reboot_on_hardware_error)", faulty)

    def _configure(self) -> None:
        """Write the settings; torque goes off only on a servo whose EEPROM must change.

        A servo found holding its pose with the right EEPROM keeps holding it,
        so an arm that gravity would drop is not dropped just to be configured.
        """
        s = self.settings
        rdt = x_series_table()["Return Delay Time"].nearest(s.return_delay_us * 1e-6)
        for sv in s.servos:
            eeprom = {"Return Delay Time": rdt, "Operating Mode": OPERATING_MODES[sv.mode]}
            if sv.current_limit_a is not None:
                limit = model_spec(sv.model).table["Current Limit"]
                eeprom["Current Limit"] = limit.nearest(sv.current_limit_a)
            changes = {k: v for k, v in eeprom.items() if self._read(sv.id, k) != v}
            if changes:
                if self._read(sv.id, "Torque Enable"):
                    self._warn(f"servo ID {sv.id} ({sv.joint}): torque off to write "
                               f"{', '.join(changes)} (EEPROM)")
                self._write(sv.id, "Torque Enable", 0)  # written whatever was read: EEPROM needs it off
                for k, v in changes.items():
                    self._write(sv.id, k, v)
            for gain, value in zip(("Position P Gain", "Position I Gain", "Position D Gain"), sv.gains):
                if value is not None:
                    self._write(sv.id, gain, value)
            # Profile off: the host streams the trajectory.
            self._write(sv.id, "Profile Velocity", 0)
            self._write(sv.id, "Profile Acceleration", 0)
        if rdt >= 250:
            self._warn("Return Delay Time is 250 (500 µs per status packet): it caps the loop rate")

    def _goal_bounds(self) -> GoalBounds:
        """Each servo's goal band (Position mode: within its Min/Max Position Limit as read)."""
        s = self.settings
        slack = [s.ultrasonic.max_correction if s.ultrasonic and sv.joint == s.ultrasonic.joint else 0.0
                 for sv in s.servos]  # the host loop steers the train past its clipped goal
        return GoalBounds.of(s.servos, self._limits.lower[self._index], self._limits.upper[self._index],
                             lambda sid: (self._read(sid, "Min Position Limit"),
                                          self._read(sid, "Max Position Limit")), slack)

    def _setup_groups(self) -> None:
        fw_ok = all(self.firmware.get(sid, 0) >= FAST_SYNC_READ_FIRMWARE for sid in self._ids)
        self._fast = self.settings.fast_sync_read and fw_ok
        if self.settings.fast_sync_read and not fw_ok:
            self._warn(f"Fast Sync Read needs firmware {FAST_SYNC_READ_FIRMWARE}+; using Sync Read")
        self._cycle = SyncCycle(self.port.link, self.settings.baud, self._ids, fast=self._fast)
        if self.settings.timeout_s:
            self._cycle.timeout_s = self.settings.timeout_s

    # -- register access with retries ----------------------------------------
    def _read(self, sid: int, name: str) -> int:
        addr, size = _register(name)
        return self._regs.read(sid, addr, size, name, signed=name == "Homing Offset")

    def _write(self, sid: int, name: str, value: int) -> None:
        addr, size = _register(name)
        self._regs.write(sid, addr, size, value, name)

    # -- the Actuators interface ----------------------------------------------
    @property
    def joint_names(self) -> Sequence[str]:
        return list(self.settings.joint_names)

    @property
    def limits(self) -> JointLimits:
        return self._limits

    def now(self) -> float:
        return self.clock.now() - self._t0

    def wait_until(self, t: float) -> None:
        self.clock.sleep_until(self._t0 + t)

    def read(self) -> JointState:
        st = self._read_bus()
        self._last = st
        self._lost = False
        return st

    @property
    def encoder_joint(self) -> Optional[str]:
        """The joint whose position comes from the ultrasonic sensor (SensedEncoder); None without one."""
        u = self.settings.ultrasonic
        return u.joint if u is not None and self._sensor is not None else None

    def encoder_position(self) -> float:
        """That joint's pinion encoder through its ratio and offset (m or rad), as of the last read,
        before the sensor's reading took its place (SensedEncoder); NaN before any read."""
        return float(getattr(self, "_encoder_train", math.nan))

    def bus_time(self) -> float:
        """Seconds this backend's servo-bus transactions took since the last call (BusTiming)."""
        took, self._cycle.bus_s = self._cycle.bus_s, 0.0
        return took

    def status_lost(self, joints: Sequence[str]) -> None:
        """The bench lost the train's last reading: the host loop holds until the next, as for a stale one."""
        u = self.settings.ultrasonic
        if u is not None and u.joint in joints:
            self._lost = True

    @property
    def start_warnings(self) -> list[str]:
        """What start-up warned about (latency timer, Return Delay Time, Sync Read), for the record."""
        return list(self.settings.warnings)

    def _read_bus(self) -> JointState:
        cyc = self._cycle
        for _ in range(self.settings.retries + 1):
            raw = cyc.read_state()  # position, velocity, current rows in servo order
            if raw is not None:
                break
        else:
            raise CommunicationError(
                f"servos {self._ids} did not answer the {'fast ' if self._fast else ''}sync read "
                f"after {self.settings.retries + 1} tries ({cyc.last_error}); bus lost?")
        raw *= self._si_per_raw
        raw[0] += self._q_at_tick0
        q, qd, eff = raw
        if not self._in_joint_order:
            q, qd, eff = q[self._servo_of_joint], qd[self._servo_of_joint], eff[self._servo_of_joint]
        flags: tuple[str, ...] = ()
        if self._sensor is not None:
            u = self.settings.ultrasonic
            try:
                distance, age = self._sensor.read(allow_stale=True)
            except CommunicationError:
                distance, age = float("nan"), float("inf")
            self._encoder_train = q[self._train]
            if age > self._sensor.stale_after_s or not math.isfinite(distance):
                flags = (f"stale:{u.joint}",)
            else:
                q[self._train] = u.to_joint(distance)
        return JointState(self.now(), q, qd, eff, flags)

    def _enable(self) -> None:
        st = self._read_bus()  # a sensed joint by its pinion: the shaft torque-on holds, not sensor noise
        shafts = st.position if self._sensor is None else self._encoder_positions(st)
        outside = outside_limits(self.joint_names, shafts, self._limits.lower, self._limits.upper,
                                 self.settings.limit_tolerance)
        if outside:
            raise BackendSetupError(f"{outside}; torque not enabled (check its offset and calibration, "
                                     f"or move it by hand with torque off)")
        goals = self._goal_ticks(shafts, hold=True)
        holding = [k for k, sid in enumerate(self._ids) if self._read(sid, "Torque Enable")]
        for k in holding:  # already holding: keep the goal it holds its load against
            held = self._read(self._ids[k], "Goal Position")
            if self._bounds.lo[k] <= held <= self._bounds.hi[k]:
                goals[k] = held
        self._send_goals(goals)
        for k, sid in enumerate(self._ids):
            if k not in holding:
                self._write(sid, "Torque Enable", 1)
        self._train_loop.reset()
        self._settle(goals)

    def _settle(self, goals: np.ndarray) -> None:
        """Wait until every servo holds still at its goal (:func:`~drivers.dynamixel.settle.settle_all`)."""
        why = settle_all(self.settings, lambda sid: self._read(sid, "Position I Gain"), self._cycle.read_state, goals,
                         self.clock)
        if why:
            self._warn(why)

    def _encoder_positions(self, st: JointState) -> np.ndarray:
        q = st.position.copy()
        if self._train is not None and hasattr(self, "_encoder_train"):
            q[self._train] = self._encoder_train
        return q

    def _command(self, position: np.ndarray, velocity: np.ndarray | None) -> None:
        lim = self._limits
        q = np.minimum(np.maximum(position, lim.lower), lim.upper)
        if self._sensor is not None and self._last is not None:
            # Host loop on the train: the arc angle follows the sensor, not the pinion.
            q = self._train_loop.goal(q, self._last.position[self._train], self._last.time,
                                      valid=not (self._last.flags or self._lost))
        self._send_goals(self._goal_ticks(q))

    def _goal_ticks(self, q: np.ndarray, hold: bool = False) -> np.ndarray:
        """Goal ticks through each transmission, each checked against its band (hold: where the
        shaft already is, against its mode's range only); one outside is refused, not clamped."""
        qs = q if self._in_joint_order else q[self._index]
        return self._bounds.check(np.rint((qs - self._q_at_tick0) * self._ticks_per_q), hold, qs)

    def _send_goals(self, ticks: np.ndarray) -> None:
        self._cycle.write_goals(ticks.tolist())

    def _disable(self) -> None:
        if self.settings.safe_stop == "hold":
            try:
                self._send_goals(self._goal_ticks(self._encoder_positions(self._read_bus()), hold=True))
                self.safe_stop_report = "holding the measured position (torque on)"
            except CommunicationError as e:
                self.safe_stop_report = f"hold not confirmed: {e}"
            except GoalOutOfRange as e:  # nothing sane to hold: free the motors instead
                self._torque_off_all()
                self.safe_stop_report = f"hold refused ({e}); {self.safe_stop_report}"
            return
        self._torque_off_all()

    def _torque_off_all(self) -> None:
        """Torque off on every servo that still answers (broadcast, then one by one), then
        Torque Enable read back from each: ``safe_stop_report`` says which confirmed."""
        addr, _ = _register("Torque Enable")
        try:
            self.ph.write1ByteTxOnly(self.port, self._sdk.BROADCAST_ID, addr, 0)
        except Exception:  # the port may already be gone; try one by one all the same
            pass
        unconfirmed = []
        for sid in self._ids:
            for _ in range(2):  # one retry: a dead bus must not hold up the exit
                try:
                    self.ph.write1ByteTxRx(self.port, sid, addr, 0)
                    value, comm, err = self.ph.read1ByteTxRx(self.port, sid, addr)
                except Exception:  # the port may already be gone
                    continue
                if comm == self._sdk.COMM_SUCCESS and value == 0:
                    break
            else:
                unconfirmed.append(sid)
        n = len(self._ids)
        self.safe_stop_report = (
            f"torque off, confirmed by reading Torque Enable back from all {n} servos"
            if not unconfirmed else
            f"torque off NOT confirmed for servo ID(s) {unconfirmed} of {n}: check the rig")

    def _close(self) -> None:
        self._shutdown_port()

    def _shutdown_port(self) -> None:
        if self._sensor is not None:
            self._sensor.close()
            self._sensor = None
        try:
            if (self.settings.safe_stop == "torque_off" and self.safe_stop_report is None
                    and getattr(self.port, "is_open", False)):
                self._torque_off_all()
        finally:
            try:
                self.port.closePort()
            except Exception:
                pass

    # -- extras ------------------------------------------------------------------
    def set_effort_limit(self, joint: int, effort: float) -> None:
        """Limit a joint's torque/force through Goal Current (current-based position mode)."""
        sv = self.settings.servos[self._index.index(joint)]
        if sv.mode != "current_based_position":
            raise BackendSetupError(
                f"joint {sv.joint}: effort limits need mode current_based_position (servo {sv.id} "
                f"is in {sv.mode})")
        current = abs(effort * sv.ratio) / _kt(sv.model)
        self._write(sv.id, "Goal Current", model_spec(sv.model).table["Goal Current"].nearest(current))
        eff = self._limits.effort.copy()
        eff[joint] = effort
        self._limits = JointLimits(self._limits.lower, self._limits.upper, self._limits.velocity, eff)

    def servo_info(self) -> list[dict]:
        """Model and firmware read from the bus, for the trial record."""
        return [{"joint": sv.joint, "id": sv.id, "model": self.models.get(sv.id),
                 "model_name": _model_name(self.models.get(sv.id, 0)),
                 "firmware": self.firmware.get(sv.id), "emulated": self.emulated.get(sv.id, False)}
                for sv in self.settings.servos]


def _model_name(number: int) -> str:
    try:
        return model_spec(number).name
    except Exception:
        return "unknown model"


def _kt(number: int) -> float:
    return model_spec(number).motor.kt


def _current_unit(number: int) -> float:
    table = model_spec(number).table
    return table["Present Current"].scale if "Present Current" in table else 0.0
