"""Guided calibration of a rig: joint zero offsets, then the ultrasonic sensor against the arc.

Joint zeros: each joint is brought to its mechanical reference (the robot's
home pose: the train at the top of the arc, θ3…θ8 at 0, d9 at its home
stroke, the needle retracted) and its servo's shaft angle is read; the zero
offset that makes the joint read its reference there is
``offset = reference − ratio · shaft``. It is kept either as a config
override (the calibration file's ``servos``, the default) or written into
the servos' Homing Offset registers — one or the other, as the technician
chooses, never both.

Ultrasonic: the train is driven by its servo (with the new zero) to stops
along the arc; at each, the arc angle ε from the servo and the mean sensor
reading are recorded, d2(ε) follows from eqs 10–18, and
``reading = offset + scale · d2`` is fitted by least squares, its residual
reported. The sensor's ``offset`` replaces the config's standoff.

Nothing is written until every measurement is done: a run stopped half way
(Ctrl-C, a fault) leaves the servos' registers and the config's files as they
were, with torque off.
"""

from __future__ import annotations

import datetime as dt
import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal, Optional

import numpy as np

from bench.config.calibration import (
    CalibrationFile,
    ServoCalibration,
    UltrasonicCalibration,
    UltrasonicStop,
    save_calibration,
)
from bench.config.models import TrialConfig
from bench.kinematics.arc_train import train_pose
from bench.kinematics.registry import get_robot
from bench.lab.motion import Ramp, move, wait_still
from bench.lab.session import check_ports, check_servos, open_backend, require_dynamixel
from bench.scene.dynamics import gravity_torques
from drivers import ActuatorError, CommunicationError
from drivers.dynamixel.bus import ServoBus
from drivers.ultrasonic import UltrasonicSensor

__all__ = ["CalibrationResult", "JointZero", "UltrasonicFit", "calibrate", "default_output",
           "fit_ultrasonic", "reference_text", "stop_angles"]

WriteMode = Literal["config", "homing"]

ZERO_SAMPLES = 9  # shaft readings per joint (median)
STOP_SAMPLES = 25  # ultrasonic readings per stop (mean)
TRAIN_SPEED = 0.2  # rad/s of arc angle while calibrating (the servo manages about 0.24)
STOP_SPAN = 2.0 / 3.0  # the stops cover this central fraction of the train's travel
STILL_ARC_M = 2e-4  # the train counts as stopped once it moves less than this along the arc in 0.25 s


@dataclass(frozen=True)
class JointZero:
    joint: str
    configured: float  # the config's offset (rad or m)
    offset: float  # the measured one
    reference: float  # the joint value at the reference

    @property
    def change(self) -> float:
        return self.offset - self.configured


@dataclass(frozen=True)
class UltrasonicFit:
    """reading = offset + scale · d2 (m), with its residuals over the stops (m)."""

    offset: float
    scale: float
    rms: float
    max_abs: float


@dataclass
class CalibrationResult:
    path: Path
    file: CalibrationFile
    zeros: dict[str, JointZero] = field(default_factory=dict)
    fit: Optional[UltrasonicFit] = None
    #: joints whose measured zero was implausible and not written: joint -> why
    refused: dict[str, str] = field(default_factory=dict)
    measured: dict[str, JointZero] = field(default_factory=dict)  # written or refused


def fit_ultrasonic(d2: np.ndarray, distance: np.ndarray) -> UltrasonicFit:
    """Least-squares line through (d2, reading) pairs, in m."""
    d2, distance = np.asarray(d2, dtype=float), np.asarray(distance, dtype=float)
    if d2.size < 2 or np.ptp(d2) <= 0:
        raise ValueError("an ultrasonic fit needs at least two stops at different d2")
    A = np.column_stack([np.ones_like(d2), d2])
    (offset, scale), *_ = np.linalg.lstsq(A, distance, rcond=None)
    res = distance - (offset + scale * d2)
    return UltrasonicFit(float(offset), float(scale), float(np.sqrt(np.mean(res ** 2))),
                         float(np.max(np.abs(res))))


