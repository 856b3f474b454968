"""An X-series servo's firmware loop and motor, per 1 ms substep: profile, position or velocity
PID in firmware units, PWM and current limits, the DC motor, overload supervision
(the physics half of :class:`~drivers.emulator.servo.ServoModel`; the register half is there)."""

from __future__ import annotations

import math

from drivers.dynamixel.units import (
    ACCEL_UNIT_RAD_S2,
    CENTER_TICK,
    POSITION_MODES,
    PWM_FULL_SCALE,
    RAD_PER_TICK,
    TICKS_PER_REV,
    VELOCITY_UNIT_RAD_S,
    OperatingMode,
)

__all__ = ["CONTROL_PERIOD_S", "ServoFirmware", "clamp"]

CONTROL_PERIOD_S = 0.001


def clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class ServoFirmware:
    """The firmware and motor of :class:`~drivers.emulator.servo.ServoModel` (a mixin: it reads and
    reports through the servo's control table)."""

    def step(self, dt: float, position: float, velocity: float) -> float:
        """Run the firmware for ``dt`` s given the shaft state (rad, rad/s); return shaft torque (N·m)."""
        # The bus runs this for every servo every millisecond: items are read from
        # the value dict directly rather than through get().
        values = self._values
        self._time += dt
        sign = -1.0 if values["Drive Mode"] & 1 else 1.0
        present = self._sense(position, velocity, sign)
        self._check_supervision()
        mode = values["Operating Mode"]
        omega = sign * velocity  # servo frame
        pwm_limit = float(values["PWM Limit"])
        current_cmd: float | None = None
        pwm = 0.0
        if values["Torque Enable"] != 1:
            self._track_present(present)
            current = 0.0
        else:
            if mode in POSITION_MODES:
                u = self._position_control(dt, present)
                if mode == OperatingMode.CURRENT_BASED_POSITION:
                    current_cmd = clamp(u, abs(self.get("Goal Current"))) * self._amps_per_unit
                else:
                    pwm = clamp(u, min(pwm_limit, abs(values["Goal PWM"])))
            elif mode == OperatingMode.VELOCITY:
                pwm = clamp(self._velocity_control(dt), min(pwm_limit, abs(values["Goal PWM"])))
            elif mode == OperatingMode.CURRENT:
                current_cmd = self.get("Goal Current") * self._amps_per_unit
            else:  # PWM
                pwm = clamp(float(values["Goal PWM"]), pwm_limit)
            vin = max(self.input_voltage, 1e-6)
            if current_cmd is not None:
                needed = current_cmd * self._resistance + self._ke * omega
                pwm = clamp(needed / vin * PWM_FULL_SCALE, pwm_limit)
            current = (pwm / PWM_FULL_SCALE * vin - self._ke * omega) / self._resistance
            current = clamp(current, self._current_limit_a())
            self._check_overload(dt, current)
        if values["Torque Enable"] != 1:  # overload may just have switched it off
            current, pwm = 0.0, 0.0
        self._report_drive(pwm, current)
        if self._forced:
            self._apply_forced()
        return sign * self._kt * current

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
        self._sense(position, velocity, sign)
        if self._forced:
            self._apply_forced()

    def _current_limit_a(self) -> float:
        if self._has_current_limit:
            return self._values["Current Limit"] * self._amps_per_unit
        return math.inf

    def _sense(self, position: float, velocity: float, sign: float) -> float:
        """Update Present Position/Velocity; return the encoder reading in ticks."""
        raw = CENTER_TICK + sign * position / RAD_PER_TICK + self._turn_offset
        self._raw_ticks = raw
        present = math.floor(raw + 0.5) + self._values["Homing Offset"]
        self._report("Present Position", present)
        self._report("Present Velocity", round(sign * velocity / VELOCITY_UNIT_RAD_S))
        self._report("Realtime Tick", int(self._time * 1000.0) % 32768)
        self._report("Present Input Voltage", round(self.input_voltage * 10.0))
        self._report("Present Temperature", max(0, min(255, round(self.temperature_c))))
        return float(present)

    def _wrap_turns(self) -> None:
        """Bring the encoder count back into one revolution, as after power-up."""
        raw = getattr(self, "_raw_ticks", CENTER_TICK + self._turn_offset)
        self._turn_offset -= TICKS_PER_REV * math.floor(raw / TICKS_PER_REV)
        self._raw_ticks = raw - TICKS_PER_REV * math.floor(raw / TICKS_PER_REV)
        self.set("Present Position", math.floor(self._raw_ticks + 0.5) + self.get("Homing Offset"))

    def _reset_controller(self, *, goal_to_present: bool) -> None:
        present = float(self.get("Present Position"))
        self._traj_pos = present
        self._traj_vel = 0.0
        self._integral = 0.0
        self._prev_error: float | None = None
        self._vel_integral = 0.0
        self._overload_timer = 0.0
        self._profile_vmax = math.inf
        self._profile_amax = math.inf
        self._profile_ongoing = False
        if goal_to_present and self.get("Operating Mode") in POSITION_MODES:
            self.set("Goal Position", int(present))
        self.set("Position Trajectory", int(present))
        self.set("Velocity Trajectory", 0)

    def _track_present(self, present: float) -> None:
        self._traj_pos = present
        self._traj_vel = 0.0
        self._profile_ongoing = False
        self._report("Position Trajectory", int(present))
        self._report("Velocity Trajectory", 0)
        self._report("Moving Status", 0)

    def _plan_profile(self) -> None:
        """Profile limits for a new Goal Position (ticks/s, ticks/s²)."""
        pv = self.get("Profile Velocity")
        pa = self.get("Profile Acceleration")
        if pv == 0:
            self._profile_vmax = self._profile_amax = math.inf
        elif self.get("Drive Mode") & 0x04:  # time-based profile
            distance = abs(self.get("Goal Position") - self._traj_pos)
            total = pv / 1000.0
            ramp = min(pa, pv / 2.0) / 1000.0
            self._profile_vmax = max(distance / max(total - ramp, 1e-3), 1e-9)
            self._profile_amax = self._profile_vmax / ramp if ramp > 0 else math.inf
        else:
            self._profile_vmax = pv * VELOCITY_UNIT_RAD_S / RAD_PER_TICK
            self._profile_amax = pa * ACCEL_UNIT_RAD_S2 / RAD_PER_TICK if pa else math.inf
        self._profile_ongoing = True

    def _advance_profile(self, dt: float) -> None:
        goal = float(self._values["Goal Position"])
        remaining = goal - self._traj_pos
        vmax, amax = self._profile_vmax, self._profile_amax
        if math.isinf(vmax) or remaining == 0.0:
            self._traj_pos, self._traj_vel = goal, 0.0
        else:
            direction = math.copysign(1.0, remaining)
            if math.isinf(amax):
                self._traj_vel = direction * vmax
            else:
                target = direction * min(vmax, math.sqrt(2.0 * amax * abs(remaining)))
                self._traj_vel += clamp(target - self._traj_vel, amax * dt)
            step = self._traj_vel * dt
            if abs(step) >= abs(remaining) or abs(remaining) < 1e-3:
                self._traj_pos, self._traj_vel = goal, 0.0
            else:
                self._traj_pos += step
        self._profile_ongoing = self._traj_pos != goal
        self._report("Position Trajectory", round(self._traj_pos))
        self._report("Velocity Trajectory", round(self._traj_vel * RAD_PER_TICK / VELOCITY_UNIT_RAD_S))

    def _position_control(self, dt: float, present: float) -> float:
        self._advance_profile(dt)
        values = self._values
        goal = values["Goal Position"]
        error = self._traj_pos - present
        if (
            self.deadband_ticks
            and not self._profile_ongoing
            and abs(goal - present) <= self.deadband_ticks
        ):
            self._integral = 0.0
            self._prev_error = error
            return 0.0
        kp = values["Position P Gain"] / 128.0
        ki = values["Position I Gain"] / 65536.0
        kd = values["Position D Gain"] / 16.0
        samples = dt / CONTROL_PERIOD_S
        limit = float(values["PWM Limit"])
        self._integral = clamp(self._integral + ki * error * samples, limit)
        derivative = 0.0 if self._prev_error is None else (error - self._prev_error) / samples
        self._prev_error = error
        return kp * error + self._integral + kd * derivative

    def _velocity_control(self, dt: float) -> float:
        goal = float(self.get("Goal Velocity"))  # 0.229 rev/min units
        pa = self.get("Profile Acceleration")
        per_unit = VELOCITY_UNIT_RAD_S / RAD_PER_TICK  # ticks/s per velocity unit
        target = goal * per_unit
        if pa:
            self._traj_vel += clamp(target - self._traj_vel, pa * ACCEL_UNIT_RAD_S2 / RAD_PER_TICK * dt)
        else:
            self._traj_vel = target
        self._profile_ongoing = self._traj_vel != target
        self._report("Velocity Trajectory", round(self._traj_vel / per_unit))
        error = self._traj_vel / per_unit - self.get("Present Velocity")
        kp = self.get("Velocity P Gain") / 128.0
        ki = self.get("Velocity I Gain") / 65536.0
        limit = float(self.get("PWM Limit"))
        self._vel_integral = clamp(self._vel_integral + ki * error * dt / CONTROL_PERIOD_S, limit)
        return kp * error + self._vel_integral

    def _check_supervision(self) -> None:
        values = self._values
        volts = self.input_voltage * 10.0
        if not values["Min Voltage Limit"] <= volts <= values["Max Voltage Limit"]:
            self.raise_hardware_error("input_voltage")
        if self.temperature_c > values["Temperature Limit"]:
            self.raise_hardware_error("overheating")

    def _check_overload(self, dt: float, current: float) -> None:
        available = min(self._current_limit_a(), self.input_voltage / self._resistance)
        if available > 0 and abs(current) >= self.overload_fraction * available:
            self._overload_timer += dt
            if self._overload_timer > self.overload_time_s:
                self.raise_hardware_error("overload")
        else:
            self._overload_timer = 0.0

    def _report_drive(self, pwm: float, current: float) -> None:
        values = self._values
        self._report("Present PWM", round(pwm))
        if self.spec.senses_current:
            self._report("Present Current", round(current / self._amps_per_unit))
        else:
            load = round(current / self.spec.motor.stall_current * 1000.0)
            self._report("Present Load", max(-1000, min(1000, load)))
        velocity = values["Present Velocity"]
        moving = abs(velocity) > values["Moving Threshold"] or self._profile_ongoing
        self._report("Moving", 1 if moving else 0)
        status = 0
        if values["Torque Enable"] == 1 and values["Operating Mode"] in POSITION_MODES:
            if abs(values["Goal Position"] - values["Present Position"]) <= max(2, self.deadband_ticks):
                status |= 0x01  # in position
            if self._profile_ongoing:
                status |= 0x02
            if not math.isinf(self._profile_vmax):
                status |= 0x30 if not math.isinf(self._profile_amax) else 0x10
        self._report("Moving Status", status)

    def _apply_forced(self) -> None:
        for name, value in list(self._forced.items()):  # may change from another thread
            self.set(name, value)
