"""An X-series servo's firmware loop and motor, per 1 ms substep: what the registers ask of the
shared servo model, and what it reports back (the physics half of
:class:`~drivers.emulator.servo.ServoModel`; the register half is there).

The profile, the position PID and the motor run in :class:`~drivers.servo.model.ServoArray`,
one slot per servo: the bus steps all its servos' slots at once (:meth:`begin_step`, the
array's step, :meth:`end_step`), a servo on its own steps a one-slot array. The simulator's
servo model is the same class, so the emulated rig and the sim cannot drift apart. The
velocity mode's PI loop, the supervision (voltage, temperature, overload) and the reports
are the emulator's own.

What a step reports (Present Position, Velocity, Current, PWM, the trajectories, Moving, Moving
Status, the tick, voltage and temperature) is written to the control table when something next
looks at the servo (a READ, a WRITE, :meth:`get`...), from the step's own values and in the step's
own order: the table then reads exactly as if each step had written it, at a fraction of the cost
of writing about a dozen items per servo every millisecond that nobody reads. The loop's inputs
(the encoder's tick, the drive, the overload timer) run every step."""

from __future__ import annotations

import math

from drivers.dynamixel.control_table import Register
from drivers.dynamixel.units import POSITION_MODES, TICKS_PER_REV, OperatingMode
from drivers.servo.model import ServoArray, ServoParams

__all__ = ["CONTROL_PERIOD_S", "NOT_LOOP_INPUTS", "REPORTED", "ServoFirmware", "clamp"]

CONTROL_PERIOD_S = 0.001
#: The items the firmware reports from each step: writing them changes none of the loop's inputs.
REPORTED = frozenset({"Present Position", "Present Velocity", "Present Current", "Present Load",
                      "Present PWM", "Present Input Voltage", "Present Temperature", "Realtime Tick",
                      "Position Trajectory", "Velocity Trajectory", "Moving", "Moving Status"})
#: The items whose writes leave the position loop's inputs as they were: the reports, and the goal
#: (a new goal plans the servo's trajectory in its slot at once, :meth:`ServoFirmware._plan_profile`).
NOT_LOOP_INPUTS = REPORTED | {"Goal Position"}


def clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class ServoFirmware:
    """The firmware and motor of :class:`~drivers.emulator.servo.ServoModel` (a mixin: it reads and
    reports through the servo's control table, and keeps its loop in a slot of a servo array)."""

    _bank: ServoArray
    _slot: int
    _motor: ServoParams
    # The registers whose units the loop converts with (set by the servo from its table).
    _position_reg: Register
    _velocity_reg: Register
    _accel_reg: Register
    _voltage_reg: Register
    _temperature_reg: Register
    _tick_reg: Register

    # -- the slot -------------------------------------------------------------------------
    def _motor_params(self) -> ServoParams:
        """This servo's motor as the servo model's parameters (one slot): the model file's, or the
        datasheet's (what the servo was built with)."""
        return self._motor.with_(amps_per_unit=self._amps_per_unit)

    def _own_bank(self) -> None:
        """A one-slot array: the servo runs on its own until a bus gathers it."""
        self._bank = ServoArray(self._motor_params())
        self._slot = 0

    def attach(self, bank: ServoArray, slot: int) -> None:
        """Move this servo's loop into ``slot`` of a bus's array, state and all."""
        old, i = self._bank, self._slot
        for name in ("traj", "traj_vel", "integral", "prev_error", "has_prev", "vmax", "amax", "goal",
                     "ongoing", "gains", "pwm_limit", "pwm_cap", "current_limit", "supply", "deadband",
                     "current_based", "goal_current", "amps_per_unit"):
            getattr(bank, name)[slot] = getattr(old, name)[i]
        self._bank, self._slot = bank, slot

    #: What the last step (and an observation after it) left to report, in order: ("sense",
    #: position, velocity, sign, time), ("drive", pwm, current, trajectory or None), ...
    _pending: list[tuple] | None = None
    #: Items written other than reports and the goal (the loop's inputs may have changed), and the key under
    #: which the slot's inputs were last set: (writes, supply, deadband).
    _writes = 0
    _loop_inputs: tuple | None = None

    def _flush_reports(self) -> None:
        """Write what the last step left to report (see the module's note); a no-op when nothing is."""
        pending = self._pending
        if pending is None:
            return
        self._pending = None
        seen = None  # a step's encoder, for its drive's report, where a later sense rewrites it
        last = len(pending) - 1
        for k, item in enumerate(pending):
            if item[0] == "sense":
                if k + 2 <= last and pending[k + 1][0] == "drive" and pending[k + 2][0] == "sense":
                    seen = self._sensed(*item[1:4])
                else:
                    self._report_sense(*item[1:])
            else:
                self._report_step(*item[1:], seen=seen)
                seen = None

    # -- one physics step ---------------------------------------------------------------------
    def step(self, dt: float, position: float, velocity: float) -> float:
        """Run the firmware for ``dt`` s given the shaft state (rad, rad/s); return shaft torque (N·m).

        A servo on a bus is stepped with the others by the bus (:meth:`begin_step`, the array,
        :meth:`end_step`), never alone."""
        if self._bank.params.n != 1:
            raise RuntimeError(f"servo {self.id} is stepped by its bus, with the others")
        self.begin_step(dt, position, velocity)
        self._bank.step_ticks(dt)
        return self.end_step(dt)

    def begin_step(self, dt: float, position: float, velocity: float) -> None:
        """Sense, supervise and hand the array this servo's inputs for the step."""
        # The bus runs this for every servo every millisecond: items are read from
        # the value dict directly rather than through get().
        values = self._values
        self._time += dt
        sign = -1.0 if values["Drive Mode"] & 1 else 1.0
        self._sign = sign
        present = self._encoder(position, sign)
        # this step's reports replace the last step's, which they rewrite whole
        self._pending = [("sense", position, velocity, sign, self._time)]
        self._check_supervision()
        b, i = self._bank, self._slot
        b.present[i] = present
        b.omega[i] = sign * velocity  # servo frame
        mode = values["Operating Mode"]
        if values["Torque Enable"] == 1 and mode in POSITION_MODES:
            # the position loop's inputs stand as the last step set them while no item but a
            # report was written since, and the supply and the deadband are the same
            key = self._loop_key()
            if key == self._loop_inputs:
                return
            self._loop_inputs = key
        else:
            self._loop_inputs = None
        if values["Torque Enable"] != 1:
            b.pid[i] = False
            b.pwm_in[i] = b.current_in[i] = math.nan
            self._track_present(present)
            self._driving = False
            return
        self._set_loop_inputs(dt, mode)

    def _loop_key(self) -> tuple:
        """What the position loop's inputs were last set under: (writes, supply, deadband)."""
        return (self._writes, self.input_voltage, self.deadband_ticks)

    def _set_loop_inputs(self, dt: float, mode: int) -> None:
        """Hand the array this servo's loop inputs (torque on): the gains and limits of a position
        mode, or the drive of the others."""
        values = self._values
        b, i = self._bank, self._slot
        b.version += 1  # the array's registers written in place: a fused loop works its constants out again
        b.pid[i] = False
        b.pwm_in[i] = b.current_in[i] = math.nan
        self._driving = True
        pwm_limit = float(values["PWM Limit"])
        b.pwm_limit[i] = pwm_limit
        b.supply[i] = self.input_voltage
        b.current_limit[i] = self._current_limit_a()
        b.current_based[i] = False
        if mode in POSITION_MODES:
            b.pid[i] = True
            b.gains[i, 0] = values["Position P Gain"]
            b.gains[i, 1] = values["Position I Gain"]
            b.gains[i, 2] = values["Position D Gain"]
            b.deadband[i] = self.deadband_ticks
            if mode == OperatingMode.CURRENT_BASED_POSITION:
                b.current_based[i] = True
                b.goal_current[i] = abs(values["Goal Current"])
            else:
                b.pwm_cap[i] = min(pwm_limit, abs(values["Goal PWM"]))
        elif mode == OperatingMode.VELOCITY:
            b.pwm_in[i] = clamp(self._velocity_control(dt), min(pwm_limit, abs(values["Goal PWM"])))
        elif mode == OperatingMode.CURRENT:
            b.current_in[i] = values["Goal Current"] * self._amps_per_unit
        else:  # PWM
            b.pwm_in[i] = clamp(float(values["Goal PWM"]), pwm_limit)

    def steady(self) -> tuple | None:
        """This servo's constants for a run of steady steps (:mod:`drivers.emulator.steady`), its loop
        inputs brought up to date; None where its next step must take :meth:`begin_step`'s path:
        torque off, a mode other than a position mode, a forced item, a supervision fault due."""
        values = self._values
        mode = values["Operating Mode"]
        if values["Torque Enable"] != 1 or mode not in POSITION_MODES or self._forced:
            return None
        if self._supervision_faults():
            return None
        key = self._loop_key()
        if key != self._loop_inputs:
            self._loop_inputs = key
            self._set_loop_inputs(CONTROL_PERIOD_S, mode)
        sign = -1.0 if values["Drive Mode"] & 1 else 1.0
        available = min(self._current_limit_a(), self.input_voltage / self._resistance)
        overload_at = self.overload_fraction * available if available > 0 else math.inf
        return (sign, self._position_reg.from_si, self._turn_offset, values["Homing Offset"],
                sign * self._kt, overload_at, self.overload_time_s, self._overload_timer, self._time)

    def settle(self, position: float, velocity: float, raw: float, time_s: float, overload_timer: float,
               sign: float, *, drive: bool) -> None:
        """After a run of steady steps: the state its last step leaves, as :meth:`begin_step` and, with
        ``drive``, :meth:`end_step` would have left it (without, :meth:`end_step` is still to run)."""
        b, i = self._bank, self._slot
        self._time, self._sign, self._raw_ticks, self._overload_timer = time_s, sign, raw, overload_timer
        self._pending = [("sense", position, velocity, sign, time_s)]
        if drive:
            self._profile_ongoing = bool(b.ongoing[i])
            self._pending.append(("drive", float(b.pwm[i]), float(b.current[i]),
                                  (float(b.traj[i]), float(b.traj_vel[i]))))

    def end_step(self, dt: float) -> float:
        """Take the array's drive for this servo: supervise the current, report, return the torque."""
        values = self._values
        b, i = self._bank, self._slot
        current = pwm = 0.0
        trajectory = None
        if self._driving:
            current, pwm = float(b.current[i]), float(b.pwm[i])
            self._check_overload(dt, current)
            if b.pid[i]:
                self._profile_ongoing = bool(b.ongoing[i])
                trajectory = (float(b.traj[i]), float(b.traj_vel[i]))
        if values["Torque Enable"] != 1:  # overload may just have switched it off
            current, pwm = 0.0, 0.0
        drive = ("drive", pwm, current, trajectory)
        if self._pending is None:
            self._pending = [drive]
        else:
            self._pending.append(drive)
        if self._forced:
            self._flush_reports()
            self._apply_forced()
        return self._sign * self._kt * current

    def _report_step(self, pwm: float, current: float, trajectory: tuple[float, float] | None,
                     seen: tuple[int, int] | None = None) -> None:
        """A step's drive, as the firmware reports it: the trajectory (position loop), PWM, current,
        moving (``seen``: the step's Present Position and Velocity, where they were not written)."""
        if trajectory is not None:
            self._report("Position Trajectory", round(trajectory[0]))
            traj_vel = trajectory[1] * self._position_reg.scale  # rad/s
            self._report("Velocity Trajectory", round(self._velocity_reg.from_si(traj_vel)))
        self._report_drive(pwm, current, seen)

    def power_on(self, position: float, velocity: float = 0.0) -> None:
        """Read the absolute encoder as at power-up: one turn, goal = present, torque off."""
        sign = -1.0 if self.get("Drive Mode") & 1 else 1.0
        self._sense(position, velocity, sign)
        self._wrap_turns()
        self._reset_controller(goal_to_present=True)
        self._apply_forced()

    def observe(self, position: float, velocity: float) -> None:
        """Refresh the reported state from the shaft without running the controller."""
        sign = -1.0 if self._values["Drive Mode"] & 1 else 1.0
        self._encoder(position, sign)
        sense = ("sense", position, velocity, sign, self._time)
        if self._pending is None:
            self._pending = [sense]
        else:
            self._pending.append(sense)
        if self._forced:
            self._flush_reports()
            self._apply_forced()

    def _current_limit_a(self) -> float:
        if self._has_current_limit:
            return self._values["Current Limit"] * self._amps_per_unit
        return math.inf

    def _encoder(self, position: float, sign: float) -> float:
        """The encoder reading (ticks, Homing Offset added) of a shaft at ``position``."""
        raw = self._position_reg.from_si(sign * position) + self._turn_offset
        self._raw_ticks = raw
        return float(math.floor(raw + 0.5) + self._values["Homing Offset"])

    def _sense(self, position: float, velocity: float, sign: float) -> float:
        """Update Present Position/Velocity now; return the encoder reading in ticks."""
        self._flush_reports()
        present = self._encoder(position, sign)
        self._report_sense(position, velocity, sign, self._time)
        return present

    def _sensed(self, position: float, velocity: float, sign: float) -> tuple[int, int]:
        """Present Position and Present Velocity (raw) of a shaft state."""
        raw = self._position_reg.from_si(sign * position) + self._turn_offset
        return (math.floor(raw + 0.5) + self._values["Homing Offset"],
                round(self._velocity_reg.from_si(sign * velocity)))

    _supply_raw: tuple[float, float, int, int] | None = None

    def _report_sense(self, position: float, velocity: float, sign: float, time_s: float) -> None:
        """What the encoder and the supervision report of a shaft state at ``time_s``."""
        present, speed = self._sensed(position, velocity, sign)
        self._report("Present Position", present)
        self._report("Present Velocity", speed)
        self._report("Realtime Tick", int(self._tick_reg.from_si(time_s)) % 32768)
        supply = self._supply_raw
        if supply is None or supply[0] != self.input_voltage or supply[1] != self.temperature_c:
            temperature = max(0, min(255, self._temperature_reg.nearest(self.temperature_c)))
            supply = self._supply_raw = (self.input_voltage, self.temperature_c,
                                         self._voltage_reg.nearest(self.input_voltage), temperature)
        self._report("Present Input Voltage", supply[2])
        self._report("Present Temperature", supply[3])

    def _wrap_turns(self) -> None:
        """Bring the encoder count back into one revolution, as after power-up."""
        raw = getattr(self, "_raw_ticks", self._position_reg.zero + self._turn_offset)
        self._turn_offset -= TICKS_PER_REV * math.floor(raw / TICKS_PER_REV)
        self._raw_ticks = raw - TICKS_PER_REV * math.floor(raw / TICKS_PER_REV)
        self.set("Present Position", math.floor(self._raw_ticks + 0.5) + self.get("Homing Offset"))

    def _reset_controller(self, *, goal_to_present: bool) -> None:
        if not hasattr(self, "_bank"):
            self._own_bank()
        present = float(self.get("Present Position"))
        self._bank.reset_slot(self._slot, present)
        self._bank.goal[self._slot] = float(self.get("Goal Position"))
        self._vel_traj = 0.0
        self._vel_integral = 0.0
        self._overload_timer = 0.0
        self._profile_ongoing = False
        if goal_to_present and self.get("Operating Mode") in POSITION_MODES:
            self.set("Goal Position", int(present))
            self._bank.goal[self._slot] = present
        self.set("Position Trajectory", int(present))
        self.set("Velocity Trajectory", 0)

    def _track_present(self, present: float) -> None:
        self._bank.track_slot(self._slot, present)
        self._vel_traj = 0.0
        self._profile_ongoing = False
        self._report("Position Trajectory", int(present))
        self._report("Velocity Trajectory", 0)
        self._report("Moving Status", 0)

    def _plan_profile(self) -> None:
        """Profile limits for a new Goal Position (ticks/s, ticks/s²), into the servo's slot."""
        pv = self.get("Profile Velocity")
        pa = self.get("Profile Acceleration")
        goal = float(self.get("Goal Position"))
        if pv == 0:
            vmax = amax = math.inf
        elif self.get("Drive Mode") & 0x04:  # time-based profile
            distance = abs(goal - float(self._bank.traj[self._slot]))
            total = pv / 1000.0
            ramp = min(pa, pv / 2.0) / 1000.0
            vmax = max(distance / max(total - ramp, 1e-3), 1e-9)
            amax = vmax / ramp if ramp > 0 else math.inf
        else:
            tick = self._position_reg.scale
            vmax = self._velocity_reg.to_si(pv) / tick
            amax = self._accel_reg.to_si(pa) / tick if pa else math.inf
        self._bank.plan_slot(self._slot, goal, vmax, amax)
        self._profile_ongoing = True

    def _velocity_control(self, dt: float) -> float:
        goal = float(self.get("Goal Velocity"))  # velocity units
        pa = self.get("Profile Acceleration")
        per_unit = self._velocity_reg.scale / self._position_reg.scale  # ticks/s per velocity unit
        target = goal * per_unit
        if pa:
            accel = self._accel_reg.to_si(pa) / self._position_reg.scale  # ticks/s²
            self._vel_traj += clamp(target - self._vel_traj, accel * dt)
        else:
            self._vel_traj = target
        self._profile_ongoing = self._vel_traj != target
        self._report("Velocity Trajectory", round(self._vel_traj / per_unit))
        error = self._vel_traj / per_unit - self.get("Present Velocity")
        kp = self.get("Velocity P Gain") / 128.0
        ki = self.get("Velocity I Gain") / 65536.0
        limit = float(self.get("PWM Limit"))
        self._vel_integral = clamp(self._vel_integral + ki * error * dt / CONTROL_PERIOD_S, limit)
        return kp * error + self._vel_integral

    def _supervision_faults(self) -> list[str]:
        """The supervision's faults due now, in the order the firmware latches them."""
        values = self._values
        volts = self._voltage_reg.from_si(self.input_voltage)
        faults = []
        if not values["Min Voltage Limit"] <= volts <= values["Max Voltage Limit"]:
            faults.append("input_voltage")
        if self.temperature_c > values["Temperature Limit"]:
            faults.append("overheating")
        return faults

    def _check_supervision(self) -> None:
        for fault in self._supervision_faults():
            self.raise_hardware_error(fault)

    def _check_overload(self, dt: float, current: float) -> None:
        available = min(self._current_limit_a(), self.input_voltage / self._resistance)
        if available > 0 and abs(current) >= self.overload_fraction * available:
            self._overload_timer += dt
            if self._overload_timer > self.overload_time_s:
                self.raise_hardware_error("overload")
        else:
            self._overload_timer = 0.0

    def _report_drive(self, pwm: float, current: float, seen: tuple[int, int] | None = None) -> None:
        values = self._values
        present, velocity = seen if seen is not None else (values["Present Position"],
                                                           values["Present Velocity"])
        self._report("Present PWM", round(pwm))
        if self.spec.senses_current:
            self._report("Present Current", round(current / self._amps_per_unit))
        else:
            load = round(self.table["Present Load"].from_si(current / self.spec.motor.stall_current))
            self._report("Present Load", max(-1000, min(1000, load)))
        moving = abs(velocity) > values["Moving Threshold"] or self._profile_ongoing
        self._report("Moving", 1 if moving else 0)
        status = 0
        if values["Torque Enable"] == 1 and values["Operating Mode"] in POSITION_MODES:
            if abs(values["Goal Position"] - present) <= max(2, self.deadband_ticks):
                status |= 0x01  # in position
            if self._profile_ongoing:
                status |= 0x02
            if not math.isinf(self._bank.vmax[self._slot]):
                status |= 0x30 if not math.isinf(self._bank.amax[self._slot]) else 0x10
        self._report("Moving Status", status)

    def _apply_forced(self) -> None:
        for name, value in list(self._forced.items()):  # may change from another thread
            self.set(name, value)