def stop_angles(lower: float, upper: float, n: int, span: Optional[float] = None) -> np.ndarray:
    """``n`` arc angles evenly over ``span`` (rad) centred on the train's travel.

    The default span is the central two thirds of the travel, clear of the end stops.
    """
    if n < 3:
        raise ValueError(f"--stops must be at least 3 for a fit with a residual, got {n}")
    span = (upper - lower) * STOP_SPAN if span is None else span
    if not 0 < span <= upper - lower:
        raise ValueError(f"--span-deg must be within the train's travel (0, "
                         f"{math.degrees(upper - lower):.0f}°], got {math.degrees(span):.1f}°")
    mid = (lower + upper) / 2
    return np.linspace(mid - span / 2, mid + span / 2, n)


def reference_text(robot, joint: str) -> str:
    """The reference of a joint as a technician reads it (degrees or mm)."""
    i = robot.joint_names.index(joint)
    row = robot.chain.rows[i]
    v = float(robot.chain.home[i])
    return f"{math.degrees(v):.1f}°" if row.kind == "revolute" else f"{v * 1e3:.1f} mm"


def default_output(config: TrialConfig, now: Optional[dt.datetime] = None) -> Path:
    """``<config dir>/calibration/<config name>-<YYYYmmdd-HHMMSS>.yaml``."""
    now = now or dt.datetime.now()
    base = Path(config.source).parent if config.source else Path("hil_configs")
    return base / "calibration" / f"{config.name}-{now.strftime('%Y%m%d-%H%M%S')}.yaml"


#: A zero offset further than this from the config's is implausible for a servo horn that
#: was mounted by hand (rad for revolute joints, m for prismatic): more is a joint read
#: while it sagged under load, or not at its reference.
PLAUSIBLE_CHANGE = {"revolute": math.radians(2.0), "prismatic": 2e-3}


def implausible_zeros(config: TrialConfig, robot, zeros: dict[str, "JointZero"]) -> dict[str, str]:
    """The zeros that moved further than :data:`PLAUSIBLE_CHANGE`, each with the likely cause:
    the gravity load the joint carries at its reference (from the URDF)."""

    load = None
    out: dict[str, str] = {}
    for joint, z in zeros.items():
        kind = robot.chain.rows[robot.joint_names.index(joint)].kind
        if abs(z.change) <= PLAUSIBLE_CHANGE[kind]:
            continue
        if load is None:
            try:
                load = gravity_torques(config.robot, robot.chain.home, config.urdf_dir)
            except Exception:  # noqa: BLE001 - the warning still stands without the load figure
                load = np.full(len(robot.joint_names), np.nan)
        tau = load[robot.joint_names.index(joint)]
        unit = "N·m" if kind == "revolute" else "N"
        why = (f"{_value(robot, joint, z.change, signed=True)} from the config is more than "
               f"{_value(robot, joint, PLAUSIBLE_CHANGE[kind])}")
        if np.isfinite(tau) and abs(tau) > 0.05:
            why += (f"; the joint carries {abs(tau):.2f} {unit} of gravity at its reference, so it "
                    f"sags unless supported: hold it at its reference (or give the servo integral "
                    f"gain, position_i) and calibrate again")
        else:
            why += "; check that the joint is at its reference"
        out[joint] = why
    return out


def calibrate(config: TrialConfig, *, write: WriteMode = "config", stops: int = 5,
              span: Optional[float] = None, samples: int = STOP_SAMPLES, out: Optional[Path] = None,
              accept_large: bool = False,
              confirm: Callable[[str], bool] = lambda message: True,
              note: Callable[[str], None] = lambda message: None) -> CalibrationResult:
    """Run the whole calibration and write the file (and the registers, for ``homing``).

    ``confirm(message)`` asks the technician to do something and returns False
    to skip it; ``note(message)`` reports progress, one line each. A zero that moved
    implausibly far (:data:`PLAUSIBLE_CHANGE`) is left out of the file, with a warning,
    unless ``accept_large``. The arm is left held (torque on) after the ultrasonic
    stops, never dropped.
    """

    require_dynamixel(config, "calibrate")
    if write not in ("config", "homing"):
        raise ValueError(f"--write must be config or homing, got {write!r}")
    if samples < 1:
        raise ValueError(f"--samples must be at least 1, got {samples}")
    b = config.backend
    run_ultrasonic = b.ultrasonic is not None and stops > 0
    robot = get_robot(config.robot)
    train = robot.joint_names.index(b.ultrasonic.joint) if b.ultrasonic else None
    if run_ultrasonic:
        row = robot.chain.rows[train]
        angles = stop_angles(row.lower, row.upper, stops, span)
    check_ports(config, ultrasonic=run_ultrasonic)
    path = Path(out) if out is not None else default_output(config)

    zeros = measure_zeros(config, robot, confirm, note)
    refused = {} if accept_large else implausible_zeros(config, robot, zeros)
    measured = dict(zeros)  # the refused ones too, for the technician's table
    for joint in refused:
        del zeros[joint]
    offsets = {j: z.offset for j, z in zeros.items()}
    fit, readings = None, []
    if run_ultrasonic and confirm(
            f"the train will drive to {stops} stops between {math.degrees(angles[0]):.0f}° and "
            f"{math.degrees(angles[-1]):.0f}° on the arc and back: keep clear of the robot"):
        readings = measure_ultrasonic(config, offsets, train, angles, note, samples)
        fit = fit_ultrasonic(np.array([r.d2_mm for r in readings]) * 1e-3,
                             np.array([r.distance_mm for r in readings]) * 1e-3)

    # Everything is measured: now (and only now) write.
    fields: dict = {"joint_offsets": write if zeros else "none"}
    if zeros and write == "homing":
        fields["homing_offsets"] = write_homing(config, zeros, note)
    elif zeros:
        fields["servos"] = {j: ServoCalibration(offset=z.offset, change=z.change)
                            for j, z in zeros.items()}
    if fit is not None:
        fields["ultrasonic"] = UltrasonicCalibration(
            offset_mm=fit.offset * 1e3, scale=fit.scale, residual_mm=fit.rms * 1e3,
            max_residual_mm=fit.max_abs * 1e3, stops=readings)
    cal = CalibrationFile(
        config_name=config.name, config_file=str(config.source) if config.source else None,
        robot=config.robot, created=dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        **fields)
    save_calibration(cal, path)
    return CalibrationResult(path, cal, zeros, fit, refused, measured)


def measure_zeros(config: TrialConfig, robot, confirm: Callable[[str], bool],
                  note: Callable[[str], None]) -> dict[str, JointZero]:
    """Each joint's zero offset, read at its reference (torque left as it is)."""

    b = config.backend
    reference = robot.chain.home
    order = [j for j in robot.joint_names if j in b.servos]
    zeros: dict[str, JointZero] = {}
    with ServoBus(b.port, b.baud) as bus:
        check_servos(bus, config)
        for joint in order:
            sc = b.servos[joint]
            if not confirm(f"{joint}: bring it to its reference ({reference_text(robot, joint)})"):
                note(f"{joint}: skipped, its offset stays {sc.offset:.6g}")
                continue
            shafts = []
            for _ in range(ZERO_SAMPLES):
                shafts.append(bus.shaft_angle(sc.id))
                bus.clock.sleep(0.01)
            ref = float(reference[robot.joint_names.index(joint)])
            z = JointZero(joint, sc.offset, ref - sc.ratio * statistics.median(shafts), ref)
            zeros[joint] = z
            note(f"{joint}: zero offset {_value(robot, joint, z.offset)} "
                 f"({_value(robot, joint, z.change, signed=True)} from the config)")
    return zeros


def measure_ultrasonic(config: TrialConfig, offsets: dict[str, float], train: int,
                       angles: np.ndarray, note: Callable[[str], None],
                       samples: int = STOP_SAMPLES) -> list[UltrasonicStop]:
    """Drive the train to each stop and read the sensor there; back to the start, held there
    (torque on: letting go would drop the arm onto its stops)."""

    u = config.backend.ultrasonic
    assert u is not None
    params = get_robot(config.robot).params
    still = STILL_ARC_M / params.arc_radius  # arc angle (rad)
    stops: list[UltrasonicStop] = []
    with open_backend(config, ultrasonic=False, offsets=offsets, calibrated=False,
                      safe_stop="hold") as act, \
            UltrasonicSensor(u.port, **{**u.sensor_options(), "median_window": 1,
                                        "stale_after_s": max(u.stale_after_s or 0.0, 1.0)}) as sensor:
        act.enable()
        start = act.read().position
        speed = np.full(len(start), 1e-9)
        speed[train] = TRAIN_SPEED
        ramp = Ramp(start, speed)
        for k, eps in enumerate(angles):
            goal = ramp.command.copy()
            goal[train] = eps
            move(act, ramp, goal)
            if not wait_still(act, train, still):
                note(f"stop {k + 1}: the train is still creeping; reading anyway")
            e, d = _sample(act, sensor, train, samples)
            d2 = float(train_pose(e, params).d2)
            stops.append(UltrasonicStop(epsilon_rad=e, d2_mm=d2 * 1e3, distance_mm=d * 1e3,
                                        samples=samples))
            note(f"stop {k + 1}/{len(angles)}: arc {math.degrees(e):.2f}°, d2 {d2 * 1e3:.1f} mm, "
                 f"reading {d * 1e3:.1f} mm")
        move(act, ramp, start)
    note("the arm is held where it started (torque on); jog it or power the servos off to release")
    return stops


def _sample(act, sensor, train: int, n: int, timeout_s: float = 10.0) -> tuple[float, float]:
    """Mean arc angle (servo) and mean of ``n`` fresh ultrasonic readings (m)."""

    distances, angles = [], []
    seen = sensor.counters.readings
    clock = sensor.clock  # the wall clock; an emulated line's virtual one
    t0 = next_read = clock.now()
    while len(distances) < n:
        now = clock.now()
        if now - t0 > timeout_s:
            raise CommunicationError(f"ultrasonic sensor on {sensor.port}: {len(distances)} of {n} "
                                     f"readings in {timeout_s:.0f} s")
        if now >= next_read:  # the encoder at 50 Hz, the sensor at whatever rate it streams
            angles.append(float(act.read().position[train]))
            next_read = now + 0.02
        count = sensor.counters.readings
        if count > seen:
            seen = count
            distances.append(sensor.read(allow_stale=True)[0])
        clock.sleep(0.003)
    return float(np.mean(angles)), float(np.mean(distances))


def write_homing(config: TrialConfig, zeros: dict[str, JointZero],
                 note: Callable[[str], None]) -> dict[str, float]:
    """Write each zero into its servo's Homing Offset (torque off for the write); shifts in shaft rad."""


    b = config.backend
    shifts: dict[str, float] = {}
    with ServoBus(b.port, b.baud) as bus:
        for joint, z in zeros.items():
            sc = b.servos[joint]
            try:
                shifts[joint] = bus.shift_zero(sc.id, (z.offset - sc.offset) / sc.ratio)
            except ActuatorError as e:
                done = f"already written for {', '.join(shifts)}" if shifts else "none written"
                raise type(e)(f"{e} (Homing Offsets: {done})") from None
            note(f"{joint}: Homing Offset of ID {sc.id} shifted by "
                 f"{math.degrees(shifts[joint]):+.3f}° of shaft")
    return shifts


def _value(robot, joint: str, v: float, signed: bool = False) -> str:
    kind = robot.chain.rows[robot.joint_names.index(joint)].kind
    fmt = "+.3f" if signed else ".3f"
    return f"{math.degrees(v):{fmt}}°" if kind == "revolute" else f"{v * 1e3:{fmt}} mm"
